"""Failures per million and tolerance allocation for any mechanism file and any output.

Nothing here names a mechanism: both studies take a FileMechanism (sewtol.mechanism), a
tolerance set, one output and its limits (an upper limit, a lower limit, or both).

- `file_limit_state`: the output as a rare_event.LimitState over the standard-normal map of the
  tolerance set (rare_event.StandardNormalMap, the same map as the needle's). A machine fails when
  its value lies beyond a limit or when it cannot run; each group that can fail gives two named
  failure modes, "cannot_close at G" and "dead_point at G", so a failing machine is counted under
  the group that failed first (assembly order), never dropped. With `adjust` (a compensator of
  the file, or several: sewtol.adjuster) the value is the output adjusted for `objective`
  (default minimised) on each machine and the status is the one at the chosen settings.
- `allocate`: the largest common scale k of the set (each tolerance's limits times k times its
  weight) at which the yield (fraction of machines that run and lie within the limits) reaches a
  target. Common random numbers: one matrix of uniforms for every trial k, so each machine's
  deviation moves along a fixed ray from nominal as k grows. The yield is then a step function
  of k, and non-increasing in k when the pass region is star-shaped about the nominal along those
  rays (e.g. an output monotone in each parameter, or |2 r - 2 r0| < limit); bisection finds the
  crossing. Where the pass region is not star-shaped the yield need not be monotone, and the
  bisection finds a crossing, not necessarily the largest one: `trials` lists every k tried.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from sewtol import adjuster as ADJ
from sewtol.errors import ParameterError
from sewtol.studies import generic as G
from sewtol.studies.rare_event import LimitState, StandardNormalMap
from sewtol.tolerances import Tolerance, ToleranceSet

FAILURE_STATUSES = ("cannot_close", "dead_point")
# bisection on the scale stops when the bracket is this small relative to the scale
SCALE_RTOL = 1e-4
MAX_DOUBLINGS = 20


def check_limits(upper: float | None, lower: float | None) -> tuple[float | None, float | None]:
    """At least one finite limit; lower below upper when both are given."""
    if upper is None and lower is None:
        raise ParameterError("limit", "give an upper limit (--limit) and/or a lower limit "
                             "(--lower-limit)", None)
    for name, v in (("limit", upper), ("lower_limit", lower)):
        if v is not None and not np.isfinite(v):
            raise ParameterError(name, "must be a finite number", v)
    if upper is not None and lower is not None and not lower < upper:
        raise ParameterError("lower_limit", f"must be below the upper limit {upper:g}", lower)
    return (None if upper is None else float(upper)), (None if lower is None else float(lower))


def excess(y: np.ndarray, upper: float | None, lower: float | None) -> np.ndarray:
    """How far each value lies beyond the limits (output units; <= 0 inside)."""
    parts = []
    if upper is not None:
        parts.append(y - upper)
    if lower is not None:
        parts.append(lower - y)
    return np.maximum.reduce(parts) if len(parts) > 1 else parts[0]


def _check_adjust(mech, adjust):
    if adjust is not None:
        ADJ.compensators_of(mech, adjust)


def _failing_groups(mech) -> list[str]:
    """The groups that can fail (they carry a closure), in assembly order, found on the nominal
    machine's state."""
    state = mech.state(q_rad=np.zeros(1))
    return [g.name for g in mech.groups if g.name in state.closures]


def _evaluate(mech, values, output, adjust, objective=None):
    if adjust is None:
        ev = mech.evaluate(values, [output])
        return ev.outputs[output], ev.status, ev.failed_group
    a = ADJ.adjust(mech, values, output, adjust, objective)
    return a.value, a.status, a.failed_group


@dataclass(frozen=True)
class _FileResponse:
    """z (n, dim) -> (value, mode) of one output of a file mechanism (picklable for workers)."""

    mech: object
    zmap: StandardNormalMap
    output: str
    upper: float | None
    lower: float | None
    adjust: str | None
    modes: tuple[tuple[str, str], ...]  # (status, group) of failure mode k = index + 1
    objective: ADJ.Objective = ADJ.Objective()

    def __call__(self, z):
        dev = self.zmap.to_physical(z)
        y, status, group = _evaluate(self.mech, G._values(self.mech, dev), self.output,
                                     self.adjust, self.objective)
        mode = np.zeros(y.size, dtype=int)
        for k, (s, g) in enumerate(self.modes, start=1):
            mode[(status == s) & (group == g)] = k
        value = y if self.lower is None else excess(y, self.upper, self.lower)
        return np.where(mode == 0, value, np.nan), mode


def file_limit_state(mech, tolerances: ToleranceSet, output: str, upper: float | None = None,
                     lower: float | None = None, adjust=None, objective=None) -> LimitState:
    """One output of a file mechanism as a LimitState (see the module doc).

    With an upper limit only, the LimitState's value is the output itself and its limit the
    upper limit; with a lower limit, its value is the excess beyond the limits (output units,
    named OUTPUT_excess) and its limit 0."""
    mech.output(output)
    _check_adjust(mech, adjust)
    upper, lower = check_limits(upper, lower)
    tol = G._check_tolerances(mech, tolerances)
    zmap = StandardNormalMap(tol)
    modes = tuple((s, g) for g in _failing_groups(mech) for s in FAILURE_STATUSES)
    label = output if adjust is None else f"{output}_adjusted"
    if lower is None:
        limit, name = upper, label
    else:
        limit, name = 0.0, f"{label}_excess"
    return LimitState(_FileResponse(mech, zmap, output, upper, lower, ADJ.adjust_label(adjust),
                                    modes, ADJ.Objective.parse(objective)), zmap.dim,
                      float(limit), tuple(f"{s} at {g}" for s, g in modes), name,
                      zmap.to_physical)


def limits_text(output: str, upper: float | None, lower: float | None, unit: str = "") -> str:
    """The pass condition in words, e.g. "4.2 mm <= stroke_mm <= 4.4 mm"."""
    u = f" {unit}" if unit and unit != "1" else ""
    if lower is None:
        return f"{output} <= {upper:g}{u}"
    if upper is None:
        return f"{output} >= {lower:g}{u}"
    return f"{lower:g}{u} <= {output} <= {upper:g}{u}"


# --- allocation ----------------------------------------------------------------------------

@dataclass(frozen=True)
class FileAllocation:
    """The largest common scale of a tolerance set that keeps the yield at a target.

    `table`: per parameter its weight, the reference limits and the allocated limits (reference
    times scale times weight), in the parameter's unit. `trials`: every scale tried with its
    yield and counts (the step function the bisection walked)."""

    mechanism: str
    output: str
    upper: float | None
    lower: float | None
    tolerances: str
    target: float
    n: int
    seed: int
    scale: float
    yield_: float
    capped: bool  # True when the yield stays above the target up to the largest scale tried
    table: pd.DataFrame
    trials: pd.DataFrame
    adjust: str | None = None

    method = ("common scale k of the set (limits times k times each weight), bisection on the "
              "Monte-Carlo yield with common random numbers (one matrix of uniforms for every "
              "k): exact for the sample when the pass region is star-shaped about the nominal")

    def to_dataframe(self) -> pd.DataFrame:
        return self.table.copy()

    def as_tolerance_set(self, name: str | None = None) -> ToleranceSet:
        """The allocated limits as a ToleranceSet (each tolerance keeps its distribution)."""
        return ToleranceSet(name or f"{self.tolerances}*allocated", tuple(
            Tolerance(r["param"], r["lower"], r["upper"], r["dist"])
            for r in self.table.to_dict("records")), "allocated by sewtol (generic_yield)")

    def to_dict(self) -> dict:
        ci = stats.binomtest(int(round(self.yield_ * self.n)), self.n).proportion_ci(
            0.95, method="exact")
        return {"mechanism": self.mechanism, "output": self.output, "limit": self.upper,
                "lower_limit": self.lower, "adjust": self.adjust,
                "tolerances": self.tolerances, "target": self.target, "n": self.n,
                "seed": self.seed, "scale": self.scale, "yield": self.yield_,
                "yield_ci95": [float(ci.low), float(ci.high)], "capped": self.capped,
                "method": self.method, "rows": self.table.to_dict("records"),
                "trials": self.trials.to_dict("records")}


def allocate(mech, tolerances: ToleranceSet, output: str, target: float = 0.9973,
             upper: float | None = None, lower: float | None = None, n: int = 2000,
             seed: int = 0, weights: dict[str, float] | None = None,
             adjust=None, objective=None) -> FileAllocation:
    """The largest common scale k of `tolerances` (each limit times k times its weight, default
    weight 1) at which the fraction of n machines that run and keep `output` within the limits
    is at least `target` (see the module doc: common random numbers, bisection on k to a
    relative SCALE_RTOL). Machines that cannot run count against the yield. A scale at which the
    set would draw machines the parameter rules reject (a length <= 0) counts as too wide."""
    mech.output(output)
    _check_adjust(mech, adjust)
    upper, lower = check_limits(upper, lower)
    if not (isinstance(target, (int, float)) and 0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    if int(n) != n or n < 10:
        raise ParameterError("n", "must be a whole number of machines >= 10", n)
    if int(seed) != seed or seed < 0:
        raise ParameterError("seed", "must be a whole number >= 0", seed)
    tol = G._check_tolerances(mech, tolerances)
    weights = dict(weights or {})
    unknown = sorted(set(weights) - set(tol.params))
    if unknown:
        raise ParameterError("weights", "must name toleranced parameters ("
                             + ", ".join(tol.params) + ")", unknown)
    for k, w in weights.items():
        if not (np.isfinite(w) and w > 0):
            raise ParameterError("weights", f"{k}'s weight must be a positive number", w)
    w = np.array([float(weights.get(p, 1.0)) for p in tol.params])
    # common random numbers: the deviations at k = 1, scaled along their ray for every k
    u = np.random.default_rng(seed).random((int(n), len(tol.items)))
    base = {t.param: w[i] * t.from_unit(u[:, i]) for i, t in enumerate(tol.items)}
    record = mech.parameter_record()
    trials = []

    def yield_at(k):
        try:
            tol.scaled({p: k * w[i] for i, p in enumerate(tol.params)}).check_against(record)
        except ParameterError as exc:
            trials.append({"scale": k, "yield": np.nan, "ok": 0, "out_of_limits": 0,
                           "cannot_close": 0, "dead_point": 0, "note": exc.rule})
            return -1.0
        dev = {p: k * v for p, v in base.items()}
        y, status, _ = _evaluate(mech, G._values(mech, dev), output, adjust, objective)
        runs = status == "ok"
        inside = runs & (excess(np.where(runs, y, 0.0), upper, lower) <= 0)
        yk = float(np.mean(inside))
        trials.append({"scale": k, "yield": yk, "ok": int(inside.sum()),
                       "out_of_limits": int((runs & ~inside).sum()),
                       "cannot_close": int(np.sum(status == "cannot_close")),
                       "dead_point": int(np.sum(status == "dead_point")), "note": ""})
        return yk

    lo, hi, capped = 0.0, 1.0, False
    if yield_at(1.0) >= target:
        lo = 1.0
        for _ in range(MAX_DOUBLINGS):
            hi = 2.0 * lo
            if yield_at(hi) < target:
                break
            lo = hi
        else:
            capped = True
    else:
        for _ in range(MAX_DOUBLINGS):
            lo = 0.5 * hi
            if yield_at(lo) >= target:
                break
            hi = lo
        else:
            lo = 0.0
    if not capped and lo > 0:
        while hi - lo > SCALE_RTOL * lo:
            mid = 0.5 * (lo + hi)
            if yield_at(mid) >= target:
                lo = mid
            else:
                hi = mid
    done = {t["scale"]: t["yield"] for t in trials}
    y_lo = done.get(lo, float("nan"))  # nan: no scale down to 2**-20 reaches the target
    rows = [{"param": t.param, "unit": next(p.unit for p in mech.parameters
                                            if p.name == t.param),
             "weight": w[i], "reference_lower": t.lower, "reference_upper": t.upper,
             "lower": t.lower * lo * w[i], "upper": t.upper * lo * w[i], "dist": t.dist}
            for i, t in enumerate(tol.items)]
    trials_frame = pd.DataFrame(trials).sort_values("scale", kind="stable").reset_index(drop=True)
    return FileAllocation(mech.name, output, upper, lower, tolerances.name, float(target),
                          int(n), int(seed), float(lo), float(y_lo), capped, pd.DataFrame(rows),
                          trials_frame, ADJ.adjust_label(adjust))
