"""The needle's tables of the generic studies: a `Needle208` as a protocol mechanism, and the
scan, worst case, largest tolerances and Sobol indices (sewtol.studies.scan, worst_case, sobol)
in the source study's columns and words.

The studies run on `as_mechanism(nominal)` (the folder's mechanism.toml with the machine's
values as nominals) and so on the needle's plug-ins (fast_path.py): SumDelta exactly by the
fused kernel, beta (and the guide shift) by the exact sliding-window optimum, any strategy by
needle_208.adjustment. This module only names their figures as the source did: beta_deg (beta*,
the adjusted beta; or the machine's own where a strategy does not set it), plus_um, minus_um,
total_um (Delta+, Delta-, SumDelta at the settings), beta_at_bound (beta*'s plateau reaches
an end of its range), NAME_mm (deviations).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.tolerances import Tolerance, ToleranceSet, needle_set

if TYPE_CHECKING:
    from collections.abc import Callable

    from distributed import Client

    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.studies.checkpoint import ChunkStore
    from sewtol.studies.rare_event import LimitState
    from sewtol.studies.sobol import SobolResult

OUTPUT = "SumDelta_um"
MAX_CORNER_PARAMS = 10
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
        """The rows as dicts, the fixed columns first (the JSON rows of ``sewtol needle scan``)."""
        cols = ["param", "side", "delta_mm", "value_mm", "beta_deg", "plus_um", "minus_um",
                "total_um"]
        cols += [c for c in self.rows.columns if c not in cols]
        return self.rows[cols].to_dict(orient="records")


def _figures(a, base, strategy) -> dict:
    """The needle's columns of an adjusted batch (sewtol.studies.adjusting.Adjusted)."""
    n = len(a.value)
    if strategy is None:
        return {"beta_deg": a.settings["beta"], **{k: a.extras[k] for k in FIGURES},
                "beta_at_bound": np.asarray(a.at_bound["beta"], bool)}
    f = {"beta_deg": a.settings["beta"] if "beta" in strategy.names else np.full(n, base.beta),
         **{k: a.extras[k] for k in FIGURES},
         "beta_at_bound": a.at_bound["beta"] if "beta" in strategy.names else np.zeros(n, bool)}
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
        (the parameter's value), ``beta_deg`` (beta*), ``plus_um``, ``minus_um`` and
        ``total_um`` (Delta+, Delta-, SumDelta) and ``beta_at_bound`` (beta*'s plateau reaches
        an end of range_deg: the row's optimum may lie outside it); ``nominal_row`` the same
        for the nominal.
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


@dataclass(frozen=True)
class WorstCase:
    case: str
    total_um: float
    corner_total_um: float
    point: dict  # deviation per parameter (mm)
    beta_deg: float
    interior: bool  # True when the worst point is not a corner
    # the worst machine's adjusted beta*: its plateau reaches an end of the searched range
    beta_at_bound: bool = False

    def to_row(self) -> dict:
        row = {"case": self.case, "total_um": self.total_um,
               "worst_corner_total_um": self.corner_total_um, "beta_deg": self.beta_deg,
               "beta_at_bound": self.beta_at_bound, "interior": self.interior}
        row.update({f"{k}_mm": v for k, v in self.point.items()})
        return row


def worst_case(nominal, tolerances: ToleranceSet | str, adjust: bool,
               range_deg=sb.DEFAULT_RANGE_DEG, starts: int = 3, strategy=None) -> WorstCase:
    """The worst SumDelta over the tolerance box (sewtol.studies.worst_case, the best `starts`
    corners polished, a machine that cannot run counting as the worst): beta fixed as in
    `nominal` (adjust=False), beta re-optimised per trial machine (adjust=True), or, with
    adjust=True and a strategy, the joint optimum over the strategy's compensators."""
    from sewtol.studies import worst_case as W

    tolerances = needle_set(tolerances)
    if len(tolerances.active().params) > MAX_CORNER_PARAMS:
        raise ParameterError("tolerances", "worst case enumerates corners; at most 10 parameters",
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
    return WorstCase(case, e.value, e.corner_value, e.point, beta, e.interior, at_bound)


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
                                    strategy=strategy if a else None).to_row()
                         for a in (False, True)])


def _failure_reasons(mech, values, output) -> tuple[np.ndarray, np.ndarray]:
    """(status, dyad) of machines that do not run, at the mechanism's beta: the first reason
    in assembly order (status.failure_reasons; "unexplained" when none is found)."""
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.fast_path import needle_params
    from sewtol.mechanisms.needle_208.status import failure_reasons

    why = failure_reasons(nm.columns(needle_params(mech, values))[0])
    return np.where(why["status"] == "", "unexplained", why["status"]), why["dyad"]


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
    from sewtol.mechanisms.needle_208.montecarlo import fixed_beta_of
    from sewtol.studies import sobol as S

    tolerances = needle_set(tolerances)
    S.check_sobol(nominal, tolerances, n, seed, second_order)
    sb.check_range(range_deg, limit_um)
    nominal = nominal.override(beta=fixed_beta_of(nominal, fixed_beta, range_deg, limit_um))
    if strategy is None:
        adjusted, comps, options = "adjusted_beta", _beta_box(range_deg, limit_um), {}
    else:
        adjusted = "adjusted_" + strategy.name
        comps, options = strategy.compensators, {"limit_um": limit_um, "plateaus": False}
    return S.sobol(as_mechanism(nominal), tolerances, OUTPUT, n, seed,
                   cases={"fixed_beta": None, adjusted: comps}, resamples=resamples,
                   conf_level=conf_level, second_order=second_order, n_jobs=n_jobs,
                   progress=progress, backend=backend, chunk_size=chunk_size or S.CHUNK,
                   store=store, scheduler=scheduler, failures=_failure_reasons, **options)


NEEDLE_MODES = ("cannot assemble", "dead point")
ADJUSTMENTS = ("none", "beta")


def _needle_failures(mech, values, output) -> np.ndarray:
    """Per machine without a value: "cannot assemble" (a dyad misses at the mechanism's beta),
    else "dead point" (a dyad passes within the dead-point angle, or no beta assembles it)."""
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.fast_path import needle_params

    c, _ = nm.columns(needle_params(mech, values))
    m = len(next(iter(values.values())))
    f = nm.feasibility({k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()})
    return np.where((f.miss_LMA_mm > 0) | (f.miss_BCD_mm > 0), *NEEDLE_MODES)


def needle_limit_state(nominal: Needle208, tolerances: ToleranceSet | str, limit_um: float = 10.0,
                       adjust: str = "beta",
                       range_deg: tuple[float, float] | None = None) -> LimitState:
    """SumDelta of the 208 needle drive after the assembly adjustment, as a LimitState
    (sewtol.studies.ppm.limit_state on `as_mechanism`).

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
    from sewtol.studies.ppm import limit_state

    tolerances = needle_set(tolerances)
    if adjust not in ADJUSTMENTS:
        raise ParameterError("adjust", f"must be one of {', '.join(ADJUSTMENTS)}", adjust)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    range_deg = sb.DEFAULT_RANGE_DEG if range_deg is None else tuple(map(float, range_deg))
    if not tolerances.active().items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    beta = adjust == "beta"
    return limit_state(as_mechanism(nominal), tolerances, OUTPUT, float(limit_um),
                       adjust={"beta": range_deg} if beta else None,
                       name="total_adjusted_um" if beta else "total_fixed_um",
                       modes=NEEDLE_MODES, failures=_needle_failures)


@dataclass(frozen=True)
class NeedleAllocation:
    """Allocated symmetric tolerances and the yield they give (see `allocate`).

    ``to_dataframe()`` has per parameter ``cost_weight``, ``slope_um_per_mm``,
    ``tolerance_mm`` (the allocated +/- limit) and the reference limits;
    ``as_tolerance_set()`` turns it into a `ToleranceSet` for further studies.
    """

    table: pd.DataFrame  # param, cost_weight, slope_um_per_mm, tolerance_mm, reference_mm
    yield_adjusted: float
    target: float
    n: int
    seed: int
    scale: float

    def to_dataframe(self) -> pd.DataFrame:
        """The allocation table (a copy)."""
        return self.table.copy()

    def as_tolerance_set(self, name: str = "allocated") -> ToleranceSet:
        """The allocated limits as a symmetric, uniform ToleranceSet."""
        return ToleranceSet(name, tuple(Tolerance(p, -t, t) for p, t in
                                        zip(self.table["param"], self.table["tolerance_mm"],
                                            strict=True)), "allocated by sewtol")


def allocate(nominal: Needle208, reference: ToleranceSet | str, target: float = 0.9973,
             n: int = 2000, seed: int = 0, costs: dict[str, float] | None = None,
             max_mm: float = 1.0, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
             steps: int = 12) -> NeedleAllocation:
    """The widest symmetric tolerances that keep the yield after beta adjustment at a target.

    Cost is reciprocal, sum c_i / t_i; the shape t_i ~ (c_i / s_i^2)^(1/3) (s_i the slope of
    SumDelta at beta* from the scan, um per mm) is the root-sum-square optimum; the common scale
    of the shapes is sewtol.studies.allocation.allocate's (bisection in (0, max_mm) on the
    yield after beta adjustment per machine, common random numbers).

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
        The regulating range for beta, (low, high) in deg.
    steps : int
        Bisection steps on the scale.

    Returns
    -------
    NeedleAllocation
        The allocated +/- tolerance per parameter (mm), the yield it gives with beta adjusted,
        the target, n, seed and the scale found.

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
    names = ref.params
    costs = costs or {}
    c = np.array([float(costs.get(p, 1.0)) for p in names])
    if np.any(c <= 0):
        raise ParameterError("costs", "must be positive weights", costs)
    sc = scan(nominal, ref, range_deg=range_deg)
    t0 = sc.nominal_row["total_um"]
    rows = sc.rows
    slope = []
    for t in ref.items:
        r = rows[rows["param"] == t.param]
        width = max(abs(t.upper), abs(t.lower))
        slope.append(float(np.max(np.abs(r["total_um"].to_numpy() - t0))) / width)
    s = np.maximum(np.array(slope), 1e-9)
    shape = (c / s**2) ** (1.0 / 3.0)
    shape = shape / shape.max()
    # the scale k (mm) of the shapes (the largest 1), searched in (0, max_mm): no tolerance
    # exceeds max_mm; the yield is SumDelta <= limit after beta adjustment per machine
    shapes = ToleranceSet(reference.name, tuple(Tolerance(p, -a, a) for p, a in
                                                zip(names, shape, strict=True)))
    a = A.allocate(as_mechanism(nominal), shapes, OUTPUT, target, sc.limit_um, None, n, seed,
                   adjust=_beta_box(range_deg), bracket=(0.0, max_mm), steps=steps,
                   failures=_failure_reasons)
    table = pd.DataFrame({
        "param": names, "cost_weight": c, "slope_um_per_mm": s,
        "tolerance_mm": a.table["upper"].to_numpy(),
        "reference_lower_mm": [x.lower for x in ref.items],
        "reference_upper_mm": [x.upper for x in ref.items],
    })
    return NeedleAllocation(table, a.yield_ if a.scale > 0 else 1.0, target, n, seed, a.scale)
