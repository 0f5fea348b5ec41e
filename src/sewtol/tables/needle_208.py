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
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.measurement_error import MeasurementError
from sewtol.mechanism.loader import builtin
from sewtol.mechanism.spec import Spec
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.adjustment import Adjustment, adjust, columns_of
from sewtol.mechanisms.needle_208.single import nominal_figures
from sewtol.studies import montecarlo as MC
from sewtol.studies import strategies as ST
from sewtol.studies.montecarlo import (
    CHUNK,
    MonteCarloResult,
    check_sampling,
)
from sewtol.studies.parallel import chunk_bounds
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    import pandas as pd
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


def as_mechanism(params: Needle208):
    """The needle drive `params` (scalar fields) as a protocol mechanism: the folder's
    mechanism.toml (fast_path needle_208) with the machine's values as its nominals."""
    return builtin("needle_208").override(**{k: float(getattr(params, k))
                                             for k in P.field_names(type(params))})


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
    import pandas as pd

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
    import pandas as pd

    tolerances = needle_set(tolerances)
    return pd.DataFrame([worst_case(nominal, tolerances, a, range_deg,
                                    strategy=strategy if a else None) for a in (False, True)])


@dataclass(frozen=True)
class StrategiesResult(ST.StrategiesResult):
    """The strategies study's result (sewtol.studies.strategies: its table in the needle's
    words, `failure_contributors`) with the needle's per-machine view of each row."""

    limit_um: float = sb.DEFAULT_LIMIT_UM

    @property
    def params(self) -> tuple[str, ...]:
        return tuple(self.deviations)

    def _adjustment(self, i: int, rows: slice = slice(None)) -> Adjustment:
        """Row i (its machines `rows`) as needle_208.adjustment.Adjustment."""
        a = self.adjusted[i]
        if not self.per_machine:
            raise ParameterError("per_machine", "must be True for the per-machine tables (this "
                                 "study kept only what its rows read)", False)

        def cut(v):
            return {k: cut(x) for k, x in v.items()} if isinstance(v, dict) else v[rows]

        return Adjustment(self.rows[i], self.limit_um, *(cut(v) for v in (
            a.extras["total_before_um"], a.value, a.extras["plus_um"], a.extras["minus_um"],
            a.extras["achieved_um"], a.status, a.settings, a.extras["low"], a.extras["high"],
            a.extras["at_limit"])))

    @property
    def adjustments(self) -> tuple[Adjustment, ...]:
        """Each row as needle_208.adjustment.Adjustment (its settings, plateaus, at-limit flags
        and achieved SumDelta per machine)."""
        return tuple(self._adjustment(i) for i in range(len(self.names)))

    def machines(self, strategy: str, rows: slice = slice(None)) -> pd.DataFrame:
        """Deviations, criterion before and after, settings, at-limit flags and status (of the
        machines `rows`: a slice of 0 .. n-1)."""
        import pandas as pd

        self.get(strategy)  # refused in one line when not a row
        f = pd.DataFrame({k: v[rows] for k, v in self.deviations.items()})
        f.insert(0, "machine", np.arange(self.n)[rows])
        return pd.concat([f, self._adjustment(self.names.index(strategy), rows).to_dataframe()],
                         axis=1)

    def machine_chunks(self, strategy: str, size: int = ST.CHUNK):
        """`machines(strategy)` in consecutive pieces of `size` machines, made one at a time
        (what --out writes: never the whole per-machine table at once)."""
        self.get(strategy)
        for a, b in chunk_bounds(self.n, size):
            yield self.machines(strategy, slice(a, b))


def adjusted_summary(nominal: Needle208, machines: pd.DataFrame, strategy: Strategy,
                     limit_um: float) -> pd.DataFrame:
    """`needle montecarlo --adjust`: the strategies table's row (sewtol.studies.strategies.row,
    in the needle's words, without measurement_error) of a per-machine table written by
    Adjustment.to_dataframe()."""
    from sewtol.protocol import plugins
    from sewtol.studies.adjusting import Adjusted

    mech = as_mechanism(nominal)
    names = [c.name for c in strategy.compensators]
    a = Adjusted(machines["total_after_um"].to_numpy(float),
                 {k: machines[next(c for c in machines if c.startswith(f"{k}_setting"))]
                  .to_numpy(float) for k in names}, machines["status"].to_numpy(), {},
                 {"achieved_um": machines["achieved_um"].to_numpy(float),
                  "at_limit": {k: machines[f"{k}_at_limit"].to_numpy(bool) for k in names}})
    columns = {k: v for k, v in plugins(mech).columns["strategies"].items()
               if k != "measurement_error"}
    return ST.table([ST.row(strategy.name, strategy.compensators, a,
                            Spec(OUTPUT, float(limit_um)), ST.setting_labels(mech, strategy))],
                    columns)


def strategies_table(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                     strategies: list[Strategy] | None = None, limit_um: float = 10.0,
                     n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
                     measurement: MeasurementError | None = None,
                     per_machine: bool = True) -> StrategiesResult:
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
    per_machine : bool
        Keep every machine's figures for ``machines(name)`` (False: only what the table's
        rows read, less memory; sewtol.studies.strategies.strategies).

    Returns
    -------
    StrategiesResult
        ``to_dataframe()``: the generic row (sewtol.studies.strategies.row) in the needle's
        words (its Plugins.columns["strategies"]): per strategy the counts (ok, out_of_spec,
        cannot_assemble, dead_point; they add up to n), the yield and its interval, SumDelta
        quantiles (um), Cpk, at-limit shares, achieved yield and distinct settings;
        ``machines(name)`` per machine; ``failure_contributors(name)``.
    """
    from sewtol.mechanisms.needle_208.compensators import default_strategies

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
                      measurement=measurement, per_machine=per_machine)
    return StrategiesResult(**vars(r), limit_um=float(limit_um))


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
ALLOCATION_COLUMNS = {"param": "param", "cost_weight": "cost_weight", "slope": "slope_um_per_mm",
                      **{k: f"{k}_mm" for k in ("lower", "upper", "reference_lower",
                                                 "reference_upper")}}


def allocate(nominal: Needle208, reference: ToleranceSet | str, target: float = 0.9973,
             n: int = 2000, seed: int = 0, costs: dict[str, float] | None = None,
             max_mm: float = 1.0, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
             steps: int | None = None, strategy: Strategy | None = None,
             limit_um: float = sb.DEFAULT_LIMIT_UM) -> Allocation:
    """The widest tolerances that keep the yield after adjustment at a target:
    sewtol.studies.allocation.allocate_by_cost on `as_mechanism(nominal)`, slopes from the
    scan's exact SumDelta (um per mm).

    strategy None (beta re-optimised in range_deg, the source study's allocation): the
    symmetric form, +/- t_i, the scale (mm, the widest tolerance) bisected in (0, max_mm). A
    strategy: its exact joint optimum; each reference tolerance keeps its own shape, k bisected
    geometrically; a tolerance the strategy cancels alone at its reference limits (SumDelta
    within 1e-3 um, the plateau tolerance, of the nominal's at both, e.g. the guide bore's
    position under the guide shift) is held there (``held_at_reference``).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    reference : ToleranceSet or str
        The parameters to allocate and the limits at which the slopes are taken.
    target, n, seed : float, int, int
        The yield to keep (strictly between 0 and 1; 0.9973 is +/-3 sigma); the machines per
        trial scale and the seed of their common random numbers.
    costs, max_mm : dict or None, float
        Cost weight c_i per parameter (> 0; default 1); the largest tolerance (mm).
    range_deg, steps, strategy, limit_um : tuple, int or None, Strategy or None, float
        beta's regulating range (deg); bisection steps (None: 12, or 10 with a strategy); the
        assembler's adjustment (None: beta alone in range_deg); the SumDelta limit (um).

    Returns
    -------
    sewtol.studies.allocation.Allocation
        ``to_dataframe()`` per parameter ``cost_weight``, ``slope_um_per_mm``, the allocated
        limits (``tolerance_mm``, the +/- limit, for strategy None; ``lower_mm`` and
        ``upper_mm`` with a strategy) and the reference limits; ``yield_`` the yield after
        adjustment (1 when no scale above 0 keeps the target); ``as_tolerance_set()``.
    """
    from sewtol.studies.allocation import allocate_by_cost

    if strategy is None:
        adjust, options, scan_options = _beta_box(range_deg, limit_um), {}, {}
        columns = {**ALLOCATION_COLUMNS, "upper": "tolerance_mm"}
        del columns["lower"]
    else:  # the slopes read the plateau's centre (the scan's), the yield only the value
        adjust, scan_options = strategy.compensators, {"limit_um": limit_um}
        options = {"limit_um": limit_um, "plateaus": False}
        columns = {**ALLOCATION_COLUMNS, "held_at_reference": "held_at_reference"}
    a = allocate_by_cost(as_mechanism(nominal), needle_set(reference), OUTPUT, target,
                         limit_um, None, n, seed, costs, adjust, symmetric=strategy is None,
                         cap=max_mm, steps=(12 if strategy is None else 10) if steps is None
                         else steps, hold_below=1e-3, figure="total_um",
                         scan_options=scan_options, **options)
    return replace(a, columns=columns, yield_=a.yield_ if a.scale > 0 else 1.0,
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
                   strategy: Strategy | None = None,
                   limit_um: float = sb.DEFAULT_LIMIT_UM) -> pd.DataFrame:
    """One row per guide setting (shift um along the guide normal, turn deg about its point):
    sewtol.studies.settings.compare with its yield_figures (the strategies study of each
    setting's machine, beta at the setting's beta*) beside the setting's nominal figures. Every
    setting sees the same machines (`montecarlo`'s for the seed): the rows differ by the guide.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances, n, seed : ToleranceSet or str, int, int
        What the machines draw from; machines per setting; the seed (>= 0).
    variants : sequence of (str, float, float)
        ``(label, shift_um, turn_deg)`` per setting; default nominal, +/-50 um, +/-0.02 deg.
    range_deg, limit_um : tuple of float, float
        beta's regulating range (deg); the SumDelta limit (um).
    n_jobs, progress : int, bool or callable
        The strategies study's workers and progress bar (the table does not depend on them).
    strategy : Strategy or None
        None: beta re-optimised per machine; a strategy: its joint optimum on each setting.

    Returns
    -------
    pandas.DataFrame
        Per setting ``guide``, ``shift_um``, ``angle_from_vertical_deg``, ``beta_opt_deg``,
        ``total_um`` (nominal SumDelta at beta*), the beta window (deg) and the yields with beta
        fixed at the setting's beta* and adjusted (``failed``: cannot run, fixed), or after the
        strategy with its counts (ok + out_of_spec + cannot_assemble + dead_point = n) and
        ``p95_after_um``.
    """
    from sewtol.studies.settings import Setting, compare, yield_figures

    tolerances = needle_set(tolerances)
    check_sampling(nominal, tolerances, n, seed)  # as montecarlo checks the same machines
    settings = [Setting(label, {"guide_shift_um": nominal.guide_shift_um + shift_um,
                                "guide_angle": nominal.guide_angle + dangle},
                        {"shift_um": shift_um}) for label, shift_um, dangle in variants]
    adjusted = {"beta": tuple(map(float, range_deg))} if strategy is None else strategy

    def columns(r):
        fixed, adj = (r.row(r.names.index(k)) for k in ("fixed", "adjusted"))
        if strategy is None:
            return {"yield_fixed_beta": fixed["ok"] / r.n, "yield_adjusted_beta": adj["ok"] / r.n,
                    "failed": fixed["failed"]}
        total = r.get("adjusted").value
        return {"yield_fixed_beta": fixed["ok"] / r.n, "strategy": strategy.name,
                "yield_adjusted": adj["ok"] / r.n, "n": r.n, "ok": adj["ok"],
                "out_of_spec": adj["out_of_spec"], "cannot_assemble": adj["cannot_close"],
                "dead_point": adj["dead_point"], "p95_after_um": float(np.percentile(
                    np.where(np.isfinite(total), total, np.inf), 95))}
    yields = yield_figures(tolerances, n, seed, {"fixed": (), "adjusted": adjusted}, OUTPUT,
                           Spec(OUTPUT, float(limit_um)), columns=columns, n_jobs=n_jobs,
                           progress=progress, **({} if strategy is None else
                                                 {"limit_um": limit_um, "plateaus": False}))

    def figures(p, setting):
        fig = nominal_figures(p, range_deg, limit_um)
        return {"angle_from_vertical_deg": p.guide_angle,
                "beta_opt_deg": fig.beta_opt_deg, "total_um": fig.total_um,
                "window_low_deg": fig.window_deg[0], "window_high_deg": fig.window_deg[1],
                "window_width_deg": fig.window_deg[1] - fig.window_deg[0]
                if np.all(np.isfinite(fig.window_deg)) else np.nan,
                "beta_at_bound": fig.beta_at_bound,
                **yields(as_mechanism(p.override(beta=fig.beta_opt_deg)), setting)}
    return compare(nominal, settings, figures, "guide").to_dataframe()
