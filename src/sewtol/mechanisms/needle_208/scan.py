"""Per-parameter tolerance scan in the layout of the source's table, and the tolerance search.

Each parameter is set to its upper and then its lower limit with every other parameter nominal,
the guide fixed (optionally shifted), and beta re-optimised. All 2k variants are one batch.
With `strategy=` (a needle_208.compensators.Strategy) each row is instead adjusted by the
strategy's exact joint optimum (needle_208.adjustment.adjust): its figures, and each compensator's
setting in a `NAME_setting` column (beta_deg: the beta setting, or the nominal's when the
strategy does not set beta). `strategy=None` is the beta-only scan, unchanged.
The recommended-tolerance search finds, per parameter and side, the largest deviation that
keeps SumDelta at beta* <= the limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.optimize import bisect_root
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208


@dataclass(frozen=True)
class ScanResult:
    """The rows of a per-parameter scan and the nominal machine's row (see `scan`).

    ``to_dataframe()`` gives the rows; ``to_records()`` the same as dicts (the JSON of
    ``sewtol needle scan``).
    """

    rows: pd.DataFrame  # param, side, delta_mm, value_mm, beta_deg, plus_um, minus_um, total_um
    nominal_row: dict
    tolerances: str
    guide_shift_um: float
    limit_um: float
    strategy: str = "beta"  # the adjustment of every row (scan(strategy=...))

    def to_dataframe(self) -> pd.DataFrame:
        """The rows (a copy)."""
        return self.rows.copy()

    def to_records(self) -> list[dict]:
        """The rows as dicts, the fixed columns first (the JSON rows of ``sewtol needle scan``)."""
        cols = ["param", "side", "delta_mm", "value_mm", "beta_deg", "plus_um", "minus_um",
                "total_um"]
        cols += [c for c in self.rows.columns if c not in cols]
        return self.rows[cols].to_dict(orient="records")


def scan(nominal: Needle208, tolerances: ToleranceSet | str, guide_shift_um: float | None = None,
         limit_um: float = sb.DEFAULT_LIMIT_UM,
         range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
         strategy: Strategy | None = None) -> ScanResult:
    """Each tolerance at its upper and its lower limit, every other parameter nominal.

    The layout of the source study's Table 4.1: the guide stays fixed where the nominal machine
    put it (optionally shifted) and beta is re-optimised on every row. All 2k rows are one
    batch.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        The limits to visit; parameters not in the set stay nominal.
    guide_shift_um : float or None
        The guide's shift along its normal for every row (um); the source moved the guide
        by about 50 um for AB and BE. None keeps the nominal's own guide_shift_um.
    limit_um : float
        The SumDelta limit (um); default 10.
    range_deg : tuple of float
        The regulating range searched for beta*, (low, high) in deg; default (10, 35).
    strategy : Strategy or None
        None: beta re-optimised on each row. A strategy: each row adjusted by the strategy's
        exact joint optimum, with each compensator's setting in a ``NAME_setting`` column and
        a ``status`` column.

    Returns
    -------
    ScanResult
        Rows with ``param``, ``side`` (upper/lower), ``delta_mm`` (the deviation), ``value_mm``
        (the parameter's value), ``beta_deg`` (beta*), ``plus_um``, ``minus_um`` and
        ``total_um`` (Delta+, Delta-, SumDelta) and ``beta_at_bound`` (beta*'s plateau reaches
        an end of range_deg: the row's optimum may lie outside it); ``nominal_row`` the same
        for the nominal.
    """
    tolerances = needle_set(tolerances)
    if guide_shift_um is None:
        guide_shift_um = float(nominal.guide_shift_um)
    base = nominal.override(guide_shift_um=guide_shift_um)
    params, sides, deltas, dev = tolerances.limit_variants()
    batch = P.with_deviations(base, dev)
    if strategy is not None:
        return _scan_adjusted(base, tolerances, params, sides, deltas, dev, batch, strategy,
                              guide_shift_um, limit_um)
    opt = sb.optimise_beta(batch, range_deg, limit_um, window=False)
    values = [float(np.asarray(getattr(batch, p))[i]) for i, p in enumerate(params)]
    rows = pd.DataFrame({
        "param": params, "side": sides, "delta_mm": deltas, "value_mm": values,
        "beta_deg": opt.beta_deg, "plus_um": opt.plus_um, "minus_um": opt.minus_um,
        "total_um": opt.total_um,
        # beta* on an end of the searched range: the row's optimum may lie outside it
        "beta_at_bound": np.asarray(opt.at_bound, bool),
    })
    nom = sb.optimise_beta(base, range_deg, limit_um, window=False)
    nominal_row = {"beta_deg": float(nom.beta_deg[0]), "plus_um": float(nom.plus_um[0]),
                   "minus_um": float(nom.minus_um[0]), "total_um": float(nom.total_um[0]),
                   "beta_at_bound": bool(nom.at_bound[0])}
    return ScanResult(rows, nominal_row, tolerances.name, float(guide_shift_um), float(limit_um))


def _scan_adjusted(base, tolerances, params, sides, deltas, dev, batch, strategy,
                   guide_shift_um, limit_um) -> ScanResult:
    """The scan's rows adjusted by `strategy` (needle_208.adjustment.adjust, exact joint optimum)."""
    from sewtol.mechanisms.needle_208.adjustment import adjust
    from sewtol.mechanisms.needle_208.strategies import columns_of

    values = [float(np.asarray(getattr(batch, p))[i]) for i, p in enumerate(params)]
    zero = {p: np.zeros(1) for p in tolerances.params}
    out = []
    for c in (columns_of(base, dev), columns_of(base, zero)):
        a = adjust(c, strategy, limit_um)
        beta = a.settings["beta"] if "beta" in strategy.names else np.full(a.n, base.beta)
        f = {"beta_deg": beta, "plus_um": a.plus_um, "minus_um": a.minus_um,
             "total_um": a.total_um, "beta_at_bound": np.zeros(a.n, bool)}
        for comp in strategy.compensators:
            if comp.name == "beta":  # its plateau reaches an end of beta's range
                eps = 1e-6 * (comp.high - comp.low)
                f["beta_at_bound"] = ((a.plateau_low["beta"] <= comp.low + eps)
                                      | (a.plateau_high["beta"] >= comp.high - eps))
        for comp in strategy.compensators:
            if comp.name != "beta":
                f[f"{comp.name}_setting"] = a.settings[comp.name]
        f["status"] = a.status
        out.append(f)
    rows = pd.DataFrame({"param": params, "side": sides, "delta_mm": deltas,
                         "value_mm": values, **out[0]})
    nominal_row = {k: (float(v[0]) if k not in ("status", "beta_at_bound") else
                       (str(v[0]) if k == "status" else bool(v[0]))) for k, v in out[1].items()}
    return ScanResult(rows, nominal_row, tolerances.name, float(guide_shift_um), float(limit_um),
                      strategy.name)


def largest_tolerances(nominal: Needle208, params: list[str],
                       limit_um: float = sb.DEFAULT_LIMIT_UM, max_mm: float = 1.0,
                       guide_shift_um: float = 0.0,
                       range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                       xtol_mm: float = 1e-5) -> pd.DataFrame:
    """Per parameter and side, the largest |deviation| <= max_mm with SumDelta(beta*) <= limit.

    A geometric grid from 1 um to max_mm brackets the first crossing, bisection refines it to
    xtol_mm. `reaches_max` marks sides where even max_mm keeps the limit.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    params : list of str
        The parameters to search, one at a time, every other one nominal.
    limit_um : float
        The SumDelta limit (um) at beta*; default 10.
    max_mm : float
        The largest deviation tried (mm, or the parameter's unit).
    guide_shift_um : float
        A shift of the guide along its normal (um).
    range_deg : tuple of float
        The regulating range searched for beta*, (low, high) in deg.
    xtol_mm : float
        The bisection's tolerance on the deviation (mm).

    Returns
    -------
    pandas.DataFrame
        One row per parameter and side: ``param``, ``side`` (upper/lower),
        ``largest_delta_mm`` (signed: negative on the lower side) and ``reaches_max``.
    """
    base = nominal.override(guide_shift_um=guide_shift_um)
    c0, _ = nm.columns(base)
    grid = np.geomspace(1e-3, max_mm, 25)
    jobs = [(p, s) for p in params for s in (1.0, -1.0)]
    jm = len(jobs)

    def totals(deltas):
        """SumDelta(beta*) of machine k = job k % jm at |deviation| deltas[k]."""
        deltas = np.asarray(deltas, float)
        c = nm.repeat(c0, deltas.size)  # fresh arrays, safe to change in place
        job = np.arange(deltas.size) % jm
        for j, (p, s) in enumerate(jobs):
            rows = job == j
            c[p][rows, 0] = c[p][rows, 0] + s * deltas[rows]
        return sb.optimise_beta_columns(c, range_deg, limit_um, window=False).total_um

    # grid: every job at every grid value in one batch
    tot = totals(np.repeat(grid, jm)).reshape(grid.size, jm)
    exceed = ~(tot <= limit_um)
    first = np.where(exceed.any(axis=0), exceed.argmax(axis=0), -1)
    lo = np.where(first > 0, grid[np.maximum(first - 1, 0)], 0.0)
    hi = np.where(first >= 0, grid[np.maximum(first, 0)], max_mm)
    edge = bisect_root(lambda d: totals(d) - limit_um, lo, hi, xtol=xtol_mm)
    edge = np.where(first >= 0, edge, max_mm)
    return pd.DataFrame({
        "param": [p for p, _ in jobs], "side": ["upper" if s > 0 else "lower" for _, s in jobs],
        "largest_delta_mm": [s * e for (_, s), e in zip(jobs, edge, strict=True)],
        "reaches_max": first < 0,
    })
