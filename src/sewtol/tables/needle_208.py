"""The needle's tables of the generic studies: a `Needle208` as a protocol mechanism, and the
scan, worst case and largest tolerances (sewtol.studies.scan, sewtol.studies.worst_case), the
Monte-Carlo (sewtol.studies.montecarlo: beta fixed at the nominal's beta* and re-optimised
per machine, each failure named by needle_208.status), the strategies table
(sewtol.studies.strategies), Sobol indices, the rare-event limit state and the allocation
(sewtol.studies.sobol, rare_event, allocation) in the source study's columns and words.

The studies run on `as_mechanism(nominal)` (the folder's mechanism.toml with the machine's
values as nominals) and so on the needle's plug-ins (fast_path.py): SumDelta exactly by the
fused kernel, beta (and the guide shift) by the exact sliding-window optimum, any strategy by
needle_208.adjustment. This module only names their figures as the source did: beta_deg (beta*,
the adjusted beta; or the machine's own where a strategy does not set it), plus_um, minus_um,
total_um (Delta+, Delta-, SumDelta at the settings), beta_at_bound (beta*'s plateau reaches
an end of its range), NAME_mm (deviations).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.measurement_error import MeasurementError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.adjustment import STATUSES, Adjustment, adjust, columns_of
from sewtol.mechanisms.needle_208.single import nominal_figures
from sewtol.studies import montecarlo as MC
from sewtol.studies.montecarlo import (
    CHUNK,
    MonteCarloResult,
    check_sampling,
    contributors,
    draw_deviations,
)
from sewtol.studies.settings import Setting, compare
from sewtol.tolerances import Tolerance, ToleranceSet, needle_set

if TYPE_CHECKING:
    from distributed import Client

    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.studies.allocation import Allocation
    from sewtol.studies.checkpoint import ChunkStore
    from sewtol.studies.rare_event import LimitState
    from sewtol.studies.sobol import SobolResult

OUTPUT = "SumDelta_um"
# 2**14 corners: the built-in sets with the housing (recommended_housing has 14 tolerances)
MAX_CORNER_PARAMS = 14
FIGURES = ("plus_um", "minus_um", "total_um")


@cache
def _file():
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    return load(mechanism_file("needle_208"))


def as_mechanism(params: Needle208):
    """The needle drive `params` (scalar fields) as a protocol mechanism: the folder's
    mechanism.toml (fast_path needle_208) with the machine's values as its nominals."""
    return _file().override(**{k: float(getattr(params, k)) for k in P.field_names(type(params))})


def _beta_box(range_deg, limit_um=sb.DEFAULT_LIMIT_UM) -> dict:
    sb.check_range(range_deg, limit_um)
    return {"beta": tuple(map(float, range_deg))}


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
        """The rows as dicts (the JSON rows of ``sewtol needle scan``)."""
        return self.rows.to_dict(orient="records")


def _figures(a, base, strategy) -> dict:
    """The needle's columns of an adjusted batch (sewtol.studies.adjusting.Adjusted): with beta
    set, also its plateau beta_low_deg .. beta_high_deg (SumDelta within 1e-3 um of the
    optimum; beta_deg is its centre), which beta_at_bound says reaches an end of the range."""
    n, sets_beta = len(a.value), strategy is None or "beta" in strategy.names
    beta = a.settings["beta"] if sets_beta else np.full(n, base.beta)
    plateau = {}
    if sets_beta and "low" in a.extras and "beta" in a.extras["low"]:
        plateau = {"beta_low_deg": a.extras["low"]["beta"],
                   "beta_high_deg": a.extras["high"]["beta"]}
    f = {"beta_deg": beta, **plateau,
         **{k: a.extras[k] for k in FIGURES},
         "beta_at_bound": (np.asarray(a.at_bound["beta"], bool) if strategy is None
                           else a.at_bound["beta"]) if sets_beta else np.zeros(n, bool)}
    if strategy is None:
        return f
    f.update({f"{k}_setting": a.settings[k] for k in strategy.names if k != "beta"})
    f["status"] = a.status
    return f


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
        (the parameter's value), ``beta_deg`` (beta*, the centre of its plateau),
        ``beta_low_deg`` and ``beta_high_deg`` (the plateau: every beta there gives SumDelta
        within 1e-3 um of the optimum), ``plus_um``, ``minus_um`` and ``total_um`` (Delta+,
        Delta-, SumDelta) and ``beta_at_bound`` (the plateau reaches an end of range_deg:
        SumDelta is flat up to that end and may stay flat or fall beyond it);
        ``nominal_row`` the same for the nominal.
    """
    from sewtol.studies import scan as S

    tolerances = needle_set(tolerances)
    if guide_shift_um is None:
        guide_shift_um = float(nominal.guide_shift_um)
    base = nominal.override(guide_shift_um=guide_shift_um)
    if strategy is None:
        comps, options = _beta_box(range_deg, limit_um), {}
    else:
        comps, options = strategy.compensators, {"limit_um": limit_um}
    r = S.scan(as_mechanism(base), tolerances, (), comps, OUTPUT, zero_width=True, **options)
    values = [float(r.values[p][i]) for i, p in enumerate(r.params)]
    rows = pd.DataFrame({"param": r.params, "side": r.sides, "delta_mm": r.deviations,
                         "value_mm": values, **_figures(r.adjusted, base, strategy)})
    nominal_row = {k: (str(v[0]) if k == "status" else bool(v[0]) if k == "beta_at_bound"
                       else float(v[0]))
                   for k, v in _figures(r.adjusted_nominal, base, strategy).items()}
    return ScanResult(rows, nominal_row, tolerances.name, float(guide_shift_um), float(limit_um),
                      "beta" if strategy is None else strategy.name)


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
    from sewtol.studies import scan as S

    base = nominal.override(guide_shift_um=guide_shift_um)
    t = S.largest_tolerances(as_mechanism(base), params, OUTPUT, limit_um,
                             _beta_box(range_deg, limit_um), max_mm, xtol_mm, figure="total_um")
    return t.rename(columns={"largest_deviation": "largest_delta_mm"})


def worst_case(nominal, tolerances: ToleranceSet | str, adjust: bool,
               range_deg=sb.DEFAULT_RANGE_DEG, starts: int = 3, strategy=None) -> dict:
    """The worst SumDelta over the tolerance box (sewtol.studies.worst_case, the best `starts`
    corners polished, a machine that cannot run counting as the worst): beta fixed as in
    `nominal` (adjust=False), beta re-optimised per trial machine (adjust=True), or, with
    adjust=True and a strategy, the joint optimum over the strategy's compensators.

    Returns the row of `worst_case_table`: case, total_um, worst_corner_total_um, beta_deg,
    beta_at_bound (the worst machine's adjusted beta* on an end of the searched range),
    interior (the worst point is not a corner) and the deviation NAME_mm per parameter."""
    from sewtol.studies import worst_case as W

    tolerances = needle_set(tolerances)
    if len(tolerances.active().params) > MAX_CORNER_PARAMS:
        raise ParameterError("tolerances", "worst case enumerates corners; at most "
                             f"{MAX_CORNER_PARAMS} parameters",
                             len(tolerances.active().params))
    comps, options = None, {}
    if adjust:
        comps = _beta_box(range_deg) if strategy is None else strategy.compensators
        options = {} if strategy is None else {"plateaus": False}
    search = W.Search(starts=starts, maxiter=200, step=None, eps=1e-6, failures="worst")
    r = W.worst_case(as_mechanism(nominal), tolerances, OUTPUT, adjust=comps, extremes=("max",),
                     search=search, axes=False, **options)
    e = r.extremes[0]
    sets_beta = adjust and (strategy is None or "beta" in strategy.names)
    beta = float(e.adjusted.settings["beta"][0]) if sets_beta else float(nominal.beta)
    at_bound = bool(e.adjusted.at_bound["beta"][0]) if sets_beta else False
    case = "fixed_beta" if not adjust else \
        "adjusted_beta" if strategy is None else f"adjusted_{strategy.name}"
    return {"case": case, "total_um": e.value, "worst_corner_total_um": e.corner_value,
            "beta_deg": beta, "beta_at_bound": at_bound, "interior": e.interior,
            **{f"{k}_mm": v for k, v in e.point.items()}}


def worst_case_table(nominal: Needle208, tolerances: ToleranceSet | str,
                     range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                     strategy: Strategy | None = None) -> pd.DataFrame:
    """The worst SumDelta over the tolerance box, with beta fixed and after adjustment.

    Every corner of the box and its centre are evaluated as one batch; the three worst are
    polished by L-BFGS-B inside the box, so a worst point inside the box is found too.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters); its beta* is the fixed case's beta.
    tolerances : ToleranceSet or str
        The box: every tolerance between its lower and upper limit.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    strategy : Strategy or None
        The adjusted case: None for beta re-optimised, or a strategy's joint optimum.

    Returns
    -------
    pandas.DataFrame
        Rows ``fixed_beta`` and the adjusted case, with ``total_um`` (the worst SumDelta),
        ``worst_corner_total_um``, ``beta_deg``, ``interior`` (True when the worst point is not
        a corner) and the worst point's deviation per parameter (``NAME_mm``).
    """
    tolerances = needle_set(tolerances)
    return pd.DataFrame([worst_case(nominal, tolerances, a, range_deg,
                                    strategy=strategy if a else None) for a in (False, True)])


def strategy_setting(strategy: Strategy) -> tuple[str, str]:
    """(resolution, setting error) of a strategy's row: ``NAME VALUE UNIT`` per compensator that
    has one, "none" where all are exact."""
    from sewtol import setting_error as se

    res = [f"{c.name} {c.resolution:g} {c.unit}".rstrip() for c in strategy.compensators
           if c.resolution]
    err = [f"{c.name} {se.label(c.setting_error, c.unit)}" for c in strategy.compensators
           if c.setting_error is not None]
    return "; ".join(res) or "none", "; ".join(err) or "none"


def summarise_frame(machines: pd.DataFrame, strategy: Strategy, limit_um: float) -> pd.DataFrame:
    """The row of the strategies table (counts, yield and interval, SumDelta quantiles, Cpk,
    at-limit shares, achieved yield, distinct settings) of a per-machine table written by
    Adjustment.to_dataframe()."""
    total = machines["total_after_um"].to_numpy(float)
    status, achieved = machines["status"].to_numpy(), machines["achieved_um"].to_numpy(float)
    at_limit = {c.name: machines[f"{c.name}_at_limit"].to_numpy(bool)
                for c in strategy.compensators}
    n = total.size
    counts = {s: int(np.sum(status == s)) for s in STATUSES}
    if sum(counts.values()) != n:
        raise ParameterError("status", f"must be one of {', '.join(STATUSES)} for every machine",
                             sorted(set(status) - set(STATUSES)))
    k = counts["ok"]
    ci_low, ci_high = clopper_pearson(k, n)
    x = np.where(np.isfinite(total), total, np.inf)
    q = {f"p{p}_um": float(np.quantile(x, p / 100, method="higher")) for p in (50, 95, 99)}
    run = total[np.isfinite(total)]
    if run.size >= 2 and np.std(run, ddof=1) > 0:
        cpk = float((limit_um - run.mean()) / (3 * np.std(run, ddof=1)))
    else:
        cpk = float("nan")
    row = {"strategy": strategy.name, **dict(zip(("resolution", "setting_error"),
                                                  strategy_setting(strategy), strict=True)),
           "n": n, "ok": k,
           "out_of_spec": counts["out of spec"], "cannot_assemble": counts["cannot assemble"],
           "dead_point": counts["dead point"], "yield": k / n, "yield_ci_low": ci_low,
           "yield_ci_high": ci_high, **q, "Cpk": cpk}
    ok = status == "ok"
    any_limit = np.zeros(n, bool)
    for comp in strategy.compensators:
        any_limit |= at_limit[comp.name]
    row["at_limit_share"] = float(any_limit.mean())
    for comp in strategy.compensators:  # one column per compensator: its share at an end
        row[f"at_limit_{comp.name}"] = float(np.mean(at_limit[comp.name]))
    # the combined text the committed reports (strategies.csv/.md, report.html) were made with
    row["at_limit"] = ", ".join(f"{c.name} {np.mean(at_limit[c.name]):.1%}"
                                for c in strategy.compensators)
    row["achieved_yield"] = float(np.mean(achieved <= limit_um))
    setting = {c.name: next(k for k in machines.columns if k.startswith(f"{c.name}_setting"))
               for c in strategy.compensators}
    row["distinct_settings"] = ", ".join(
        f"{c.name} {np.unique(np.round(machines[setting[c.name]].to_numpy(float)[ok], 9)).size}"
        for c in strategy.compensators if c.discrete)
    return pd.DataFrame([row])


@dataclass(frozen=True)
class StrategiesResult:
    """The strategies table, the per-machine adjustments and the deviations they share."""

    deviations: pd.DataFrame
    adjustments: tuple[Adjustment, ...]
    params: tuple[str, ...]
    tolerances: str
    seed: int
    limit_um: float
    limits: dict  # param -> (lower, upper) deviation limits of the tolerance set
    # the reading the compensators were set from (sewtol.measurement_error label; none: the
    # true deviation)
    measurement: str = "none"

    @property
    def n(self) -> int:
        return len(self.deviations)

    def to_dataframe(self) -> pd.DataFrame:
        """One row per strategy; at_limit_NAME (the share of machines with compensator NAME at
        an end of its range) sits after at_limit_share, NaN in a row without NAME;
        measurement_error after setting_error (none in a row that sets nothing)."""
        table = pd.concat([summarise_frame(a.to_dataframe(), a.strategy, a.limit_um)
                           for a in self.adjustments], ignore_index=True)
        table.insert(list(table.columns).index("setting_error") + 1, "measurement_error",
                     [self.measurement if a.strategy.compensators else "none"
                      for a in self.adjustments])
        split = [f"at_limit_{c.name}" for a in self.adjustments for c in a.strategy.compensators]
        split = list(dict.fromkeys(split))
        rest = [c for c in table.columns if c not in split]
        at = rest.index("at_limit_share") + 1
        return table[rest[:at] + split + rest[at:]]

    def machines(self, strategy: str) -> pd.DataFrame:
        """Deviations, criterion before and after, settings, at-limit flags and status."""
        adj = self.get(strategy)
        f = self.deviations.copy()
        f.insert(0, "machine", np.arange(self.n))
        return pd.concat([f, adj.to_dataframe()], axis=1)

    def get(self, strategy: str) -> Adjustment:
        for a in self.adjustments:
            if a.strategy.name == strategy:
                return a
        names = [a.strategy.name for a in self.adjustments]
        raise ParameterError("strategy", f"not in this table; rows are {', '.join(names)}",
                             strategy)

    def failure_contributors(self, strategy: str, bins: int = 10) -> pd.DataFrame:
        """Which tolerances drive the machines still out of spec after adjustment.

        Two views side by side: the correlation-ratio shares (montecarlo.contributors) of the
        adjusted SumDelta over all machines that run and over the out-of-spec ones alone, and
        the conditional shift of each deviation: the mean of (deviation - mid) / half-width
        over the failing machines, with mid and half-width those of the tolerance (about 0 for a
        tolerance that does not matter, towards +/-1 for one whose limit the failures sit at),
        and the mean |z| over the failing machines next to that over all machines.
        """
        adj = self.get(strategy)
        frame = self.deviations.copy()
        frame["total_after_um"] = adj.total_um
        fail = adj.status == "out of spec"
        out = pd.DataFrame({"param": list(self.params)})
        all_c = contributors(frame, self.params, "total_after_um", bins).set_index("param")
        out["share_all_pct"] = out.param.map(all_c["share_pct"])
        if fail.sum() > bins + 1:
            f_c = contributors(frame[fail], self.params, "total_after_um", bins).set_index("param")
            out["share_failing_pct"] = out.param.map(f_c["share_pct"])
        else:
            out["share_failing_pct"] = np.nan
        lo, hi = np.array([self.limits[p] for p in self.params]).T[:, :, None]
        z = (frame[list(self.params)].to_numpy().T.copy() - 0.5 * (hi + lo)) / (0.5 * (hi - lo))
        out["mean_z_failing"] = z[:, fail].mean(axis=1) if fail.any() else np.nan
        out["mean_abs_z_failing"] = np.abs(z[:, fail]).mean(axis=1) if fail.any() else np.nan
        out["mean_abs_z_all"] = np.abs(z).mean(axis=1)
        out.insert(1, "n_failing", int(fail.sum()))
        return out.sort_values("mean_abs_z_failing", ascending=False, na_position="last") \
            .reset_index(drop=True)


def strategies_table(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                     strategies: list[Strategy] | None = None, limit_um: float = 10.0,
                     n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
                     measurement: MeasurementError | None = None) -> StrategiesResult:
    """`sewtol needle strategies`: the strategies study (sewtol.studies.strategies) of the same
    n machines (one draw from `seed`) on `as_mechanism(nominal)`, each strategy's joint optimum
    by the needle's strategy adjuster (needle_208.adjustment), in the source's columns.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        What the machines draw from.
    n : int
        Machines (>= 2), the same for every strategy.
    seed : int
        The seed of the one draw (>= 0).
    strategies : list of Strategy or None
        The rows; None: none, beta, beta+shift, beta+shift+angle, beta+CD and all, with the
        built-in compensator ranges.
    limit_um : float
        The SumDelta limit (um).
    n_jobs : int
        Worker processes (chunks of machines; the same numbers for any n_jobs).
    progress : bool or callable
        A progress bar, or a callback progress(done, total).
    measurement : sewtol.measurement_error.MeasurementError or None
        Set the compensators from a reading of the needle bar's deviation with this error
        (None or sd 0: from the true deviation, as before).

    Returns
    -------
    StrategiesResult
        ``to_dataframe()``: per strategy the counts (ok, out of spec, cannot assemble, dead
        point; they add up to n), the yield and its interval, SumDelta quantiles (um), Cpk,
        at-limit shares and distinct settings; ``machines(name)`` per machine.
    """
    from sewtol.mechanism.spec import Spec
    from sewtol.mechanisms.needle_208.compensators import default_strategies
    from sewtol.studies import strategies as ST

    tolerances = needle_set(tolerances)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    tol = tolerances.active()
    strategies = default_strategies() if strategies is None else strategies
    names = [s.name for s in strategies]
    if len(set(names)) != len(names):
        raise ParameterError("strategies", "names a strategy twice", names)
    valid = list(columns_of(nominal, {t.param: np.zeros(1) for t in tol.items}))
    strategies = [s.check_names(valid) for s in strategies]
    r = ST.strategies(as_mechanism(nominal), tolerances, n, seed,
                      {s.name: s for s in strategies}, OUTPUT, Spec(OUTPUT, float(limit_um)),
                      n_jobs=n_jobs, progress=progress, limit_um=limit_um,
                      measurement=measurement)
    adjs = tuple(Adjustment(s, float(limit_um), a.extras["total_before_um"], a.value,
                            a.extras["plus_um"], a.extras["minus_um"], a.extras["achieved_um"],
                            a.status, a.settings, a.extras["low"], a.extras["high"],
                            a.extras["at_limit"]) for s, a in zip(strategies, r.adjusted,
                                                                  strict=True))
    return StrategiesResult(pd.DataFrame(r.deviations), adjs, tuple(tol.params), tolerances.name,
                            int(seed), float(limit_um),
                            {t.param: (t.lower, t.upper) for t in tol.items}, r.measurement)


def adjusted_montecarlo_model(nominal, dev, strategy: Strategy, limit_um: float):
    """Model for montecarlo.sample_machines: the per-machine table of one strategy."""
    adj = adjust(columns_of(nominal, dev), strategy, limit_um)
    f = adj.to_dataframe()
    return {k: f[k].to_numpy() for k in f.columns}


# fixed_beta -> what the generic Monte-Carlo holds beta at in the fixed case (its `hold`)
FIXED_BETA = {"optimum": "optimum", "as_given": "nominal"}
FIXED_BETA_MEANS = {
    "optimum": "every machine keeps the nominal machine's beta* in the searched range (as "
               "`sewtol needle nominal` prints it for the same parameters)",
    "as_given": "every machine keeps the nominal's own beta parameter"}


def held(nominal, fixed_beta: str, range_deg):
    """`as_mechanism(nominal)` with beta where the fixed case keeps it: "optimum" the nominal
    machine's beta* in range_deg (studies.montecarlo.at_optimum; what `sewtol needle nominal`
    prints), "as_given" the nominal's own beta."""
    if fixed_beta not in FIXED_BETA:
        raise ParameterError("fixed_beta", f"must be one of {', '.join(FIXED_BETA)}", fixed_beta)
    mech = as_mechanism(nominal)
    return MC.at_optimum(mech, _beta_box(range_deg), OUTPUT) if fixed_beta == "optimum" else mech


def montecarlo(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
               limit_um: float = 10.0, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
               n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
               backend: str | None = None, chunk_size: int = CHUNK,
               store: ChunkStore | None = None, fixed_beta: str = "optimum",
               scheduler: str | Client | None = None) -> MonteCarloResult:
    """N machines in chunks of chunk_size, chunk i drawing from child i of the seed.

    The fixed case keeps every machine at the nominal machine's beta* (fixed_beta="optimum",
    the default) or at the nominal's own beta parameter (fixed_beta="as_given"); the adjusted case
    re-optimises beta per machine in range_deg. With a ChunkStore (studies.checkpoint) finished
    chunks are saved as they arrive and an interrupted study resumes without recomputing them.
    progress: True (bar on stderr) or a callable progress(done, total) in chunks; scheduler: run
    on a Dask cluster (address or distributed.Client), same machines as a local run.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters); machines deviate from it.
    tolerances : ToleranceSet or str
        What each machine's parameters draw from (deviations in mm, deg or um).
    n : int
        The number of machines (>= 1).
    seed : int
        The seed (>= 0; 0 is a seed). Chunk i draws from child i of
        ``numpy.random.default_rng(seed)`` (``spawn``).
    limit_um : float
        The SumDelta limit (um) a machine must keep to count as ok; default 10.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg; default (10, 35).
    n_jobs : int
        Workers on this machine (threads of this process: the needle's kernels release the
        GIL, `studies.montecarlo.gil_free`); the tables do not depend on it.
    progress : bool or callable
        True: a bar on stderr; a callable ``progress(done, total)`` is called as chunks finish.
    backend : str or None
        A joblib backend (e.g. ``"dask"`` inside a ``distributed.Client()``); None: threads
        with n_jobs > 1.
    chunk_size : int
        Machines per chunk; part of the study's identity (another chunk size draws other
        machines).
    store : ChunkStore or None
        A study folder (``studies.checkpoint.ChunkStore``) that saves finished chunks and
        resumes an interrupted study.
    fixed_beta : str
        ``"optimum"``: the fixed case is the nominal machine's beta*; ``"as_given"``: the
        nominal's own ``beta`` parameter.
    scheduler : str, distributed.Client or None
        A Dask scheduler address or client: the chunks run on that cluster.

    Returns
    -------
    MonteCarloResult
        Every machine with its deviations, SumDelta (um) in both cases (total_fixed_um,
        total_adjusted_um), beta* (beta_opt_deg) and status (fast_path.COLUMNS); yields,
        counts, quantiles and capability per case (fixed_beta, adjusted_beta; "fixed" and
        "adjusted" name them too); ``extra`` holds limit_um, nominal_beta_deg (the fixed case's
        beta), fixed_beta and beta_search_range_deg.

    Raises
    ------
    ParameterError
        For a bad n, seed, limit, range or tolerance set (before anything runs).

    Examples
    --------
    >>> import sewtol
    >>> res = sewtol.montecarlo(sewtol.Needle208.nominal(), sewtol.tolerance_set("base"),
    ...                         n=200, seed=2026)
    >>> c = res.counts("adjusted")
    >>> c["ok"] + c["out_of_spec"] + c["failed"] == 200
    True
    """
    tolerances = needle_set(tolerances)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    sb.check_range(range_deg, limit_um)
    check_sampling(nominal, tolerances, n, seed, chunk_size,
                   bytes_per_row=MC.montecarlo_bytes(1, 1))
    if fixed_beta not in FIXED_BETA:
        raise ParameterError("fixed_beta", f"must be one of {', '.join(FIXED_BETA)}", fixed_beta)
    r = MC.montecarlo(as_mechanism(nominal), tolerances, n, seed, [OUTPUT], limit_um,
                      n_jobs=n_jobs, progress=progress, chunk_size=chunk_size,
                      adjust={"beta": tuple(map(float, range_deg))}, fast=True,
                      backend=backend, store=store, scheduler=scheduler,
                      hold=FIXED_BETA[fixed_beta])
    return replace(r, summary="cases",
                   extra={"limit_um": float(limit_um), "nominal_beta_deg": r.held["beta"],
                          "fixed_beta": fixed_beta, "fixed_beta_means": FIXED_BETA_MEANS[fixed_beta],
                          "beta_search_range_deg": list(map(float, range_deg))})


def needle_sobol(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                 range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG, n_jobs: int = 1,
                 progress: bool | Callable[[int, int], None] = False,
                 backend: str | None = None, resamples: int = 200,
                 chunk_size: int | None = None, store: ChunkStore | None = None,
                 conf_level: float = 0.95, fixed_beta: str = "optimum",
                 limit_um: float = sb.DEFAULT_LIMIT_UM,
                 scheduler: str | Client | None = None,
                 strategy: Strategy | None = None,
                 second_order: bool = False) -> SobolResult:
    """Sobol indices of SumDelta, beta fixed and beta adjusted, at n and n/2 base samples
    (sewtol.studies.sobol.sobol on `as_mechanism`; a machine that does not run is counted under
    studies.sobol.POLICY with its reason and dyad at the fixed beta).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        The inputs: each tolerance is one factor with its distribution.
    n, seed : int
        Base samples, a power of 2 (>= 16; n (k + 2) machines for k factors, per case) and the
        seed of the scrambled Sobol' sample and the bootstrap (>= 0; 0 is a seed).
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    n_jobs, progress, backend, chunk_size, store, scheduler : see studies.sobol.sobol
        How the model runs (workers, a bar or ``progress(done, total)``, a joblib backend,
        runs per chunk, a resumable study folder, a Dask cluster); no index depends on them.
    resamples, conf_level : int, float
        The bootstrap resamples and the confidence level of the intervals.
    fixed_beta : str
        The fixed case's beta, as in `montecarlo`: ``"optimum"`` (the nominal's beta*) or
        ``"as_given"`` (its ``beta`` parameter).
    limit_um : float
        The SumDelta limit (um) of the beta search and the strategy's status.
    strategy : Strategy or None
        The adjusted case: None for beta re-optimised in range_deg ("adjusted_beta"), or the
        strategy's exact joint optimum ("adjusted_" + its name).
    second_order : bool
        True: the design of n (2k + 2) machines per case and the S2 of every pair.

    Returns
    -------
    SobolResult
        S1 and ST with their confidence half-widths per parameter and case, at n and n/2,
        and the convergence table (with second_order, the S2 pairs and max |dS2|).
    """
    from sewtol.studies import sobol as S

    tolerances = needle_set(tolerances)
    S.check_sobol(nominal, tolerances, n, seed, second_order)
    sb.check_range(range_deg, limit_um)
    if strategy is None:
        adjusted, comps, options = "adjusted_beta", _beta_box(range_deg, limit_um), {}
    else:
        adjusted = "adjusted_" + strategy.name
        comps, options = strategy.compensators, {"limit_um": limit_um, "plateaus": False}
    return S.sobol(held(nominal, fixed_beta, range_deg), tolerances, OUTPUT, n, seed,
                   cases={"fixed_beta": None, adjusted: comps}, resamples=resamples,
                   conf_level=conf_level, second_order=second_order, n_jobs=n_jobs,
                   progress=progress, backend=backend, chunk_size=chunk_size or S.CHUNK,
                   store=store, scheduler=scheduler, **options)


ADJUSTMENTS = ("none", "beta")
# the rare-event failure modes in the needle's words: a dyad misses at the mechanism's beta, or
# else a dyad passes within the dead-point angle (or no beta in the range assembles it)
LIMIT_STATE_MODES = {"cannot_close": "cannot assemble", "dead_point": "dead point",
                     "unexplained": "dead point"}


def needle_limit_state(nominal: Needle208, tolerances: ToleranceSet | str, limit_um: float = 10.0,
                       adjust: str = "beta",
                       range_deg: tuple[float, float] | None = None) -> LimitState:
    """SumDelta of the 208 needle drive after the assembly adjustment, as a LimitState
    (sewtol.studies.rare_event.limit_state on `as_mechanism`).

    adjust "beta": beta re-optimised per machine in range_deg (total_adjusted_um); "none": beta
    left at the nominal beta* (total_fixed_um). A machine without a value is "cannot assemble"
    (a dyad misses at the nominal beta) or else "dead point" (a dyad passes within the dead-point
    angle, or no beta in the range assembles it).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        The inputs, mapped from independent standard normals through each tolerance's
        distribution.
    limit_um : float
        A machine fails when its SumDelta exceeds this (um), or when it cannot run.
    adjust : str
        ``"beta"`` (beta re-optimised per machine) or ``"none"`` (beta at the nominal's beta*).
    range_deg : tuple of float or None
        The regulating range for beta, (low, high) in deg; None: (10, 35).

    Returns
    -------
    LimitState
        The failure event for `estimate`, with failure modes ``"cannot assemble"`` and
        ``"dead point"`` and the deviations (mm) of failing machines.

    Raises
    ------
    ParameterError
        For an unknown adjustment, a non-positive limit, or a set without any tolerance.
    """
    from sewtol.studies.rare_event import limit_state

    tolerances = needle_set(tolerances)
    if adjust not in ADJUSTMENTS:
        raise ParameterError("adjust", f"must be one of {', '.join(ADJUSTMENTS)}", adjust)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    range_deg = sb.DEFAULT_RANGE_DEG if range_deg is None else tuple(map(float, range_deg))
    beta = adjust == "beta"
    return limit_state(as_mechanism(nominal), tolerances, OUTPUT, float(limit_um),
                       adjust={"beta": range_deg} if beta else None,
                       name="total_adjusted_um" if beta else "total_fixed_um",
                       modes=LIMIT_STATE_MODES)


# the needle's names of the allocation's columns (studies.allocation.Allocation.to_dataframe)
ALLOCATION_COLUMNS = {"param": "param", "cost_weight": "cost_weight",
                      "slope_um_per_mm": "slope_um_per_mm", "lower": "lower_mm",
                      "upper": "upper_mm", "reference_lower": "reference_lower_mm",
                      "reference_upper": "reference_upper_mm"}


def allocate(nominal: Needle208, reference: ToleranceSet | str, target: float = 0.9973,
             n: int = 2000, seed: int = 0, costs: dict[str, float] | None = None,
             max_mm: float = 1.0, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
             steps: int | None = None, strategy: Strategy | None = None,
             limit_um: float = sb.DEFAULT_LIMIT_UM) -> Allocation:
    """The widest tolerances that keep the yield after adjustment at a target.

    Cost is reciprocal, sum c_i / t_i; the shape t_i ~ (c_i / s_i^2)^(1/3) (s_i the slope of
    the adjusted SumDelta at the reference limits from the scan, um per mm, each tolerance
    alone) is the root-sum-square optimum; the common scale of the shapes is
    sewtol.studies.allocation.allocate's (bisection on the Monte-Carlo yield after adjustment
    per machine, common random numbers: one uniform matrix for every trial scale).

    strategy None (beta re-optimised in range_deg, the source study's allocation): symmetric
    tolerances +/- t_i, slopes per the larger side of each reference tolerance, the scale (mm,
    the widest tolerance) bisected in (0, max_mm). A strategy: its exact joint optimum; each
    reference tolerance keeps its own (possibly asymmetric) shape, both limits scaled by
    min(k a_i, max_mm) / h_i (h_i its half-width, slopes per h_i), k bisected geometrically
    (it spans decades) up to where every tolerance reaches max_mm. A tolerance the strategy
    cancels alone at its reference limits (SumDelta within 1e-3 um of the nominal's at both,
    e.g. the guide bore's position under the guide shift) is held at its reference limits
    (``held_at_reference``), not scaled.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    reference : ToleranceSet or str
        Which parameters to allocate, and the limits at which the slopes are taken.
    target : float
        The yield to keep, strictly between 0 and 1; default 0.9973 (+/-3 sigma).
    n, seed : int
        Monte-Carlo machines per trial scale and the seed of their common random numbers.
    costs : dict or None
        Cost weight c_i per parameter (> 0); a parameter not named weighs 1.
    max_mm : float
        The cap on any tolerance (mm); insensitive parameters end there.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg (strategy None).
    steps : int or None
        Bisection steps on the scale; None: 12 (strategy None) or 10 (a strategy).
    strategy : Strategy or None
        The assembler's adjustment; None: beta alone in range_deg.
    limit_um : float
        The SumDelta limit (um) of the yield.

    Returns
    -------
    sewtol.studies.allocation.Allocation
        ``to_dataframe()`` per parameter ``cost_weight``, ``slope_um_per_mm``, the allocated
        limits (``tolerance_mm``, the +/- limit, for strategy None; ``lower_mm`` and
        ``upper_mm`` with a strategy) and the reference limits; ``yield_`` the yield after
        adjustment (1 when no scale above 0 keeps the target), ``scale``, ``target``, ``n``,
        ``seed``; ``as_tolerance_set()`` the allocated limits (uniform) for further studies.

    Raises
    ------
    ParameterError
        For a target outside (0, 1) or a non-positive cost weight.
    """
    from sewtol.studies import allocation as A

    reference = needle_set(reference)
    if not (0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    ref = reference.active()
    A.refuse_relations(ref)
    names = ref.params
    costs = costs or {}
    c = np.array([float(costs.get(p, 1.0)) for p in names])
    if np.any(c <= 0):
        raise ParameterError("costs", "must be positive weights", costs)
    sc = scan(nominal, ref, range_deg=range_deg, strategy=strategy, limit_um=limit_um)
    slope = []
    for t in ref.items:
        width = max(abs(t.upper), abs(t.lower)) if strategy is None else 0.5 * (t.upper - t.lower)
        r = sc.rows[sc.rows["param"] == t.param]["total_um"].to_numpy()
        worst = np.nanmax(np.abs(r - sc.nominal_row["total_um"]))
        slope.append(float(worst) / width if np.isfinite(worst) else np.inf)
    s = np.clip(np.array(slope), 1e-9, 1e12)
    shape = (c / s**2) ** (1.0 / 3.0)
    shape = shape / shape.max()
    mech = as_mechanism(nominal)
    if strategy is None:
        # the scale k (mm) of the shapes (the largest 1), searched in (0, max_mm): no tolerance
        # exceeds max_mm
        # the copula ties ranks, whatever the widths: every trial keeps the set's dependence
        shapes = ToleranceSet(reference.name, tuple(Tolerance(p, -a, a) for p, a in
                                                    zip(names, shape, strict=True)),
                              dependence=ref.dependence)
        a = A.allocate(mech, shapes, OUTPUT, target, limit_um, None, n, seed,
                       adjust=_beta_box(range_deg), bracket=(0.0, max_mm),
                       steps=12 if steps is None else steps)
        columns = {**ALLOCATION_COLUMNS, "upper": "tolerance_mm"}
        del columns["lower"]
    else:
        half = np.array([0.5 * (t.upper - t.lower) for t in ref.items])
        # a tolerance the strategy cancels alone at its reference limits (within the plateau
        # tolerance, e.g. the guide bore's position under the guide shift) has no slope to
        # shape it: scaled like the others it would take the cap at once and use up the
        # compensator's range the others need (the housing sets: every other tolerance fell to
        # 1e-9 mm), so it is held at its reference limits and the rest are allocated
        held = np.array(slope) * half < 1e-3
        if held.all():
            held[:] = False
        free = (c / s**2) ** (1.0 / 3.0)
        shape = np.where(held, np.nan, free)
        shape = np.where(held, half, shape / np.nanmax(shape))

        def limits(k):
            f = np.where(held, half, np.minimum(k * shape, max_mm)) / half
            return ToleranceSet("trial", tuple(Tolerance(t.param, t.lower * fi, t.upper * fi)
                                               for t, fi in zip(ref.items, f, strict=True)),
                                dependence=ref.dependence)

        # k up to where every tolerance reaches the cap, so the cap never ends the search early
        a = A.allocate(mech, ref, OUTPUT, target, limit_um, None, n, seed,
                       adjust=strategy.compensators, bracket=(0.0, float(max_mm / shape[~held].min())),
                       steps=10 if steps is None else steps, geometric=True, limits=limits,
                       limit_um=limit_um, plateaus=False)
        columns = {**ALLOCATION_COLUMNS, "held_at_reference": "held_at_reference"}
    table = a.table.assign(cost_weight=c, slope_um_per_mm=s,
                           reference_lower=[t.lower for t in ref.items],
                           reference_upper=[t.upper for t in ref.items])
    if strategy is not None:
        table = table.assign(held_at_reference=held)
    return replace(a, table=table, columns=columns, yield_=a.yield_ if a.scale > 0 else 1.0,
                   adjust="beta" if strategy is None else strategy.name)


# --- guide settings compared (the needle's instance of sewtol.studies.settings) ------------

DEFAULT_VARIANTS = (
    ("nominal", 0.0, 0.0),
    ("shift +50 um", 50.0, 0.0),
    ("shift -50 um", -50.0, 0.0),
    ("angle +0.02 deg", 0.0, 0.02),
    ("angle -0.02 deg", 0.0, -0.02),
)


def compare_guides(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                   variants: Sequence[tuple[str, float, float]] = DEFAULT_VARIANTS,
                   range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                   n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
                   scheduler: str | Client | None = None, strategy: Strategy | None = None,
                   limit_um: float = sb.DEFAULT_LIMIT_UM) -> pd.DataFrame:
    """One row per guide setting (shift um along the guide normal, turn deg about its point).

    Every setting sees the same machines (the ones `montecarlo` draws from the seed), so the
    rows differ by the guide alone.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        What the machines draw from.
    n : int
        Monte-Carlo machines per setting.
    seed : int
        The seed (>= 0), as in `montecarlo`.
    variants : sequence of (str, float, float)
        ``(label, shift_um, turn_deg)`` per setting: a shift along the guide's normal (um) and
        a turn about its point (deg). Default: nominal, +/-50 um, +/-0.02 deg.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    n_jobs : int
        Worker processes on this machine; the table does not depend on it.
    progress : bool or callable
        True: a bar on stderr; or ``progress(done, total)`` as chunks finish.
    scheduler : str, distributed.Client or None
        A Dask scheduler address or client.
    strategy : Strategy or None
        None: beta re-optimised per machine. A strategy: its joint optimum on top of each
        setting, with the counts after it.
    limit_um : float
        The SumDelta limit (um).

    Returns
    -------
    pandas.DataFrame
        Per setting: ``guide``, ``shift_um``, ``angle_from_vertical_deg``, ``beta_opt_deg``,
        ``total_um`` (nominal SumDelta at beta*), the beta window (deg) and the yields with
        beta fixed at the setting's beta* and adjusted (or after the strategy, with its counts:
        ok + out_of_spec + cannot_assemble + dead_point = n).
    """
    tolerances = needle_set(tolerances)
    settings = [Setting(label, {"guide_shift_um": nominal.guide_shift_um + shift_um,
                                "guide_angle": nominal.guide_angle + dangle},
                        {"shift_um": shift_um}) for label, shift_um, dangle in variants]
    if strategy is not None:
        return compare(nominal, settings, _adjusted_figures(nominal, tolerances, n, seed,
                                                            range_deg, strategy, limit_um),
                       "guide").to_dataframe()

    def figures(p, setting):
        fig, row = _guide_figures(p, range_deg, limit_um)
        mc = montecarlo(p.override(beta=fig.beta_opt_deg), tolerances, n, seed,
                        limit_um=limit_um, range_deg=range_deg, n_jobs=n_jobs,
                        progress=progress, scheduler=scheduler)
        return {**row, "yield_fixed_beta": mc.yield_of("fixed"),
                "yield_adjusted_beta": mc.yield_of("adjusted"), "failed": mc.failed}
    return compare(nominal, settings, figures, "guide").to_dataframe()


def _guide_figures(p, range_deg, limit_um=sb.DEFAULT_LIMIT_UM):
    """The nominal figures of the machine with a guide setting, and the row's columns."""
    fig = nominal_figures(p, range_deg, limit_um)
    row = {"angle_from_vertical_deg": p.guide_angle,
           "beta_opt_deg": fig.beta_opt_deg, "total_um": fig.total_um,
           "window_low_deg": fig.window_deg[0], "window_high_deg": fig.window_deg[1],
           "window_width_deg": fig.window_deg[1] - fig.window_deg[0]
           if np.all(np.isfinite(fig.window_deg)) else np.nan,
           "beta_at_bound": fig.beta_at_bound}
    return fig, row


def _adjusted_figures(nominal, tolerances, n, seed, range_deg, strategy, limit_um):
    """Each setting's figures with the strategy's joint optimum on the same machines."""
    from sewtol.mechanisms.needle_208.compensators import Strategy

    check_sampling(nominal, tolerances, n, seed)  # as montecarlo checks the same machines
    dev = draw_deviations(tolerances, n, seed)  # montecarlo's machines for this seed

    def figures(p, setting):
        fig, row = _guide_figures(p, range_deg, limit_um)
        c = columns_of(p.override(beta=fig.beta_opt_deg), dev)
        fixed = adjust(c, Strategy("none"), limit_um)
        adj = adjust(c, strategy, limit_um, plateaus=False)
        k = adj.counts()
        return {
            **row,
            "yield_fixed_beta": float(np.mean(fixed.status == "ok")),
            "strategy": strategy.name, "yield_adjusted": k["ok"] / adj.n,
            "n": adj.n, "ok": k["ok"], "out_of_spec": k["out of spec"],
            "cannot_assemble": k["cannot assemble"], "dead_point": k["dead point"],
            "p95_after_um": float(np.percentile(np.where(np.isfinite(adj.total_um),
                                                         adj.total_um, np.inf), 95)),
        }
    return figures
