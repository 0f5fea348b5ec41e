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

import numpy as np
import pandas as pd

from ..errors import ParameterError
from ..tolerances import Tolerance, ToleranceSet
from . import beta as sb
from .needle_eval import evaluate
from .scan import scan


@dataclass(frozen=True)
class Allocation:
    table: pd.DataFrame  # param, cost_weight, slope_um_per_mm, tolerance_mm, reference_mm
    yield_adjusted: float
    target: float
    n: int
    seed: int
    scale: float

    def to_dataframe(self) -> pd.DataFrame:
        return self.table.copy()

    def as_tolerance_set(self, name: str = "allocated") -> ToleranceSet:
        return ToleranceSet(name, tuple(Tolerance(p, -t, t) for p, t in
                                        zip(self.table["param"], self.table["tolerance_mm"],
                                            strict=True)), "allocated by sewtol")


def allocate(nominal, reference: ToleranceSet, target: float = 0.9973, n: int = 2000,
             seed: int = 0, costs: dict | None = None, max_mm: float = 1.0,
             range_deg=sb.DEFAULT_RANGE_DEG, steps: int = 12) -> Allocation:
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

    # common random numbers: one standard-uniform matrix for every trial scale
    u = np.random.default_rng(seed).random((n, len(names)))

    def tolerances_at(k):
        return np.minimum(k * shape, max_mm)

    def yield_at(k):
        t = tolerances_at(k)
        dev = {p: (2 * u[:, i] - 1) * t[i] for i, p in enumerate(names)}
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
