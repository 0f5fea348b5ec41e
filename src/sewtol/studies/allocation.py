"""Tolerance allocation of any mechanism: the largest common scale of a tolerance set that keeps
the yield of one output at a target.

`allocate(mech, tolerances, output, target, upper, lower, ...)`: the largest scale k of the set
(each tolerance's limits times k times its weight) at which the yield (the fraction of n
machines that give a value within the limits; machines that cannot run count against it)
reaches the target. The output is as evaluated (the plug-in kernel where the mechanism has one)
or minimised over the compensators `adjust` (`sewtol.studies.adjusting.adjusted`: the needle's
exact beta optimum). Common random numbers: one matrix of uniforms (the one sampler,
sewtol.law) for every trial k, so each machine's deviation moves along a fixed ray from nominal
as k grows. The yield is then a step function of k, and non-increasing in k when the pass
region is star-shaped about the nominal along those rays (e.g. an output monotone in each
parameter, or |2 r - 2 r0| < limit); bisection finds the crossing. Where the pass region is not
star-shaped the yield need not be monotone, and the bisection finds a crossing, not necessarily
the largest one: `trials` lists every k tried. The bracket is found by doubling (or halving)
from k = 1, or given (`bracket`, e.g. the needle's (0, max_mm) for a set of shapes); the
bisection runs to a relative SCALE_RTOL, or a given number of `steps`.

`allocate_by_cost(mech, reference, output, ...)`: the shape found first, then its scale. Cost is
reciprocal, sum c_i / t_i; each tolerance's slope s_i is the output's largest change (fixed, or
adjusted over the compensators) at its reference limits, each tolerance alone (the scan,
`sewtol.studies.scan`), per unit of its width; the shape t_i ~ (c_i / s_i^2)^(1/3) is the
root-sum-square optimum, and `allocate` finds its common scale. Two forms:
- symmetric (the needle's source study): +/- t_i, slopes per the larger side of each reference
  tolerance, the scale (the widest tolerance, largest shape 1) bisected in (0, cap);
- otherwise each reference tolerance keeps its own (possibly asymmetric) shape, both limits
  scaled by min(k a_i, cap) / h_i (h_i its half-width, slopes per h_i), k bisected
  geometrically (it spans decades) up to where every tolerance reaches the cap. A tolerance
  that moves the output by less than `hold_below` at its reference limits (one a compensator
  cancels alone, e.g. the needle's guide bore under the guide shift; or one the output does not
  see) has no slope to shape it: it is held at its reference limits (`held_at_reference`), not
  scaled (scaled like the others it would take the cap at once and could use up the
  compensators' range the others need).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from sewtol.dependence import Dependence
from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import InputLaw, draw_units, unit_streams
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.studies.adjusting import evaluated, failures_of
from sewtol.studies.rare_event import check_adjust, limits_of, output_of
from sewtol.studies.scan import checked, scan
from sewtol.tolerances import Tolerance, ToleranceSet

# bisection on the scale stops when the bracket is this small relative to the scale
SCALE_RTOL = 1e-4
MAX_DOUBLINGS = 20
MAX_BISECTIONS = 60  # steps to SCALE_RTOL at most (about 14 decades of bracket)
SET_METHOD = ("common scale k of the set (limits times k times each weight), bisection on the "
              "Monte-Carlo yield with common random numbers (one matrix of uniforms for every "
              "k): exact for the sample when the pass region is star-shaped about the nominal")
COST_METHOD = ("reciprocal cost sum c_i / t_i; shape t_i ~ (c_i / s_i^2)^(1/3) (s_i the "
               "output's largest change at the reference limits per unit width, from the "
               "scan); common scale by bisection on the Monte-Carlo yield (common random "
               "numbers)")


@dataclass(frozen=True)
class Allocation:
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
    # a mechanism's names for to_dataframe(): table column -> its name (None: the table as is)
    columns: dict | None = None
    dependence: Dependence | None = None  # the set's copula, kept by the allocated set
    method: str = SET_METHOD

    def to_dataframe(self) -> pd.DataFrame:
        if self.columns is None:
            return self.table.copy()
        return self.table[list(self.columns)].rename(columns=self.columns)

    def as_tolerance_set(self, name: str | None = None) -> ToleranceSet:
        """The allocated limits as a ToleranceSet (each tolerance keeps its distribution)."""
        return ToleranceSet(name or f"{self.tolerances}*allocated", tuple(
            Tolerance(r["param"], r["lower"], r["upper"], r["dist"])
            for r in self.table.to_dict("records")), "allocated by sewtol (studies.allocation)",
            dependence=self.dependence)

    def to_dict(self) -> dict:
        # yield NaN: no scale down to 2**-20 reaches the target (no interval either)
        ci = clopper_pearson(round(self.yield_ * self.n), self.n) \
            if np.isfinite(self.yield_) else None
        return {"mechanism": self.mechanism, "output": self.output, "limit": self.upper,
                "lower_limit": self.lower, "adjust": self.adjust,
                "tolerances": self.tolerances, "target": self.target, "n": self.n,
                "seed": self.seed, "scale": self.scale, "yield": self.yield_,
                "yield_ci95": list(ci) if ci else [None, None],
                "capped": self.capped,
                "method": self.method, "rows": self.table.to_dict("records"),
                "trials": self.trials.to_dict("records")}


def refuse_relations(tolerances: ToleranceSet) -> None:
    """Allocation scales each tolerance by its own factor; a relation (sewtol.relations) is one
    limit on several of them, which no common scale defines, and the machines it rejects would
    change with the scale (no common random numbers): refused in one line."""
    if tolerances.relations:
        raise ParameterError(tolerances.relations[0].where, "allocation scales each tolerance "
                             "on its own and cannot scale a relation between several; allocate "
                             "the set without its relations, then add them",
                             tolerances.relations[0].expr)
    if tolerances.selective is not None:
        raise ParameterError(tolerances.selective.where, "allocation draws unmatched machines; "
                             "compare selective assembly with tightening in the selective "
                             "assembly study (sewtol.studies.selective_assembly)",
                             tolerances.selective.as_dict())


def _per_parameter(weights: dict | None, params, field: str) -> np.ndarray:
    """Positive weights by parameter name (default 1), in the order of params."""
    weights = dict(weights or {})
    unknown = sorted(set(weights) - set(params))
    if unknown:
        raise ParameterError(field, "must name toleranced parameters (" + ", ".join(params)
                             + ")", unknown)
    for k, w in weights.items():
        if not (np.isfinite(w) and w > 0):
            raise ParameterError(field, f"{k}'s weight must be a positive number", w)
    return np.array([float(weights.get(p, 1.0)) for p in params])


def allocate(mech, tolerances: ToleranceSet, output: str, target: float = 0.9973,
             upper: float | None = None, lower: float | None = None, n: int = 2000,
             seed: int = 0, weights: dict[str, float] | None = None,
             adjust=None, *, bracket: tuple[float, float] | None = None,
             steps: int | None = None, geometric: bool = False,
             limits: Callable[[float], ToleranceSet] | None = None,
             failures: Callable | None = None, fast: bool = True, **options) -> Allocation:
    """The largest common scale k of `tolerances` (each limit times k times its weight, default
    weight 1) at which the fraction of n machines that run and keep `output` within the limits
    is at least `target` (limits default to the file's [[specs]] entry; see the module doc:
    common random numbers, bisection on k to a relative SCALE_RTOL). Machines that cannot run
    count against the yield. A scale at which the set would draw machines the parameter rules
    reject (a length <= 0) counts as too wide.

    adjust: compensators as `adjusting.adjusted` takes them; options go to the mechanism's
    strategy adjuster. bracket (low, high): search k there (k = high when its yield reaches the
    target) instead of doubling from 1; steps: that many bisection steps instead of SCALE_RTOL;
    geometric: bisect at sqrt(max(lo, 1e-6 hi) hi) (k spans decades). limits(k): the trial set
    at scale k instead of each limit times k times its weight (e.g. the needle's shapes capped
    at a largest tolerance); the table's limits are then those of limits(scale).
    failures(mech, values, output) -> (status, group) of machines without a value (default the
    mechanism's plug-in, else adjusting.evaluated_failures), counted per trial. fast=False: the
    generic reference path."""
    mech.output(output)
    check_adjust(mech, adjust)
    upper, lower = limits_of(mech, output, upper, lower)
    spec = Spec(output, upper, lower)
    if not (isinstance(target, (int, float)) and 0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    if int(n) != n or n < 10:
        raise ParameterError("n", "must be a whole number of machines >= 10", n)
    if int(seed) != seed or seed < 0:
        raise ParameterError("seed", "must be a whole number >= 0", seed)
    tol = checked(mech, tolerances)
    refuse_relations(tol)
    w = _per_parameter(weights, tol.params, "weights")
    # common random numbers: montecarlo's uniforms for this seed, mapped through the scaled set
    # for every k, so each machine moves along its ray from nominal
    u = draw_units(unit_streams(seed, n), len(tol.items), 0, n)
    record = mech.parameter_record()
    trials = []

    def yield_at(k):
        try:
            trial = limits(k) if limits is not None else \
                tol.scaled({p: k * w[i] for i, p in enumerate(tol.params)})
            trial.check_against(record)
        except ParameterError as exc:
            trials.append({"scale": k, "yield": np.nan, "ok": 0, "out_of_limits": 0,
                           "cannot_close": 0, "dead_point": 0, "note": exc.rule})
            return -1.0
        values = machines(mech, InputLaw.of(trial).of_uniforms(u))
        y = output_of(mech, values, output, adjust, fast, **options)
        status = np.full(y.size, "ok", dtype=object)
        bad = ~np.isfinite(y)
        if bad.any():
            status[bad] = failures_of(mech, fast, failures)(
                mech, {p: v[bad] for p, v in values.items()}, output)[0]
        runs = status == "ok"
        inside = runs & spec.passes(y)
        yk = float(np.mean(inside))
        trials.append({"scale": k, "yield": yk, "ok": int(inside.sum()),
                       "out_of_limits": int((runs & ~inside).sum()),
                       "cannot_close": int(np.sum(status == "cannot_close")),
                       "dead_point": int(np.sum(status == "dead_point")), "note": ""})
        return yk

    lo, hi, capped = 0.0, 1.0, False
    if bracket is not None:
        lo, hi = map(float, bracket)
        if yield_at(hi) >= target:
            lo, capped = hi, True
    elif yield_at(1.0) >= target:
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
    def bisect(lo, hi):
        mid = np.sqrt(max(lo, hi * 1e-6) * hi) if geometric else 0.5 * (lo + hi)
        return (mid, hi) if yield_at(mid) >= target else (lo, mid)

    if not capped and (steps is not None or lo > 0 or bracket is not None):
        floor = hi * 2.0**-MAX_DOUBLINGS  # (0, hi) failing down to here: no scale keeps it
        for _ in range(MAX_BISECTIONS if steps is None else int(steps)):
            if steps is None and (hi - lo <= SCALE_RTOL * lo if lo > 0 else hi < floor):
                break
            lo, hi = bisect(lo, hi)
    done = {t["scale"]: t["yield"] for t in trials}
    y_lo = done.get(lo, float("nan"))  # nan: no scale down to 2**-20 reaches the target
    final = limits(lo).items if limits is not None else None
    rows = [{"param": t.param, "unit": next(p.unit for p in mech.parameters
                                            if p.name == t.param),
             "weight": w[i], "reference_lower": t.lower, "reference_upper": t.upper,
             "lower": t.lower * lo * w[i] if final is None else final[i].lower,
             "upper": t.upper * lo * w[i] if final is None else final[i].upper,
             "dist": t.dist if final is None else final[i].dist}
            for i, t in enumerate(tol.items)]
    trials_frame = pd.DataFrame(trials).sort_values("scale", kind="stable").reset_index(drop=True)
    return Allocation(mech.name, output, upper, lower, tolerances.name, float(target), int(n),
                      int(seed), float(lo), float(y_lo), capped, pd.DataFrame(rows), trials_frame,
                      adjust, dependence=tol.dependence)


def allocate_by_cost(mech, reference: ToleranceSet, output: str, target: float = 0.9973,
                     upper: float | None = None, lower: float | None = None, n: int = 2000,
                     seed: int = 0, costs: dict[str, float] | None = None, adjust=None, *,
                     symmetric: bool = False, cap: float = 1.0, steps: int | None = None,
                     hold_below: float | None = None, figure: str | None = None,
                     scan_options: dict | None = None, fast: bool = True,
                     **options) -> Allocation:
    """The widest tolerances of the cost shape that keep the yield at `target` (see the module
    docstring: slopes from the scan at the reference limits, t_i ~ (c_i / s_i^2)^(1/3), then
    `allocate`'s common scale on the same machines).

    costs: c_i per parameter (> 0; default 1). adjust, options: the compensators and the
    strategy adjuster's options, as `allocate` takes them; scan_options: the adjuster's
    options for the slopes (default options); figure: the slopes read this extra figure of the
    adjusted scan (a plug-in's, e.g. the needle's exact total_um) instead of its value.
    symmetric: the source study's +/- t_i form; cap: the largest tolerance (half-width, the
    parameter's unit); steps: bisection steps (None: to SCALE_RTOL); hold_below: the change of
    the output at the reference limits below which a tolerance is held there (not symmetric;
    None: 1e-6 of the largest change). The table adds per parameter `cost_weight`, `slope`
    (output per parameter unit), the set's `reference_lower`/`reference_upper` and
    `held_at_reference`."""
    mech.output(output)
    if not (isinstance(target, (int, float)) and 0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    ref = checked(mech, reference)
    refuse_relations(ref)
    c = _per_parameter(costs, ref.params, "costs")
    r = scan(mech, ref, (), adjust, output, fast=fast,
             **(options if scan_options is None else scan_options))
    if adjust is None:
        y, y0 = evaluated(mech, r.values, output, fast=fast), \
            evaluated(mech, None, output, fast=fast)[0]
    else:
        def pick(a):
            return a.value if figure is None else a.extras[figure]
        y, y0 = pick(r.adjusted), float(pick(r.adjusted_nominal)[0])
    of = np.asarray(r.params)
    if symmetric:
        width = np.array([max(abs(t.upper), abs(t.lower)) for t in ref.items])
    else:
        width = np.array([0.5 * (t.upper - t.lower) for t in ref.items])
    slope = []
    for t, wi in zip(ref.items, width, strict=True):
        worst = np.nanmax(np.abs(np.asarray(y, float)[of == t.param] - y0))
        slope.append(float(worst) / wi if np.isfinite(worst) else np.inf)
    s = np.clip(np.array(slope), 1e-9, 1e12)
    free = (c / s**2) ** (1.0 / 3.0)
    held = np.zeros(len(ref.items), bool)
    if symmetric:
        # the scale k is the widest tolerance, searched in (0, cap): none exceeds the cap; the
        # copula ties ranks, whatever the widths: every trial keeps the set's dependence
        shape = free / free.max()
        a = allocate(mech, ToleranceSet(reference.name, tuple(
            replace(t, lower=-ai, upper=ai, shift=t.shift * ai / wi)
            for t, ai, wi in zip(ref.items, shape, width, strict=True)),
            dependence=ref.dependence), output, target, upper, lower, n, seed, None, adjust,
            bracket=(0.0, cap), steps=steps, fast=fast, **options)
    else:
        change = np.array(slope) * width
        finite = change[np.isfinite(change)]
        limit = hold_below if hold_below is not None else \
            1e-6 * (finite.max() if finite.size else 0.0)
        held = change < limit
        if held.all():
            held[:] = False
        shape = np.where(held, np.nan, free)
        shape = np.where(held, width, shape / np.nanmax(shape))

        def limits(k):
            f = np.where(held, width, np.minimum(k * shape, cap)) / width
            return ToleranceSet("trial", tuple(
                replace(t, lower=t.lower * fi, upper=t.upper * fi, shift=t.shift * fi)
                for t, fi in zip(ref.items, f, strict=True)), dependence=ref.dependence)

        # k up to where every tolerance reaches the cap, so the cap never ends the search early
        a = allocate(mech, ref, output, target, upper, lower, n, seed, None, adjust,
                     bracket=(0.0, float(cap / shape[~held].min())), steps=steps,
                     geometric=True, limits=limits, fast=fast, **options)
    table = a.table.drop(columns="weight").assign(
        cost_weight=c, slope=s, reference_lower=[t.lower for t in ref.items],
        reference_upper=[t.upper for t in ref.items], held_at_reference=held)
    return replace(a, tolerances=reference.name, table=table, method=COST_METHOD)
