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
