"""Tolerance allocation: the widest tolerances that keep the yield after beta adjustment.

Cost model: reciprocal, cost = sum c_i / t_i for symmetric tolerances +/- t_i. With the
scatter of SumDelta modelled as root-sum-square of s_i t_i (s_i: the slope of SumDelta at beta*
from the scan, um per mm), the Lagrange optimum is t_i proportional to (c_i / s_i^2)^(1/3).
The common scale k is then found by bisection on the Monte-Carlo yield of the real model (same
random numbers for every trial k, so the yield is a deterministic step function of k) so that
the yield with per-machine beta is at least the target. Insensitive parameters are capped at
`max_mm`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.adjustment import adjust, columns_of
from sewtol.mechanisms.needle_208.compensators import Strategy
from sewtol.mechanisms.needle_208.evaluate import evaluate
from sewtol.mechanisms.needle_208.tables import scan
from sewtol.studies.montecarlo import draw_units, unit_streams
from sewtol.tolerances import Tolerance, ToleranceSet, needle_set

if TYPE_CHECKING:
    from sewtol.mechanisms.needle_208.model import Needle208


@dataclass(frozen=True)
class Allocation:
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
             steps: int = 12) -> Allocation:
    """The widest symmetric tolerances that keep the yield after beta adjustment at a target.

    Cost is reciprocal, sum c_i / t_i; the shape t_i ~ (c_i / s_i^2)^(1/3) (s_i the slope of
    SumDelta at beta* from the scan, um per mm) is the root-sum-square optimum, and the common
    scale is found by bisection on the Monte-Carlo yield of the real model with beta set per
    machine (the same random numbers for every trial scale).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    reference : ToleranceSet or str
        Which parameters to allocate, and the limits at which the slopes are taken.
    target : float
        The yield to keep, strictly between 0 and 1; default 0.9973 (+/-3 sigma).
    n : int
        Monte-Carlo machines per trial scale.
    seed : int
        Seed of the common random numbers (>= 0).
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
    Allocation
        The allocated +/- tolerance per parameter (mm), the yield it gives with beta adjusted,
        the target, n, seed and the scale found.

    Raises
    ------
    ParameterError
        For a target outside (0, 1) or a non-positive cost weight.
    """
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

    # common random numbers: montecarlo's uniforms for this seed, the same for every scale
    u = draw_units(unit_streams(seed, n), len(names), 0, n)

    def tolerances_at(k):
        return np.minimum(k * shape, max_mm)

    def yield_at(k):
        dev = ToleranceSet("trial", tuple(Tolerance(p, -t, t) for p, t in
                                          zip(names, tolerances_at(k), strict=True))).from_unit(u)
        out = evaluate(nominal, dev, adjust=True, range_deg=range_deg)
        return float(np.mean(out.total_adjusted_um <= sc.limit_um))

    lo, hi = 0.0, max_mm
    if yield_at(hi) >= target:
        lo = hi
    else:
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            if yield_at(mid) >= target:
                lo = mid
            else:
                hi = mid
    t = tolerances_at(lo)
    table = pd.DataFrame({
        "param": names, "cost_weight": c, "slope_um_per_mm": s, "tolerance_mm": t,
        "reference_lower_mm": [x.lower for x in ref.items],
        "reference_upper_mm": [x.upper for x in ref.items],
    })
    return Allocation(table, yield_at(lo) if lo > 0 else 1.0, target, n, seed, lo)


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
    """The allocation of needle_208.allocation with the yield taken after the
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
