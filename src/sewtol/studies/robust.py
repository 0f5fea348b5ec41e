"""Robust design: maximise over the nominal design (inside `bounds`) the yield of a tolerance set
under an adjustment strategy, on common random numbers (the same n machines' deviations laid
on every design), the nominal held by `constraints` and, for an epsilon-constraint sweep, by
`nominal_limit`. Differential evolution from restarts spawned from one seed, a tie-break below
one machine's worth across the yield's plateaus, and the archive of every design evaluated,
whose non-dominated designs approximate the Pareto front. See docs/refine.md, "Robust design".
Nothing here names a mechanism.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.studies.refine import PENALTY, Constraint, DesignProblem, bound_row


@dataclass(frozen=True)
class RobustResult:
    """The most robust design found and the designs evaluated on the way (module docstring).

    `best`: every value of the design (today's values elsewhere); `figures`: yield, nominal
    objective and kept output of today's and the best design on the search's machines;
    `restarts`: a row per restart; `archive`: every feasible design evaluated (parameters,
    `yield`, `nominal`, `error`); `front`: its non-dominated rows (nominal low, yield high,
    error small)."""

    mechanism: str
    objective: str
    limit: float
    tolerances: str
    adjust: tuple[str, ...]
    n: int
    seed: int
    bounds: dict[str, tuple[float, float]]
    constraints: tuple[Constraint, ...]
    nominal_limit: float | None
    start: dict[str, float]
    best: dict[str, float]
    figures: pd.DataFrame
    restarts: pd.DataFrame
    archive: pd.DataFrame
    front: pd.DataFrame
    seconds: float
    options: dict = field(default_factory=dict)

    @property
    def spread(self) -> float:
        """Largest minus smallest yield over the restarts."""
        r = self.restarts["yield"]
        return float(r.max() - r.min())

    def to_dataframe(self) -> pd.DataFrame:
        """The design's parameters: today, best, change, box, at a bound."""
        held = self.options.get("hold")
        boxes = {**self.bounds, **({held[2]: tuple(held[3])} if held else {})}
        return pd.DataFrame([bound_row(k, self.start[k], self.best[k], box, "robust")
                             for k, box in boxes.items()])

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "objective": self.objective, "limit": self.limit,
                "tolerances": self.tolerances, "adjust": list(self.adjust), "n": self.n,
                "seed": self.seed, "bounds": {k: list(v) for k, v in self.bounds.items()},
                "constraints": [c.text() for c in self.constraints],
                "nominal_limit": self.nominal_limit,
                "parameters": {k: v for k, v in self.best.items() if v != self.start.get(k)},
                "figures": self.figures.to_dict("records"),
                "restarts": self.restarts.to_dict("records"), "spread": self.spread,
                "front": self.front.to_dict("records"), "seconds": self.seconds,
                "options": self.options}

    def plot(self, ax=None, label: str | None = None):
        """The front: yield against the nominal objective, coloured by the kept output's
        error; returns the axes."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(6, 4))
        f = self.front
        sc = ax.scatter(f["nominal"], 100 * f["yield"], c=f["error"], s=14, cmap="viridis",
                        label=label)
        ax.set_xlabel(f"nominal {self.objective}")
        ax.set_ylabel(f"yield (%), {self.tolerances}, adjust {'+'.join(self.adjust)}")
        ax.figure.colorbar(sc, ax=ax, label="error of the kept output")
        return ax


def _nondominated(obj: np.ndarray) -> np.ndarray:
    """Mask of the rows of obj (minimised columns) that no other row dominates."""
    return np.array([not np.any(np.all(obj <= o, axis=1) & np.any(obj < o, axis=1))
                     for o in obj], bool)


def front_of(archive: pd.DataFrame) -> pd.DataFrame:
    """The non-dominated feasible designs of an archive (nominal and error low, yield high),
    one row per distinct (nominal, yield, error)."""
    a = archive.drop_duplicates(subset=["nominal", "yield", "error"])
    obj = np.column_stack([a["nominal"], -a["yield"], np.abs(a["error"])])
    return a[_nondominated(obj)].sort_values("nominal").reset_index(drop=True)


class _Yield:
    """Penalised -yield of designs (DE's vectorised call), with an archive."""

    def __init__(self, mech, objective, bounds, tolerances, adjust, nominal_adjust, limit,
                 constraints, nominal_limit, deviations, error_of, fast, hold=None):
        self.mech = mech
        self.objective = objective
        self.names = list(bounds)
        self.adjust = list(adjust)
        self.limit = float(limit)
        self.nominal = DesignProblem(mech, objective, bounds, nominal_adjust, (), fast)
        self.constraints = list(constraints)
        self.nominal_limit = nominal_limit
        self.dev = deviations
        self.n = len(next(iter(deviations.values())))
        self.error_of = error_of
        self.fast = fast
        self.start = mech.nominal_values()
        self.rows: list[np.ndarray] = []
        self.hold = hold
        self.hold_names = [] if hold is None else [hold[2]]

    def held(self, values: dict) -> tuple[dict, np.ndarray]:
        """The designs with the held output brought to its target by its parameter (secant
        iterations from the parameter's own value, vectorised over designs), and where that
        converged inside the parameter's box."""
        if self.hold is None:
            return values, np.ones(len(next(iter(values.values()))), bool)
        output, target, p, (lo, hi) = self.hold
        m = len(next(iter(values.values())))
        x0 = np.asarray(values.get(p, np.full(m, self.start[p])), float)

        def g(x):
            ev = self.mech.evaluate({**values, p: x}, [output])
            return np.asarray(ev.outputs[output], float) - target

        x1 = x0 * (1 + 1e-3)
        g0, g1 = g(x0), g(x1)
        for _ in range(6):
            with np.errstate(divide="ignore", invalid="ignore"):
                x2 = x1 - g1 * (x1 - x0) / (g1 - g0)
            x2 = np.where(np.isfinite(x2), x2, x1)
            x0, g0, x1 = x1, g1, x2
            g1 = g(x1)
        ok = np.isfinite(g1) & (np.abs(g1) <= 1e-6 * max(abs(target), 1.0)) \
            & (x1 >= lo) & (x1 <= hi)
        return {**values, p: np.where(ok, x1, x0)}, ok

    def figures(self, X):
        """(yield, nominal objective, error, feasible, tie-break) of designs X (S, k)."""
        from sewtol.studies.adjusting import adjusted

        S = X.shape[0]
        values, held = self.held(self.nominal.values(X))
        y0, settings, ok0 = self.nominal.adjusted(values)
        full = {**values, **{k: np.where(np.isfinite(v), v, self.start[k])
                             for k, v in settings.items()}}
        outs = [c.output for c in self.constraints]
        viol = np.zeros(S)
        err = np.full(S, np.nan)
        if outs:
            ev = self.mech.evaluate(full, outs)
            runs = np.array([str(s) == "ok" for s in ev.status])
            viol = sum(c.violation(ev.outputs[c.output]) for c in self.constraints)
            viol = np.where(np.isfinite(viol) & runs, viol, 1e3)
            if self.error_of is not None:
                err = ev.outputs[self.error_of[0]] - self.error_of[1]
        if self.nominal_limit is not None:
            viol = viol + np.maximum(y0 - self.nominal_limit, 0.0) / max(self.nominal_limit, 1.0)
        viol = viol + np.where(held, 0.0, 1.0)
        feasible = ok0 & (viol == 0)
        # the machines: every design with the same n deviations (common random numbers)
        mach = {k: np.repeat(v, self.n) for k, v in values.items()}
        for k, d in self.dev.items():
            base = mach[k] if k in mach else np.full(S * self.n, self.start[k])
            mach[k] = base + np.tile(d, S)
        a = adjusted(self.mech, mach, self.adjust, self.objective, fast=self.fast)
        v = np.asarray(a.value, float).reshape(S, self.n)
        st = np.broadcast_to(np.asarray(a.status), (S * self.n,)).reshape(S, self.n)
        good = (st == "ok") & np.isfinite(v)
        passed = good & (v <= self.limit)
        yld = passed.mean(axis=1)
        # v / (v + limit) in [0, 1): grows with every machine's objective, never flat
        tie = np.where(good, v / (np.abs(v) + self.limit), 1.0).mean(axis=1)
        extra = [values[k] for k in self.hold_names]
        return yld, np.where(ok0, y0, np.nan), err, feasible, tie, viol, extra

    def __call__(self, X):
        X = np.asarray(X, float)
        single = X.ndim == 1
        Xs = X.reshape(len(self.names), -1).T
        yld, nom, err, feas, tie, viol, extra = self.figures(Xs)
        self.rows.append(np.column_stack([Xs, *extra, yld, nom, err, feas]))
        f = np.where(feas, -yld + 0.5 * tie / self.n, PENALTY + np.minimum(viol, 1e3))
        return float(f[0]) if single else f

    def archive(self) -> pd.DataFrame:
        a = pd.DataFrame(np.vstack(self.rows),
                         columns=[*self.names, *self.hold_names, "yield", "nominal", "error",
                                  "feasible"])
        return a[a["feasible"] > 0].drop(columns="feasible").reset_index(drop=True)


def robust(mech, bounds: Mapping[str, tuple[float, float]], tolerances, *,
           adjust: Sequence[str] = ("beta",), nominal_adjust: Sequence[str] | None = None,
           objective: str | None = None, limit: float | None = None,
           constraints: Sequence[Constraint] = (), nominal_limit: float | None = None,
           error_of: tuple[str, float] | None = None,
           hold: tuple[str, float, str, tuple[float, float]] | None = None,
           init_designs: Sequence[Mapping] = (), n: int = 200, seed: int = 0,
           restarts: int = 2, popsize: int = 5, maxiter: int = 30,
           fast: bool = True) -> RobustResult:
    """Maximise the yield over the nominal design (see the module docstring).

    Parameters
    ----------
    mech : mechanism
    bounds : mapping
        Design parameter -> (low, high), absolute.
    tolerances : ToleranceSet
        The machines' deviations (its law; common to every design).
    adjust : compensator names
        What the assembler sets per machine (e.g. ["beta"], ["beta", "guide_shift"]).
    nominal_adjust : compensator names or None
        What is set on the nominal design before its constraints are read (default: `adjust`).
    objective, limit
        The criterion: objective (default the first output) at most limit (default the
        file's spec of that output).
    constraints : refine.Constraint
        On the nominal design's outputs.
    nominal_limit : float or None
        The nominal design's adjusted objective at most this (an epsilon constraint).
    error_of : (output, reference) or None
        The archive's `error` column: that output of the nominal design minus reference.
    hold : (output, target, parameter, (low, high)) or None
        Hold an output of the nominal design at a target by solving for one parameter (not a
        design parameter; inside its box) on every design: a thin constraint such as a stroke
        within +-0.1 mm is then met by construction instead of by chance.
    init_designs : mappings
        Designs (parameter -> value; clipped to the box) put in every restart's first
        population beside today's, e.g. the straightness-refined ones.
    n, seed
        Machines per design and the seed of their deviations (the restarts' Generators are
        children of the same seed's Generator).
    restarts, popsize, maxiter
        Differential evolution.
    """
    from scipy.optimize import differential_evolution

    from sewtol.law import InputLaw

    t0 = time.perf_counter()
    objective = objective or mech.output_names[0]
    mech.output(objective)
    if limit is None:
        spec = next((s for s in getattr(mech, "specs", ()) if s.output == objective), None)
        if spec is None or spec.upper is None:
            raise ParameterError("limit", f"must be given ({objective} has no upper spec)", None)
        limit = float(spec.upper)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ParameterError("n", "must be an integer >= 1", n)
    for name, (lo, hi) in bounds.items():
        if not lo < hi:
            raise ParameterError(name, "box must have low < high", (lo, hi))
    names = list(bounds)
    dev = InputLaw.of(tolerances.active()).draw(int(n), seed)
    nominal_adjust = list(adjust) if nominal_adjust is None else list(nominal_adjust)
    if hold is not None and hold[2] in bounds:
        raise ParameterError("hold", "its parameter must not be a design parameter", hold[2])
    prob = _Yield(mech, objective, bounds, tolerances, adjust, nominal_adjust, limit,
                  constraints, nominal_limit, dev, error_of, fast, hold)
    lo = np.array([bounds[k][0] for k in names])
    hi = np.array([bounds[k][1] for k in names])
    start = {k: float(v) for k, v in mech.nominal_values().items()}
    x_today = np.array([start[k] for k in names])
    rows = []
    for i, rng in enumerate(np.random.default_rng(seed).spawn(restarts)):
        t = time.perf_counter()
        inside = bool(np.all((lo <= x_today) & (x_today <= hi)))
        # today's design rides in the first population where the box holds it
        init = "latinhypercube"
        if inside:
            pop = lo + rng.random((popsize * len(names), len(names))) * (hi - lo)
            pop[0] = x_today
            for j, dsg in enumerate(init_designs, start=1):
                pop[j] = np.clip([float(dsg.get(k, start[k])) for k in names], lo, hi)
            init = pop
        r = differential_evolution(prob, list(zip(lo, hi, strict=True)), rng=rng,
                                   popsize=popsize, maxiter=maxiter, tol=1e-8, polish=False,
                                   init=init, vectorized=True, updating="deferred",
                                   mutation=(0.5, 1.0), recombination=0.9)
        yld, nom, err, feas, _, _, extra = prob.figures(np.atleast_2d(r.x))
        rows.append({"restart": i, "yield": float(yld[0]), "nominal": float(nom[0]),
                     "error": float(err[0]), "feasible": bool(feas[0]),
                     **dict(zip(names, map(float, r.x), strict=True)),
                     **{k: float(e[0]) for k, e in zip(prob.hold_names, extra, strict=True)},
                     "generations": int(r.nit), "seconds": time.perf_counter() - t})
    table = pd.DataFrame(rows)
    ok = table[table["feasible"]]
    pick = (ok if len(ok) else table)["yield"].idxmax()
    best = {**start, **{k: float(table.loc[pick, k]) for k in names + prob.hold_names}}
    fig = []
    for label, x in (("today", x_today), ("robust", np.array([best[k] for k in names]))):
        yld, nom, err, feas, _, _, _ = prob.figures(x[None, :])
        fig.append({"design": label, "yield": float(yld[0]), "nominal": float(nom[0]),
                    "error": float(err[0]), "feasible": bool(feas[0])})
    archive = prob.archive()
    return RobustResult(
        mechanism=mech.name, objective=objective, limit=float(limit),
        tolerances=getattr(tolerances, "name", ""), adjust=tuple(adjust), n=int(n),
        seed=int(seed), bounds={k: tuple(map(float, v)) for k, v in bounds.items()},
        constraints=tuple(constraints), nominal_limit=nominal_limit, start=start, best=best,
        figures=pd.DataFrame(fig), restarts=table, archive=archive, front=front_of(archive),
        seconds=time.perf_counter() - t0,
        options={"restarts": restarts, "popsize": popsize, "maxiter": maxiter,
                 "nominal_adjust": nominal_adjust, "error_of": error_of, "hold": hold})


def yield_check(mech, design: Mapping, tolerances, adjust: Sequence[str], objective: str,
                limit: float, n: int, seed: int, fast: bool = True) -> dict:
    """The yield of one design on n machines drawn afresh (seed), with its 95 % Wilson
    interval and the counts (ok + out_of_spec + failed = n): the check of a search's yield
    with machines it never saw."""
    from sewtol.law import InputLaw
    from sewtol.studies.adjusting import adjusted

    dev = InputLaw.of(tolerances.active()).draw(int(n), seed)
    vals = {k: np.full(int(n), float(v)) for k, v in design.items()}
    for k, d in dev.items():
        vals[k] = vals[k] + d
    a = adjusted(mech, vals, list(adjust), objective, fast=fast)
    v = np.asarray(a.value, float)
    good = (np.broadcast_to(np.asarray(a.status), v.shape) == "ok") & np.isfinite(v)
    ok = int(np.sum(good & (v <= limit)))
    failed = int(np.sum(~good))
    z = 1.959963984540054
    p = ok / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return {"n": int(n), "seed": int(seed), "ok": ok, "out_of_spec": int(n) - ok - failed,
            "failed": failed, "yield": p, "yield_ci_low": max(0.0, centre - half),
            "yield_ci_high": min(1.0, centre + half)}
