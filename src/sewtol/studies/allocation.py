"""Tolerance allocation of any mechanism: the largest common scale k of a tolerance set (each
limit times k times its weight) at which the yield of one output (as evaluated or adjusted;
machines that cannot run count against it) reaches a target, on common random numbers so that
each machine moves along a fixed ray as k grows; bracket by doubling or halving (or given),
then bisection to SCALE_RTOL or `steps`. Where the pass region is not star-shaped about the
nominal the crossing found need not be the largest: `trials` lists every k tried.
`allocate_by_cost`: the root-sum-square optimum shape t_i ~ (c_i / s_i^2)^(1/3), then its scale;
a tolerance that moves the output by less than `hold_below` is held at its reference limits
(`held_at_reference`). See docs/mechanism_files.md, "Allocation".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from sewtol.dependence import Dependence
from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import InputLaw, draw_units, refuse_conditioned, unit_streams
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.studies.adjusting import evaluated
from sewtol.studies.montecarlo import check_seed
from sewtol.studies.rare_event import checked_limits, spec_counts
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
class AllocatedLimits:
    """What every allocation of one output's yield holds (Allocation, least_cost.LeastCost): the
    case, and in the subclass the `table` of allocated limits per parameter, `adjust` and the set's
    `dependence`. KIND: the allocated set's name suffix and description."""

    mechanism: str
    output: str
    upper: float | None
    lower: float | None
    tolerances: str
    target: float

    KIND = ("allocated", "allocated by sewtol (studies.allocation)")

    def to_dataframe(self) -> pd.DataFrame:
        return self.table.copy()

    def as_tolerance_set(self, name: str | None = None) -> ToleranceSet:
        """The allocated limits as a ToleranceSet (each tolerance keeps its distribution, the
        set its copula)."""
        return ToleranceSet(name or f"{self.tolerances}*{self.KIND[0]}", tuple(
            Tolerance(r["param"], r["lower"], r["upper"], r["dist"])
            for r in self.table.to_dict("records")), self.KIND[1], dependence=self.dependence)

    def case_dict(self) -> dict:
        """The head of to_dict(): mechanism, output, limits, adjust, tolerances, target."""
        return {"mechanism": self.mechanism, "output": self.output, "limit": self.upper,
                "lower_limit": self.lower, "adjust": self.adjust,
                "tolerances": self.tolerances, "target": self.target}


@dataclass(frozen=True)
class Allocation(AllocatedLimits):
    """The largest common scale of a tolerance set that keeps the yield at a target.

    `table`: per parameter its weight, the reference limits and the allocated limits (reference
    times scale times weight), in the parameter's unit. `trials`: every scale tried with its
    yield and counts (the step function the bisection walked)."""

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

    def to_dict(self) -> dict:
        # yield NaN: no scale down to 2**-20 reaches the target (no interval either)
        ci = clopper_pearson(round(self.yield_ * self.n), self.n) \
            if np.isfinite(self.yield_) else None
        return {**self.case_dict(), "n": self.n, "seed": self.seed, "scale": self.scale,
                "yield": self.yield_, "yield_ci95": list(ci) if ci else [None, None],
                "capped": self.capped, "method": self.method,
                "rows": self.table.to_dict("records"), "trials": self.trials.to_dict("records")}


def refuse_relations(tolerances: ToleranceSet) -> None:
    """Allocation scales each tolerance by its own factor; a relation (sewtol.relations) is one
    limit on several of them, which no common scale defines, and the machines it rejects would
    change with the scale (no common random numbers): refused in one line."""
    refuse_conditioned(tolerances, "allocation scales each tolerance on its own and cannot "
                       "scale a relation between several; allocate the set without its "
                       "relations, then add them", "allocation draws unmatched machines; compare "
                       "selective assembly with tightening in the selective assembly study "
                       "(sewtol.studies.selective_assembly)")


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
    upper, lower = checked_limits(mech, output, adjust, upper, lower)
    spec = Spec(output, upper, lower)
    if not (isinstance(target, (int, float)) and 0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    if int(n) != n or n < 10:
        raise ParameterError("n", "must be a whole number of machines >= 10", n)
    seed = check_seed(seed)
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
        ok, out, cannot_close, dead_point = spec_counts(
            mech, machines(mech, InputLaw.of(trial).of_uniforms(u)), output, spec, adjust, fast,
            failures, **options)
        trials.append({"scale": k, "yield": ok / n, "ok": ok, "out_of_limits": out,
                       "cannot_close": cannot_close, "dead_point": dead_point, "note": ""})
        return ok / n

    # the bracket: given, or (1, 2^j) by doubling, or (0, 1), whose bisection halves from 1
    lo, hi = (0.0, 1.0) if bracket is None else map(float, bracket)
    capped = yield_at(hi) >= target
    if capped and bracket is None:
        for _ in range(MAX_DOUBLINGS):
            lo, hi = hi, 2.0 * hi
            if yield_at(hi) < target:
                capped = False
                break
    lo = hi if capped else lo
    floor = hi * 2.0**-MAX_DOUBLINGS  # (0, hi) failing down to here: no scale keeps it
    for _ in range(0 if capped else MAX_BISECTIONS if steps is None else int(steps)):
        if steps is None and (hi - lo <= SCALE_RTOL * lo if lo > 0 else hi <= floor):
            break
        mid = np.sqrt(max(lo, hi * 1e-6) * hi) if geometric else 0.5 * (lo + hi)
        lo, hi = (mid, hi) if yield_at(mid) >= target else (lo, mid)
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
    """The widest tolerances of the cost shape that keep the yield at `target` (the module
    docstring). costs: c_i per parameter (> 0, default 1); adjust, options: as `allocate`;
    scan_options: the adjuster's options for the slopes (default options); figure: the slopes
    read this extra figure of the adjusted scan (the needle's exact total_um) instead of its
    value; cap: the largest half-width (the parameter's unit); steps: bisection steps (None: to
    SCALE_RTOL); hold_below: see the module docstring (None: 1e-6 of the largest change). The
    table adds `cost_weight`, `slope` (output per parameter unit) and `held_at_reference`."""
    ref = checked(mech, reference)
    refuse_relations(ref)
    c = _per_parameter(costs, ref.params, "costs")
    r = scan(mech, ref, (), adjust, output, fast=fast,
             **(options if scan_options is None else scan_options))
    y, y0 = ((evaluated(mech, v, output, fast=fast) for v in (r.values, None)) if adjust is None
             else (a.value if figure is None else a.extras[figure]
                   for a in (r.adjusted, r.adjusted_nominal)))
    width = np.array([max(abs(t.upper), abs(t.lower)) if symmetric else 0.5 * (t.upper - t.lower)
                      for t in ref.items])
    change = np.array([np.nanmax(np.abs(np.asarray(y, float)[np.asarray(r.params) == t.param]
                                        - float(np.ravel(y0)[0]))) for t in ref.items])
    slope = np.where(np.isfinite(change), change / width, np.inf)
    s = np.clip(slope, 1e-9, 1e12)
    shape = (c / s**2) ** (1.0 / 3.0)
    finite = change[np.isfinite(change)]
    held = np.zeros(len(ref.items), bool) if symmetric else slope * width < (
        1e-6 * (finite.max() if finite.size else 0.0) if hold_below is None else hold_below)
    held[:] = held & ~held.all()
    shape = np.where(held, width, shape / shape[~held].max())

    def limits(k):
        f = np.where(held, width, np.minimum(k * shape, cap)) / width
        return ToleranceSet(reference.name, tuple(
            replace(t, lower=-k * a, upper=k * a, shift=t.shift * k * a / w) if symmetric else
            replace(t, lower=t.lower * fi, upper=t.upper * fi, shift=t.shift * fi)
            for t, a, w, fi in zip(ref.items, shape, width, f, strict=True)),
            dependence=ref.dependence)

    # symmetric: k is the widest tolerance, in (0, cap); else k up to where every tolerance
    # reaches the cap, bisected geometrically (it spans decades)
    a = allocate(mech, ref, output, target, upper, lower, n, seed, None, adjust,
                 bracket=(0.0, cap if symmetric else float(cap / shape[~held].min())),
                 steps=steps, geometric=not symmetric, limits=limits, fast=fast, **options)
    table = a.table.drop(columns="weight").assign(cost_weight=c, slope=s, held_at_reference=held)
    return replace(a, table=table, method=COST_METHOD)
