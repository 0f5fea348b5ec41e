"""Yield by adjustment strategy: the same machines adjusted under each strategy.

Every strategy sees the SAME machines (common random numbers: one draw of deviations from the
seed), so differences between rows are the strategies', not sampling noise. Per row: counts
ok + out of spec + cannot assemble + dead point = n, the yield with its Clopper-Pearson
interval (failures count against it), p50/p95/p99 of SumDelta (a machine that cannot run ranks
as infinitely bad), Cpk (one-sided, upper limit only: (USL - mean) / 3 s over the machines that
run), the share of machines with any compensator at a limit, and for each discrete compensator
the number of distinct settings (shim sizes) the machines in spec need.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy import stats

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.adjustment import STATUSES, Adjustment, adjust
from sewtol.mechanisms.needle_208.compensators import Strategy, strategy_of
from sewtol.studies.montecarlo import contributors, draw_deviations, draw_units, unit_streams
from sewtol.tolerances import Tolerance, ToleranceSet, needle_set

if TYPE_CHECKING:
    from sewtol.mechanisms.needle_208.model import Needle208

# the rows of the default strategies table, in order
STRATEGY_ROWS = {
    "none": (),
    "beta": ("beta",),
    "beta+shift": ("beta", "guide_shift_um"),
    "beta+shift+angle": ("beta", "guide_shift_um", "guide_angle"),
    "beta+CD": ("beta", "CD"),
    "all": ("beta", "guide_shift_um", "guide_angle", "CD"),
}


def default_strategies(table=None) -> list[Strategy]:
    return [strategy_of(names, table, name) for name, names in STRATEGY_ROWS.items()]


def columns_of(nominal, deviations: dict) -> dict:
    """Parameter columns (n, 1) of the machines nominal + deviations."""
    m = len(next(iter(deviations.values())))
    c, _ = nm.columns(P.with_deviations(nominal, deviations))
    return {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}


def summary_row(strategy: Strategy, limit_um: float, total, status, at_limit: dict,
                achieved, settings: dict) -> dict:
    """One row of the strategies table (see the module docstring) from per-machine arrays."""
    total, status, achieved = np.asarray(total, float), np.asarray(status), np.asarray(achieved)
    n = total.size
    counts = {s: int(np.sum(status == s)) for s in STATUSES}
    if sum(counts.values()) != n:
        raise ParameterError("status", f"must be one of {', '.join(STATUSES)} for every machine",
                             sorted(set(status) - set(STATUSES)))
    k = counts["ok"]
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
    x = np.where(np.isfinite(total), total, np.inf)
    q = {f"p{p}_um": float(np.quantile(x, p / 100, method="higher")) for p in (50, 95, 99)}
    run = total[np.isfinite(total)]
    if run.size >= 2 and np.std(run, ddof=1) > 0:
        cpk = float((limit_um - run.mean()) / (3 * np.std(run, ddof=1)))
    else:
        cpk = float("nan")
    row = {"strategy": strategy.name, "n": n, "ok": k,
           "out_of_spec": counts["out of spec"], "cannot_assemble": counts["cannot assemble"],
           "dead_point": counts["dead point"], "yield": k / n, "yield_ci_low": float(ci.low),
           "yield_ci_high": float(ci.high), **q, "Cpk": cpk}
    ok = status == "ok"
    any_limit = np.zeros(n, bool)
    for comp in strategy.compensators:
        any_limit |= np.asarray(at_limit[comp.name], bool)
    row["at_limit_share"] = float(any_limit.mean())
    row["at_limit"] = ", ".join(f"{c.name} {np.mean(at_limit[c.name]):.1%}"
                                for c in strategy.compensators)
    row["achieved_yield"] = float(np.mean(achieved <= limit_um))
    row["distinct_settings"] = ", ".join(
        f"{c.name} {np.unique(np.round(np.asarray(settings[c.name])[ok], 9)).size}"
        for c in strategy.compensators if c.discrete)
    return row


def summarise(adj: Adjustment) -> dict:
    return summary_row(adj.strategy, adj.limit_um, adj.total_um, adj.status, adj.at_limit,
                       adj.achieved_um, adj.settings)


def summarise_frame(machines: pd.DataFrame, strategy: Strategy, limit_um: float) -> pd.DataFrame:
    """The summary row of a per-machine table written by Adjustment.to_dataframe()."""
    cols = {c.name: [k for k in machines.columns if k.startswith(f"{c.name}_setting")][0]
            for c in strategy.compensators}
    row = summary_row(strategy, limit_um, machines["total_after_um"].to_numpy(),
                      machines["status"].to_numpy(),
                      {c.name: machines[f"{c.name}_at_limit"].to_numpy(bool)
                       for c in strategy.compensators},
                      machines["achieved_um"].to_numpy(),
                      {k: machines[v].to_numpy() for k, v in cols.items()})
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

    @property
    def n(self) -> int:
        return len(self.deviations)

    def to_dataframe(self) -> pd.DataFrame:
        return pd.DataFrame([summarise(a) for a in self.adjustments])

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
        for p in self.params:
            x = frame[p].to_numpy()
            lo, hi = self.limits[p]
            half = 0.5 * (hi - lo)
            z = (x - 0.5 * (hi + lo)) / half
            out.loc[out.param == p, "mean_z_failing"] = float(z[fail].mean()) if fail.any() \
                else np.nan
            out.loc[out.param == p, "mean_abs_z_failing"] = float(np.abs(z[fail]).mean()) \
                if fail.any() else np.nan
            out.loc[out.param == p, "mean_abs_z_all"] = float(np.abs(z).mean())
        out.insert(1, "n_failing", int(fail.sum()))
        return out.sort_values("mean_abs_z_failing", ascending=False, na_position="last") \
            .reset_index(drop=True)


# machines per chunk when the strategies run in parallel (each machine is adjusted on its own,
# so the chunking never changes a number; tested against the single-process path)
CHUNK = 250


def _adjust_chunk(nominal, dev: dict, strategies: list[Strategy], limit_um: float,
                  numba_threads: int | None = None):
    """One chunk of machines under every strategy. numba_threads: the numba threads to use
    meanwhile (1 in a worker process: the joint optimum's kernel is numba-parallel, and 2
    processes x 2 threads on 2 cores ran slower than one process; measured 40.6 s serial,
    24.9 s with 2 single-threaded workers, 52 s with 2 workers of 2 threads, 1000 machines)."""
    import numba

    before = numba.get_num_threads()
    if numba_threads is not None:
        numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    try:
        c = columns_of(nominal, dev)
        return [adjust(c, s.check_names(list(c)), limit_um) for s in strategies]
    finally:
        numba.set_num_threads(before)


def concat_adjustments(parts: list[Adjustment]) -> Adjustment:
    """One Adjustment from the Adjustments of consecutive chunks of machines."""
    first = parts[0]
    merged = {}
    for f in fields(Adjustment):
        value = getattr(first, f.name)
        if isinstance(value, np.ndarray):
            merged[f.name] = np.concatenate([getattr(a, f.name) for a in parts])
        elif isinstance(value, dict):
            merged[f.name] = {k: np.concatenate([np.asarray(getattr(a, f.name)[k])
                                                 for a in parts]) for k in value}
        else:
            merged[f.name] = value
    return Adjustment(**merged)


def strategies_table(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                     strategies: list[Strategy] | None = None, limit_um: float = 10.0,
                     n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
                     ) -> StrategiesResult:
    """Adjust the same n machines (one draw from `seed`) under each strategy.

    What ``sewtol needle strategies`` prints.

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
        Worker processes: with n_jobs != 1 the machines are adjusted in chunks of CHUNK in
        parallel (studies.parallel.run_chunks); the same numbers, machine by machine.
    progress : bool or callable
        A progress bar, or a callback progress(done, total).

    Returns
    -------
    StrategiesResult
        ``to_dataframe()``: per strategy the counts (ok, out of spec, cannot assemble, dead
        point; they add up to n), the yield and its interval, SumDelta quantiles (um), Cpk,
        at-limit shares and distinct settings; ``machines(name)`` per machine.
    """
    tolerances = needle_set(tolerances)
    if int(n) != n or n < 2:
        raise ParameterError("n", "must be a whole number >= 2", n)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    tol = tolerances.active()
    if not tol.items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    strategies = default_strategies() if strategies is None else strategies
    names = [s.name for s in strategies]
    if len(set(names)) != len(names):
        raise ParameterError("strategies", "names a strategy twice", names)
    dev = draw_deviations(tol, int(n), int(seed))  # montecarlo's machines for this seed
    if n_jobs == 1 and not progress:
        c = columns_of(nominal, dev)
        valid = list(c)
        adjs = tuple(adjust(c, s.check_names(valid), limit_um) for s in strategies)
    else:
        from sewtol.studies.parallel import chunk_bounds, run_chunks

        for s in strategies:  # unknown compensator names fail here, before any worker starts
            s.check_names(list(columns_of(nominal, {k: v[:1] for k, v in dev.items()})))
        threads = 1 if n_jobs != 1 else None
        parts = run_chunks(_adjust_chunk, [(nominal, {k: v[a:b] for k, v in dev.items()},
                                            strategies, limit_um, threads)
                                           for a, b in chunk_bounds(int(n), CHUNK)],
                           n_jobs=n_jobs, progress=progress, desc="strategies")
        adjs = tuple(concat_adjustments([p[i] for p in parts]) for i in range(len(strategies)))
    return StrategiesResult(pd.DataFrame(dev), adjs, tuple(tol.params), tolerances.name,
                            int(seed), float(limit_um),
                            {t.param: (t.lower, t.upper) for t in tol.items})


def adjusted_montecarlo_model(nominal, dev, strategy: Strategy, limit_um: float):
    """Model for montecarlo.sample_machines: the per-machine table of one strategy."""
    adj = adjust(columns_of(nominal, dev), strategy, limit_um)
    f = adj.to_dataframe()
    return {k: f[k].to_numpy() for k in f.columns}



@dataclass(frozen=True)
class StrategyAllocation:
    """Widest tolerances for a yield target when the assembler applies `strategy`."""

    table: pd.DataFrame  # param, cost_weight, slope_um_per_mm, lower_mm, upper_mm, reference_*
    strategy: str
    yield_adjusted: float
    target: float
    n: int
    seed: int
    scale: float

    def to_dataframe(self) -> pd.DataFrame:
        return self.table.copy()

    def as_tolerance_set(self, name: str = "allocated") -> ToleranceSet:
        return ToleranceSet(name, tuple(Tolerance(r.param, r.lower_mm, r.upper_mm)
                                        for r in self.table.itertuples()),
                            f"allocated by sewtol for strategy {self.strategy}")


def allocate_for_strategy(nominal, reference: ToleranceSet | str, strategy: Strategy,
                          target: float = 0.9973, n: int = 500, seed: int = 0,
                          costs: dict | None = None, max_mm: float = 1.0, steps: int = 10,
                          limit_um: float = 10.0) -> StrategyAllocation:
    """The allocation of needle_208.tables.allocate with the yield taken after the
    strategy's joint adjustment.

    Cost model: reciprocal in the width, cost = sum c_i / (upper_i - lower_i). Each reference
    tolerance keeps its own (possibly asymmetric) shape: both limits are scaled by
    f_i = min(k a_i, max_mm) / h_i, h_i its half-width, with a_i = (c_i / s_i^2)^(1/3) (the
    root-sum-square Lagrange optimum) and s_i the slope of the ADJUSTED SumDelta at the
    reference limits (each tolerance alone, the strategy applied). The common scale k is found
    by bisection (geometric, k spans decades) on the Monte-Carlo yield of the real model on
    common random numbers (one uniform matrix for every trial k), so the yield is a step
    function of k and the result is the largest k found with yield >= target.
    """
    reference = needle_set(reference)
    if not (0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    if int(n) != n or n < 2:
        raise ParameterError("n", "must be a whole number >= 2", n)
    ref = reference.active()
    names = ref.params
    costs = costs or {}
    cw = np.array([float(costs.get(p, 1.0)) for p in names])
    if np.any(cw <= 0):
        raise ParameterError("costs", "must be positive weights", costs)
    half = np.array([0.5 * (t.upper - t.lower) for t in ref.items])
    params, _, deltas, dev = ref.limit_variants()
    base = adjust(columns_of(nominal, {p: np.zeros(1) for p in names}), strategy, limit_um)
    at_limits = adjust(columns_of(nominal, dev), strategy, limit_um).total_um
    slope = []
    for p, h in zip(names, half, strict=True):
        rows = [i for i, q in enumerate(params) if q == p]
        worst = np.nanmax(np.abs(at_limits[rows] - base.total_um[0]))
        slope.append(float(worst) / h if np.isfinite(worst) else np.inf)
    s = np.clip(np.array(slope), 1e-9, 1e12)
    shape = (cw / s**2) ** (1.0 / 3.0)
    shape = shape / shape.max()
    u = draw_units(unit_streams(seed, n), len(names), 0, n)  # montecarlo's uniforms

    def limits_at(k):
        f = np.minimum(k * shape, max_mm) / half
        return [(t.lower * fi, t.upper * fi) for t, fi in zip(ref.items, f, strict=True)]

    def yield_at(k):
        d = ToleranceSet("trial", tuple(Tolerance(p, lo, hi) for p, (lo, hi) in
                                        zip(names, limits_at(k), strict=True))).from_unit(u)
        a = adjust(columns_of(nominal, d), strategy, limit_um, plateaus=False)
        return float(np.mean(a.status == "ok"))

    # k up to where every tolerance reaches the cap, so the cap never ends the search early
    lo, hi = 0.0, float(max_mm / shape.min())
    if yield_at(hi) >= target:
        lo = hi
    else:
        for _ in range(steps):
            mid = np.sqrt(max(lo, hi * 1e-6) * hi)  # geometric: k spans decades
            if yield_at(mid) >= target:
                lo = mid
            else:
                hi = mid
    lim = limits_at(lo)
    table = pd.DataFrame({
        "param": names, "cost_weight": cw, "slope_um_per_mm": s,
        "lower_mm": [x[0] for x in lim], "upper_mm": [x[1] for x in lim],
        "reference_lower_mm": [t.lower for t in ref.items],
        "reference_upper_mm": [t.upper for t in ref.items],
    })
    return StrategyAllocation(table, strategy.name, yield_at(lo) if lo > 0 else 1.0, target,
                              int(n), int(seed), lo)


__all__ = ["STATUSES", "STRATEGY_ROWS", "StrategiesResult", "StrategyAllocation",
           "adjusted_montecarlo_model", "allocate_for_strategy", "default_strategies",
           "strategies_table", "summarise", "summarise_frame", "summary_row"]
