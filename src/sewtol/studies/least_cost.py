"""Least-cost tolerance allocation of any mechanism: asymmetric zones (width and centre per
parameter) of least total cost (sewtol.costs) that keep the yield of one output at a target,
with a Clopper-Pearson `confidence` on n machines of common random numbers (one matrix of
uniforms of the one sampler, mapped through every candidate's zones). Search: scipy's
differential evolution over log half-width and centre ratio, infeasible points scored above
every feasible one, the first restart seeded with the set's largest common scale, then a
bisection polish of each limit for `sweeps` sweeps; restarts from children of the seed must
agree. Active constraints per limit: "yield", "max width", "nominal" or "". `fresh_check`
re-estimates the yield on fresh machines. See docs/mechanism_files.md, "Least-cost allocation".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize, stats

from sewtol.costs import CostModel
from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import InputLaw, draw_units, unit_streams
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.studies.allocation import AllocatedLimits, refuse_relations
from sewtol.studies.rare_event import checked_limits, output_of
from sewtol.studies.scan import checked
from sewtol.tolerances import Tolerance, ToleranceSet

# a limit is called active when pushing it out by this share of the half-width breaks the yield
ACTIVE_STEP = 0.01
# the polish pushes a limit to this share of the zone's half-width (at most POLISH_STEPS
# bisection steps after the bracket), the common scale by SCALE_STEPS geometric steps
POLISH_RTOL = 1e-3
POLISH_STEPS = 16
# the polish's scan of each zone's centre: +-SLIDE_SPAN of its half-width in SLIDE_POINTS
SLIDE_SPAN = 0.1
SLIDE_POINTS = 5
SCALE_STEPS = 24


def allowed_failures(n: int, target: float, confidence: float | None) -> int:
    """The most failures among n machines that still meet `target`: with confidence None,
    failures <= n (1 - target); else the one-sided Clopper-Pearson lower bound at `confidence`
    of the yield (n - failures) / n must reach the target. -1: no count meets it (n too small)."""
    if confidence is None:
        return int(np.floor(n * (1.0 - target) + 1e-9))
    f = np.arange(n + 1)
    ok = n - f
    # lower bound of a binomial proportion with ok successes: Beta(1 - confidence; ok, f + 1)
    low = np.where(ok > 0, stats.beta.ppf(1.0 - confidence, np.maximum(ok, 1), f + 1), 0.0)
    good = np.flatnonzero(low >= target)
    return int(good.max()) if good.size else -1


@dataclass(frozen=True)
class FreshCheck:
    """The allocated set's yield on machines not used by the search."""

    n: int
    seed: int
    ok: int
    out_of_limits: int
    cannot_run: int
    yield_: float
    ci_low: float
    ci_high: float
    target: float

    @property
    def meets(self) -> bool:
        """True when the 95 % interval reaches the target (the point estimate may be below)."""
        return self.ci_high >= self.target

    def as_dict(self) -> dict:
        return {"n": self.n, "seed": self.seed, "ok": self.ok,
                "out_of_limits": self.out_of_limits, "cannot_run": self.cannot_run,
                "yield": self.yield_, "yield_ci95": [self.ci_low, self.ci_high],
                "meets_target": self.meets}


class ZoneYield:
    """Counts of n fixed machines (common random numbers) for any zones of a tolerance set.

    zone(lower, upper) -> the ToleranceSet of those limits (each tolerance's distribution, the
    set's copula); counts(lower, upper) -> (ok, out_of_limits, cannot_run), or None when the
    zones draw machines the parameter rules reject (a length <= 0)."""

    def __init__(self, mech, tolerances: ToleranceSet, output: str, spec: Spec, u: np.ndarray,
                 adjust=None, fast: bool = True, options: dict | None = None):
        self.mech, self.tol, self.output, self.spec, self.u = mech, tolerances, output, spec, u
        self.adjust, self.fast = adjust, fast
        self.options = dict(options or {})
        self.record = mech.parameter_record()
        self.calls = 0

    @property
    def n(self) -> int:
        return len(self.u)

    def zone(self, lower, upper, name: str = "zone") -> ToleranceSet:
        return ToleranceSet(name, tuple(
            Tolerance(t.param, float(lo), float(hi), t.dist)
            for t, lo, hi in zip(self.tol.items, lower, upper, strict=True)),
            self.tol.description, dependence=self.tol.dependence, cost=self.tol.cost)

    def counts(self, lower, upper) -> tuple[int, int, int] | None:
        self.calls += 1
        try:
            trial = self.zone(lower, upper).check_against(self.record)
        except ParameterError:
            return None
        values = machines(self.mech, InputLaw.of(trial).of_uniforms(self.u))
        y = output_of(self.mech, values, self.output, self.adjust, self.fast, **self.options)
        runs = np.isfinite(y)  # no value (cannot close, dead point): counted, never a pass
        inside = runs & self.spec.passes(y)
        return int(inside.sum()), int((runs & ~inside).sum()), int((~runs).sum())

    def meets(self, lower, upper, need_ok: int) -> bool:
        """True when at least need_ok machines pass in the zones (False for a rejected one)."""
        c = self.counts(lower, upper)
        return c is not None and c[0] >= need_ok


@dataclass(frozen=True)
class LeastCost(AllocatedLimits):
    """The least-cost zones of a tolerance set for a yield target (see the module doc).

    `table`: per parameter the cost model, the reference and allocated limits, half-width,
    centre, cost and what limits each side. `compare`: the allocation beside the reference shape
    at its largest common scale (same criterion, same machines), each with its cost and its
    yield on the search sample and on fresh machines. `restarts`: each search's cost."""

    confidence: float | None
    n: int
    seed: int
    allowed_failures: int
    failures: int
    cost: float
    table: pd.DataFrame
    restarts: pd.DataFrame
    compare: pd.DataFrame
    check: FreshCheck | None
    adjust: str | None = None
    spread: float = 0.0  # (largest - smallest) / smallest cost over the restarts
    dependence: object = None
    evaluations: int = 0

    KIND = ("least_cost", "allocated at least cost by sewtol (studies.least_cost)")
    method = ("differential evolution (scipy) over each zone's log half-width and centre, "
              "cost minimised under the Monte-Carlo yield constraint on common random numbers, "
              "then each limit pushed outward by bisection; restarts from spawned seeds")

    @property
    def yield_(self) -> float:
        return (self.n - self.failures) / self.n

    @property
    def constraint_active(self) -> bool:
        """True when the sample has exactly the failures the target allows."""
        return self.failures == self.allowed_failures

    def to_dict(self) -> dict:
        lo, hi = clopper_pearson(self.n - self.failures, self.n)
        return {**self.case_dict(), "confidence": self.confidence, "n": self.n,
                "seed": self.seed, "allowed_failures": self.allowed_failures,
                "failures": self.failures, "yield": self.yield_, "yield_ci95": [lo, hi],
                "yield_constraint_active": self.constraint_active, "cost": self.cost,
                "restart_cost_spread": self.spread, "evaluations": self.evaluations,
                "fresh_check": None if self.check is None else self.check.as_dict(),
                "method": self.method, "rows": self.table.to_dict("records"),
                "compare": self.compare.to_dict("records"),
                "restarts": self.restarts.to_dict("records")}


def costs_of(tolerances: ToleranceSet, costs=None) -> list[CostModel]:
    """The cost model of every toleranced parameter: `costs` (param -> CostModel, or "*" for
    every parameter without its own) over the set's `cost` table; refused in one line when a
    parameter has none (sewtol states no default coefficients)."""
    given = {c.param: c for c in tolerances.cost}
    given.update(costs or {})
    out = []
    for t in tolerances.items:
        c = given.get(t.param, given.get("*"))
        if c is None:
            raise ParameterError(f"{tolerances.name}.cost.{t.param}", "has no cost model: "
                                 "least-cost allocation needs one per toleranced parameter "
                                 "(a [cost] table in the tolerance file, or --cost), sewtol "
                                 "assumes none", None)
        out.append(c if c.param == t.param else CostModel(
            t.param, c.model, c.a, c.b, c.k, c.m, f"--cost (for {t.param})"))
    return out


def total_cost(models: list[CostModel], half) -> float:
    return float(sum(float(m.cost(h)) for m, h in zip(models, half, strict=True)))


def common_scale(zy: ZoneYield, lower, upper, max_half, need_ok: int,
                 steps: int = SCALE_STEPS) -> tuple[float, np.ndarray, np.ndarray]:
    """The largest common factor k of the zones [k lower, k upper] (each half-width capped at
    max_half, the centre ratio kept) whose machines meet need_ok, by geometric bisection on the
    common random numbers: (k, lower, upper); k = 0 when none down to 1e-6 does."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    half, mid = 0.5 * (upper - lower), 0.5 * (upper + lower)
    ratio = np.divide(mid, half, out=np.zeros_like(mid), where=half > 0)

    def limits(k):
        h = np.minimum(k * half, max_half)
        return h * (ratio - 1.0), h * (ratio + 1.0)

    def ok(k):
        return zy.meets(*limits(k), need_ok)

    hi = float(np.max(max_half / np.where(half > 0, half, np.inf)))
    if ok(hi):
        return hi, *limits(hi)
    lo = 1e-6 * hi
    if not ok(lo):
        return 0.0, *limits(0.0)
    for _ in range(steps):
        mid_k = np.sqrt(lo * hi)
        lo, hi = (mid_k, hi) if ok(mid_k) else (lo, mid_k)
    return lo, *limits(lo)


def polish(zy: ZoneYield, lower, upper, max_half, need_ok: int, sweeps: int = 2,
           steps: int = POLISH_STEPS, scan: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Each zone in turn pushed outward (`push`) and slid (`slide`), `sweeps` times; then
    moved back to the nominal where that keeps need_ok (`recentre`)."""
    lower, upper = np.array(lower, float), np.array(upper, float)
    for _ in range(sweeps):
        for i in range(len(lower)):
            lower, upper = push(zy, lower, upper, i, max_half, need_ok, steps)
            if scan:
                lower, upper = slide(zy, lower, upper, i, max_half, need_ok, steps)
    return recentre(zy, lower, upper, need_ok)


def slide(zy: ZoneYield, lower, upper, i: int, max_half, need_ok: int,
          steps: int = POLISH_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Zone i's centre scanned (SLIDE_POINTS centres within +-SLIDE_SPAN of its half-width)
    and, at each centre, its widest half-width that meets need_ok (bracket and bisection to
    POLISH_RTOL); the widest kept. A grid: a split reached only in a narrow window of centres
    can be missed (the tests measure how far the result stays below the sample's optimum).
    Pushing a limit outward only ever adds failures on its own side, so the pushes end where
    each side is blocked; which of the allowed failures fall on which side is what the centre
    decides, and only a move of both limits together reaches another such split."""
    best = (upper[i] - lower[i], lower.copy(), upper.copy())
    if 0.5 * best[0] >= max_half[i] * (1 - 1e-9):
        return lower, upper  # at its largest width: nothing to gain
    half0 = 0.5 * (best[2][i] - best[1][i])
    centre0 = 0.5 * (best[2][i] + best[1][i])
    for c in centre0 + half0 * np.linspace(-SLIDE_SPAN, SLIDE_SPAN, SLIDE_POINTS):
        lo, hi = best[1].copy(), best[2].copy()

        def ok(h, c=c, lo=lo, hi=hi):
            if not c - h <= 0.0 <= c + h:
                return False
            lo[i], hi[i] = c - h, c + h
            return zy.meets(lo, hi, need_ok)

        # bracket: double while it holds (up to max_half), else halve until it holds
        good, bad, h = None, None, half0
        while True:
            if ok(h):
                good = h
                if bad is not None or h >= max_half[i]:
                    break
                h = min(2.0 * h, max_half[i])
            else:
                bad = h
                if good is not None:
                    break
                h *= 0.5
                if h < 1e-3 * half0:
                    break
        if good is None:
            continue
        for _ in range(steps):
            if bad is None or bad - good <= POLISH_RTOL * half0:
                break
            mid = 0.5 * (good + bad)
            good, bad = (mid, bad) if ok(mid) else (good, mid)
        if 2.0 * good > best[0]:
            lo[i], hi[i] = c - good, c + good
            best = (2.0 * good, lo.copy(), hi.copy())
    return best[1], best[2]


def push(zy: ZoneYield, lower, upper, i: int, max_half, need_ok: int,
         steps: int = POLISH_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Zone i's lower, then upper limit pushed outward by bisection as far as need_ok machines
    still pass and its half-width stays within max_half[i]."""
    lower, upper = np.array(lower, float), np.array(upper, float)
    for side in (0, 1):
        # the farthest this limit may go: the other limit + 2 max_half
        far = upper[i] - 2 * max_half[i] if side == 0 else lower[i] + 2 * max_half[i]
        here = lower[i] if side == 0 else upper[i]
        if abs(far - here) <= 1e-12 * max_half[i]:
            continue

        def ok(v, i=i, side=side):
            lo, hi = lower.copy(), upper.copy()
            (lo if side == 0 else hi)[i] = v
            return zy.meets(lo, hi, need_ok)

        # bracket by doubling steps of the half-width, then bisect to POLISH_RTOL of it
        sign = -1.0 if side == 0 else 1.0
        half = 0.5 * (upper[i] - lower[i])
        good, bad, reach = here, None, half
        while bad is None:
            v = here + sign * reach
            if sign * (v - far) >= 0:
                v = far
            if ok(v):
                good = v
                if v == far:
                    break
                reach *= 2.0
            else:
                bad = v
        for _ in range(steps):
            if bad is None or abs(bad - good) <= POLISH_RTOL * half:
                break
            mid = 0.5 * (good + bad)
            good, bad = (mid, bad) if ok(mid) else (good, mid)
        (lower if side == 0 else upper)[i] = good
    return lower, upper


def recentre(zy: ZoneYield, lower, upper, need_ok: int) -> tuple[np.ndarray, np.ndarray]:
    """Each zone moved to be symmetric about the nominal (same width) where the machines still
    meet need_ok: a shift is kept only where it buys width, not where the sample leaves the
    centre free (a parameter at its largest width, one the output hardly feels)."""
    lower, upper = np.array(lower, float), np.array(upper, float)
    for i in range(len(lower)):
        half = 0.5 * (upper[i] - lower[i])
        if lower[i] == -half:
            continue
        lo, hi = lower.copy(), upper.copy()
        lo[i], hi[i] = -half, half
        if zy.meets(lo, hi, need_ok):
            lower, upper = lo, hi
    return lower, upper


def limited_by(zy: ZoneYield, lower, upper, max_half, need_ok: int) -> list[tuple[str, str]]:
    """What stops each limit (the module doc): per parameter (lower side, upper side)."""
    out = []
    half = 0.5 * (upper - lower)
    for i in range(len(lower)):
        sides = []
        for side in (0, 1):
            if half[i] >= max_half[i] * (1 - 1e-9):
                sides.append("max width")
                continue
            lo, hi = lower.copy(), upper.copy()
            step = ACTIVE_STEP * max(half[i], 1e-12)
            if side == 0:
                lo[i] -= step
            else:
                hi[i] += step
            if not zy.meets(lo, hi, need_ok):
                sides.append("yield")
            elif (lower[i] if side == 0 else upper[i]) == 0.0:
                sides.append("nominal")
            else:
                sides.append("")
        out.append(tuple(sides))
    return out


def least_cost(mech, tolerances: ToleranceSet, output: str, target: float = 0.9973,
               upper: float | None = None, lower: float | None = None, n: int = 2000,
               seed: int = 0, adjust=None, costs: dict | None = None, *,
               confidence: float | None = 0.95, widen: float = 4.0, narrow: float = 0.01,
               max_half: float | dict | None = None,
               restarts: int = 2, popsize: int = 5, maxiter: int = 40, sweeps: int = 2,
               centre_scan: bool = True,
               shape: ToleranceSet | None = None, shape_name: str = "common scale",
               check_n: int | None = None, check_seed: int | None = None,
               fast: bool = True, **options) -> LeastCost:
    """The zones of least total cost whose n machines meet `target` (the module doc).

    tolerances: the reference set (its parameters, distributions, copula and, unless `costs`
    gives them, its cost table); half-widths are searched in [narrow, widen] times the
    reference's. costs: param -> sewtol.costs.CostModel ("*": every parameter without its
    own), over the set's table. confidence: see `allowed_failures`. shape: the set whose largest
    common scale (same criterion, same machines) is the comparison (default the reference set);
    shape_name labels it. check_n (default 10 n) fresh machines of seed check_seed (default
    seed + 1) re-estimate the yield of both; check_n 0: no check. centre_scan False: the
    polish pushes the limits without scanning the centres (cheaper: for slow models). adjust and options: the
    compensators and the strategy adjuster's options, as `sewtol.studies.allocation.allocate`
    takes them; fast=False: the generic reference path."""
    upper, lower = checked_limits(mech, output, adjust, upper, lower)
    spec = Spec(output, upper, lower)
    if not (isinstance(target, (int, float)) and 0 < target < 1):
        raise ParameterError("target", "must be a yield strictly between 0 and 1", target)
    if confidence is not None and not (0 < confidence < 1):
        raise ParameterError("confidence", "must be strictly between 0 and 1 (or None)",
                             confidence)
    if int(n) != n or n < 10:
        raise ParameterError("n", "must be a whole number of machines >= 10", n)
    if int(seed) != seed or seed < 0:
        raise ParameterError("seed", "must be a whole number >= 0", seed)
    if not (np.isfinite(widen) and widen >= 1):
        raise ParameterError("widen", "must be a finite number >= 1", widen)
    if not (np.isfinite(narrow) and 0 < narrow <= 1):
        raise ParameterError("narrow", "must be a number in (0, 1]", narrow)
    for name, v, least in (("restarts", restarts, 1), ("popsize", popsize, 2),
                           ("maxiter", maxiter, 1), ("sweeps", sweeps, 0)):
        if int(v) != v or v < least:
            raise ParameterError(name, f"must be a whole number >= {least}", v)
    tol = checked(mech, tolerances).active()
    refuse_relations(tol)
    for t in tol.items:
        if t.shift:
            raise ParameterError(f"{tol.name}.{t.param}.shift", "least-cost allocation places "
                                 "each zone itself (its centre is free); give the reference "
                                 "without a shift", t.shift)
    if not tol.items:
        raise ParameterError("tolerances", "must tolerance at least one parameter", tol.name)
    models = costs_of(tol, costs)
    need_fail = allowed_failures(int(n), float(target), confidence)
    if need_fail < 0:
        raise ParameterError("n", f"is too small to show a yield of {target:g} with "
                             f"confidence {confidence:g} even with no failure", n)
    need_ok = int(n) - need_fail
    u = draw_units(unit_streams(seed, n), len(tol.items), 0, n)
    zy = ZoneYield(mech, tol, output, spec, u, adjust, fast, options)

    ref_half = 0.5 * np.array([t.upper - t.lower for t in tol.items], float)
    cap = max_half if isinstance(max_half, dict) else {p: max_half for p in tol.params}
    bad = sorted(set(cap) - set(tol.params))
    if bad:
        raise ParameterError("max_half", f"must name toleranced parameters ({', '.join(tol.params)})",
                             bad)
    for p, v in cap.items():
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ParameterError(f"max_half.{p}", "must be a positive half-width", v)
    max_half = np.array([min(widen * h, cap.get(p) or np.inf)
                         for p, h in zip(tol.params, ref_half, strict=True)])
    d = len(models)
    cost_max = total_cost(models, narrow * ref_half)

    # the comparison: the shape at its largest common scale (also the search's seed point)
    shape_set = tol if shape is None else checked(mech, shape).active()
    if shape_set.params != tol.params:
        raise ParameterError("shape", f"must tolerance the same parameters ({', '.join(tol.params)})",
                             shape_set.params)
    k, c_lo, c_hi = common_scale(zy, [t.lower for t in shape_set.items],
                                 [t.upper for t in shape_set.items], max_half, need_ok)
    if k == 0.0:
        raise ParameterError("target", f"is out of reach: no common scale of set "
                             f"'{shape_set.name}' down to 1e-6 keeps it on {n} machines", target)

    def decode(x):
        half = ref_half * np.exp(x[:d])
        r = x[d:]
        return half * (r - 1.0), half * (r + 1.0), half

    def encode(lo, hi):
        half = 0.5 * (hi - lo)
        r = np.divide(0.5 * (hi + lo), half, out=np.zeros(d), where=half > 0)
        return np.concatenate([np.log(np.clip(half / ref_half, narrow, max_half / ref_half)),
                               np.clip(r, -1.0, 1.0)])

    def objective(x):
        lo, hi, half = decode(x)
        c = zy.counts(lo, hi)
        if c is None:
            return cost_max + 2.0 * n
        if c[0] < need_ok:
            return cost_max + (need_ok - c[0])
        return total_cost(models, half)

    bounds = [(np.log(narrow), float(np.log(m / h))) for m, h in zip(max_half, ref_half,
                                                                      strict=True)] \
        + [(-1.0, 1.0)] * d
    x_common = encode(c_lo, c_hi)
    rows, best = [], None
    for j, child in enumerate(np.random.SeedSequence(int(seed)).spawn(int(restarts))):
        rng = np.random.default_rng(child)
        pop = int(popsize) * 2 * d
        init = rng.uniform([b[0] for b in bounds], [b[1] for b in bounds], (pop, 2 * d))
        if j == 0:  # the first restart starts from today's allocation; the others do not
            init[0] = x_common
        calls = zy.calls
        res = optimize.differential_evolution(objective, bounds, init=init, maxiter=int(maxiter),
                                              seed=rng, polish=False, tol=1e-6,
                                              updating="deferred")
        lo, hi, _ = decode(res.x)
        found = objective(res.x)
        feasible = found <= cost_max
        if feasible:
            lo, hi = polish(zy, lo, hi, max_half, need_ok, int(sweeps), scan=centre_scan)
            cost = total_cost(models, 0.5 * (hi - lo))
        else:  # the search found no zone that keeps the target: reported, never polished
            cost = np.nan
        rows.append({"restart": j, "feasible": bool(feasible),
                     "cost_search": float(found) if feasible else np.nan, "cost": cost,
                     "generations": int(res.nit), "evaluations": zy.calls - calls,
                     **{f"{p}_lower": float(a) for p, a in zip(tol.params, lo, strict=True)},
                     **{f"{p}_upper": float(b) for p, b in zip(tol.params, hi, strict=True)}})
        if feasible and (best is None or cost < best[0]):
            best = (cost, lo, hi)
    if best is None:
        raise ParameterError("maxiter", f"gives no restart a zone that keeps the target on {n} "
                             "machines; search longer (maxiter, popsize)", maxiter)
    cost, lo, hi = best
    costs_found = [r["cost"] for r in rows if r["feasible"]]
    ok, out, cannot = zy.counts(lo, hi)
    sides = limited_by(zy, lo, hi, max_half, need_ok)
    half = 0.5 * (hi - lo)
    table = pd.DataFrame([{
        "param": t.param, "unit": next(p.unit for p in mech.parameters if p.name == t.param),
        "dist": t.dist, "model": m.model, "cost_model": m.formula(),
        "reference_lower": t.lower, "reference_upper": t.upper,
        "lower": float(lo[i]), "upper": float(hi[i]), "half_width": float(half[i]),
        "centre": float(0.5 * (lo[i] + hi[i])), "cost": float(m.cost(half[i])),
        "common_lower": float(c_lo[i]), "common_upper": float(c_hi[i]),
        "common_cost": float(m.cost(0.5 * (c_hi[i] - c_lo[i]))),
        "lower_limited_by": sides[i][0], "upper_limited_by": sides[i][1]}
        for i, (t, m) in enumerate(zip(tol.items, models, strict=True))])
    c_ok = zy.counts(c_lo, c_hi)[0]
    check_n = 10 * int(n) if check_n is None else int(check_n)
    check_seed = int(seed) + 1 if check_seed is None else int(check_seed)
    checks = {}
    if check_n:
        fresh = draw_units(unit_streams(check_seed, check_n), d, 0, check_n)
        zf = ZoneYield(mech, tol, output, spec, fresh, adjust, fast, options)
        for key, (a, b) in (("least_cost", (lo, hi)), ("common", (c_lo, c_hi))):
            f_ok, f_out, f_cannot = zf.counts(a, b)
            ci = clopper_pearson(f_ok, check_n)
            checks[key] = FreshCheck(check_n, check_seed, f_ok, f_out, f_cannot,
                                     f_ok / check_n, *ci, float(target))
    compare = pd.DataFrame([
        {"allocation": "least cost", "cost": cost, "n": int(n), "failures": int(n) - ok,
         "yield": ok / n, "scale": np.nan,
         **_fresh_cols(checks.get("least_cost"))},
        {"allocation": shape_name, "cost": total_cost(models, 0.5 * (c_hi - c_lo)),
         "n": int(n), "failures": int(n) - c_ok, "yield": c_ok / n, "scale": k,
         **_fresh_cols(checks.get("common"))}])
    adjust_name = None if adjust is None else adjust if isinstance(adjust, str) else \
        ",".join(getattr(a, "name", str(a)) for a in adjust)
    return LeastCost(mech.name, output, upper, lower, tolerances.name, float(target),
                     confidence, int(n), int(seed), need_fail, int(n) - ok, float(cost), table,
                     pd.DataFrame(rows), compare, checks.get("least_cost"), adjust_name,
                     float((max(costs_found) - min(costs_found)) / min(costs_found)),
                     tol.dependence, zy.calls)


def _fresh_cols(check: FreshCheck | None) -> dict:
    if check is None:
        return {"fresh_n": 0, "fresh_seed": None, "fresh_yield": np.nan,
                "fresh_ci95_low": np.nan, "fresh_ci95_high": np.nan, "fresh_meets": None}
    return {"fresh_n": check.n, "fresh_seed": check.seed, "fresh_yield": check.yield_,
            "fresh_ci95_low": check.ci_low, "fresh_ci95_high": check.ci_high,
            "fresh_meets": check.meets}
