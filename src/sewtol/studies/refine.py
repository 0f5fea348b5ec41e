"""Nominal refinement: minimise one output of the adjusted nominal design over chosen
parameters inside boxes, under constraints on other outputs (`Constraint`; by default every
transmission output >= 40 deg). Differential evolution from restarts spawned from one seed,
infeasible designs scored PENALTY plus their scaled violation, a Nelder-Mead or minimax
polish, a local search from today's design for contrast, and the degree of influence (after
Polukhin) at the optimum: the methods, defaults and checks are in docs/refine.md. Nothing here
names a mechanism.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.protocol import Mechanism
from sewtol.tolerances import ToleranceSet

PENALTY = 1e6
LINK_FRACTION = 0.10  # default box of a length: +-10 % of its nominal
FRAME_MM = 2.0  # default box of a frame coordinate: +-2 mm
ANGLE_DEG = 0.5  # default box of an angle: +-0.5 deg
MIN_TRANSMISSION_DEG = 40.0


@dataclass(frozen=True)
class Constraint:
    """An output of the adjusted design held within [lower, upper] (None: open), in the
    output's unit; `scale` divides the violation (so constraints of different units add up)."""

    output: str
    lower: float | None = None
    upper: float | None = None
    scale: float = 1.0
    doc: str = ""

    def __post_init__(self):
        for name in ("lower", "upper"):
            v = getattr(self, name)
            if v is not None and not np.isfinite(v):
                raise ParameterError(f"{self.output}.{name}", "must be a finite number", v)
        if self.lower is None and self.upper is None:
            raise ParameterError(self.output, "a constraint needs a lower or an upper limit",
                                 None)
        if self.lower is not None and self.upper is not None and not self.lower <= self.upper:
            raise ParameterError(f"{self.output}.lower", f"must be <= upper {self.upper:g}",
                                 self.lower)
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ParameterError(f"{self.output}.scale", "must be a positive number", self.scale)

    def violation(self, y) -> np.ndarray:
        """How far each value lies outside the limits, divided by `scale` (0 inside; inf for
        NaN: a design that gives no value)."""
        y = np.asarray(y, float)
        v = np.zeros_like(y)
        if self.lower is not None:
            v = v + np.maximum(self.lower - y, 0.0)
        if self.upper is not None:
            v = v + np.maximum(y - self.upper, 0.0)
        return np.where(np.isnan(y), np.inf, v / self.scale)

    def active(self, y, rel: float = 1e-2) -> bool:
        """True where the value holds and lies on a limit (within rel * scale of it)."""
        y = float(y)
        return bool(self.violation(y) == 0 and any(
            lim is not None and abs(y - lim) <= rel * self.scale
            for lim in (self.lower, self.upper)))

    def text(self) -> str:
        if self.lower is not None and self.upper is not None:
            return f"{self.lower:.6g} <= {self.output} <= {self.upper:.6g}"
        if self.lower is not None:
            return f"{self.output} >= {self.lower:.6g}"
        return f"{self.output} <= {self.upper:.6g}"


def at_least(output: str, value: float, doc: str = "") -> Constraint:
    """`output` >= value."""
    return Constraint(output, lower=float(value), scale=max(1.0, abs(float(value))), doc=doc)


def at_most(output: str, value: float, doc: str = "") -> Constraint:
    """`output` <= value."""
    return Constraint(output, upper=float(value), scale=max(1.0, abs(float(value))), doc=doc)


def keep(mech, output: str, tol: float, adjust=None, objective: str | None = None,
         doc: str = "") -> Constraint:
    """`output` within +-tol of its value on today's design, adjusted as `refine` adjusts it
    (the compensators `adjust` minimising `objective`, default the first output)."""
    if not (np.isfinite(tol) and tol > 0):
        raise ParameterError(f"{output}.tol", "must be a positive number", tol)
    today = DesignProblem(mech, objective or mech.output_names[0], {}, adjust, (),
                     fast=True).outputs_at(mech.nominal_values(), [output])
    y0 = float(today[output])
    if not np.isfinite(y0):
        raise ParameterError(output, "today's design gives no value to keep", y0)
    return Constraint(output, y0 - tol, y0 + tol, float(tol),
                      doc or f"{output} within +-{tol:g} of today's {y0:.6g}")


def default_constraints(mech) -> list[Constraint]:
    """Every transmission output of the mechanism at least 40 deg (the dead-point margin)."""
    return [at_least(o.name, MIN_TRANSMISSION_DEG, "transmission angle >= 40 deg over the "
                     "whole turn (dead-point margin)")
            for o in mech.outputs if o.type == "transmission"]


def default_parameters(mech) -> list[str]:
    """The lengths (rule positive, unit mm) and the frame coordinates (mm parameters that place
    a fixed point) of a mechanism file: the links and the pivots."""
    placing = set()
    for g in getattr(mech, "groups", ()):
        if g.type == "point":
            for k in ("x", "y"):
                placing.update(getattr(g.fields.get(k), "names", ()))
    return [p.name for p in mech.parameters
            if p.unit == "mm" and (p.rule == "positive" or p.name in placing)]


def default_bounds(mech, names: Sequence[str]) -> dict[str, tuple[float, float]]:
    """A box per parameter: a length (rule positive) +-10 % of its nominal, another mm
    parameter (a frame coordinate) +-2 mm, an angle +-0.5 deg; other units need a box."""
    nominal = mech.nominal_values()
    by_name = {p.name: p for p in mech.parameters}
    out = {}
    for n in names:
        if n not in by_name:
            raise ParameterError("parameters", "must name parameters of the mechanism ("
                                 + ", ".join(by_name) + ")", n)
        p, v = by_name[n], float(nominal[n])
        if p.rule == "branch":
            raise ParameterError(n, "a branch picks an assembly; it cannot be refined", v)
        if p.unit == "mm" and p.rule == "positive":
            out[n] = (v * (1 - LINK_FRACTION), v * (1 + LINK_FRACTION))
        elif p.unit == "mm":
            out[n] = (v - FRAME_MM, v + FRAME_MM)
        elif p.unit == "deg":
            out[n] = (v - ANGLE_DEG, v + ANGLE_DEG)
        else:
            raise ParameterError(n, f"has no default box (unit {p.unit}); give its bounds", v)
    return out


class DesignProblem:
    """The penalised objective over designs x (parameters in `names` order)."""

    def __init__(self, mech, objective, bounds, adjust, constraints, fast):
        self.mech = mech
        self.objective = objective
        mech.output(objective)
        self.names = list(bounds)
        self.bounds = dict(bounds)
        self.adjust = list(mech.compensators) if adjust is None else adjust
        self.constraints = list(constraints)
        for c in self.constraints:
            mech.output(c.output)
        self.fast = fast
        self.nfev = 0

    def values(self, X) -> dict[str, np.ndarray]:
        X = np.atleast_2d(np.asarray(X, float))
        return {n: X[:, i] for i, n in enumerate(self.names)}

    def adjusted(self, values: dict):
        """(value, settings, ok) of designs `values` after the adjustment."""
        from sewtol.studies.adjusting import adjusted, evaluated

        m = max([np.size(v) for v in values.values()] + [1])
        if not self.adjust:
            y = np.broadcast_to(evaluated(self.mech, values, self.objective, fast=self.fast),
                                (m,))
            return np.asarray(y, float), {}, np.isfinite(y)
        a = adjusted(self.mech, values, self.adjust, self.objective, fast=self.fast)
        y = np.asarray(a.value, float)
        ok = np.isfinite(y) & np.array([str(s) == "ok" for s in np.broadcast_to(a.status, (m,))])
        return y, {k: np.asarray(v, float) for k, v in a.settings.items()}, ok

    def outputs_at(self, values: dict, outputs) -> dict:
        """The objective and `outputs` of one design (scalars), at its adjusted settings."""
        y, settings, ok = self.adjusted({k: np.atleast_1d(v) for k, v in values.items()})
        full = {**{k: np.atleast_1d(np.asarray(v, float)) for k, v in values.items()},
                **{k: np.where(np.isfinite(v), v, np.asarray(values.get(k, np.nan), float))
                   for k, v in settings.items()}}
        ev = self.mech.evaluate(full, list(outputs)) if outputs else None
        out = {self.objective: float(y[0]) if ok[0] else float("nan")}
        for o in outputs or ():
            out[o] = float(ev.outputs[o][0])
        out["_settings"] = {k: float(v[0]) for k, v in settings.items()}
        return out

    def __call__(self, X) -> np.ndarray:
        """Penalised objective of designs X: shape (k,) or (k, S) as scipy passes them."""
        X = np.asarray(X, float)
        single = X.ndim == 1
        Xs = X.reshape(len(self.names), -1).T  # (S, k)
        self.nfev += Xs.shape[0]
        y, settings, ok = self.adjusted(self.values(Xs))
        f = np.where(ok, y, PENALTY * 2)
        if self.constraints:
            full = self.values(Xs)
            # designs the adjuster could not set are evaluated at their own values (and count
            # as infeasible anyway)
            full.update({k: np.where(ok & np.isfinite(v), v, full.get(
                k, np.full(len(y), self.mech.nominal_values()[k]))) for k, v in settings.items()})
            ev = self.mech.evaluate(full, [c.output for c in self.constraints])
            runs = np.array([str(s) == "ok" for s in ev.status])
            viol = sum(c.violation(ev.outputs[c.output]) for c in self.constraints)
            viol = np.where(np.isfinite(viol), viol, 1e3)
            f = np.where(ok & runs & (viol == 0), y, np.where(ok & runs, PENALTY + viol,
                                                                 PENALTY * 2))
        f = np.where(np.isfinite(f), f, PENALTY * 2)
        return float(f[0]) if single else f


@dataclass(frozen=True)
class RefineResult:
    """A refined design and how it was found (see the module docstring).

    `start`, `refined`: every value of today's and the refined design (the adjusted
    compensators included); `before`, `after`: the objective and each constrained output at
    them; `parameters`: a row per refined parameter (today, refined, change, box, at a bound);
    `restarts`: a row per restart (seed, objective, parameters, evaluations, seconds);
    `influence`: the degree of influence at the optimum; `curve_before`, `curve_after`: the
    objective's per-angle curve (a line_deviation output), None for other outputs."""

    mechanism: str
    objective: str
    unit: str
    adjust: tuple[str, ...]
    bounds: dict[str, tuple[float, float]]
    constraints: tuple[Constraint, ...]
    start: dict[str, float]
    refined: dict[str, float]
    before: dict[str, float]
    after: dict[str, float]
    parameters: pd.DataFrame
    restarts: pd.DataFrame
    polished_gain: float
    local_from_start: float
    influence: pd.DataFrame
    curve_before: pd.DataFrame | None
    curve_after: pd.DataFrame | None
    seed: int
    seconds: float
    options: dict = field(default_factory=dict)
    polished: pd.DataFrame | None = None

    @property
    def polished_spread(self) -> float:
        """Largest minus smallest objective over the polished starts (NaN without them)."""
        if self.polished is None:
            return float("nan")
        r = self.polished["objective"]
        return float(r.max() - r.min())

    @property
    def objective_before(self) -> float:
        return self.before[self.objective]

    @property
    def objective_after(self) -> float:
        return self.after[self.objective]

    @property
    def ratio(self) -> float:
        """today's objective / the refined one."""
        return self.objective_before / self.objective_after

    @property
    def spread(self) -> float:
        """Largest minus smallest objective over the restarts (before the polish)."""
        r = self.restarts["objective"]
        return float(r.max() - r.min())

    @property
    def active_bounds(self) -> list[str]:
        p = self.parameters
        return [f"{r.parameter} ({r.at_bound})" for r in p.itertuples() if r.at_bound]

    @property
    def changed(self) -> dict[str, float]:
        """Every value that differs from today's (parameters and compensator settings)."""
        return {k: v for k, v in self.refined.items() if v != self.start.get(k)}

    def confirmation(self) -> list[str]:
        """How the optimum was confirmed, in words."""
        r = self.restarts
        u = self.unit
        wide = {n: float(r[n].max() - r[n].min()) for n in self.bounds}
        widest = max(wide, key=wide.get) if wide else ""
        return [
            f"{len(r)} differential-evolution restarts (seeds spawned from {self.seed}) reached "
            f"{self.objective} = {r['objective'].min():.4f} ... {r['objective'].max():.4f} {u} "
            f"(spread {self.spread:.4f} {u}); the widest parameter spread is {widest} "
            f"{wide.get(widest, 0.0):.4g}",
            (f"Nelder-Mead polish of the best restart gained {self.polished_gain:.4f} {u}"
             if self.polished is None else
             f"minimax (SLSQP, epigraph) polish of each of {len(self.polished)} starts "
             f"(every restart's best" + (", today's design" if "today" in
                                         list(self.polished["start"]) else "")
             + f") reached {self.polished['objective'].min():.4f} ... "
             f"{self.polished['objective'].max():.4f} {u} (spread {self.polished_spread:.4f} "
             f"{u}); it gained {self.polished_gain:.4f} {u} on the best restart"),
            f"Nelder-Mead from today's design alone stops at {self.local_from_start:.4f} {u} "
            f"(a local optimum; the global search reaches {self.objective_after:.4f} {u})",
            "parameters on a bound of their box: " + (", ".join(self.active_bounds) or "none"),
            "constraints met on a limit: " + (", ".join(self.active_constraints) or "none"),
        ]

    def to_dataframe(self) -> pd.DataFrame:
        """The refined parameters: today, refined, change, box, at a bound."""
        return self.parameters

    def outputs_frame(self) -> pd.DataFrame:
        """The objective and the constrained outputs, today and refined, with the limits."""
        rows = [{"output": self.objective, "today": self.before[self.objective],
                 "refined": self.after[self.objective], "lower": np.nan, "upper": np.nan,
                 "holds": True, "active": False}]
        for c in self.constraints:
            y = self.after[c.output]
            rows.append({"output": c.output, "today": self.before[c.output], "refined": y,
                         "lower": np.nan if c.lower is None else c.lower,
                         "upper": np.nan if c.upper is None else c.upper,
                         "holds": bool(c.violation(y) == 0), "active": c.active(y)})
        return pd.DataFrame(rows)

    @property
    def active_constraints(self) -> list[str]:
        """The constraints the refined design meets on a limit (what holds it back)."""
        return [c.text() for c in self.constraints if c.active(self.after[c.output])]

    def curves(self) -> pd.DataFrame | None:
        if self.curve_before is None:
            return None
        return pd.DataFrame({"q_deg": self.curve_before["q_deg"],
                             f"{self.objective}_today": self.curve_before["value"],
                             f"{self.objective}_refined": self.curve_after["value"]})

    def to_dict(self) -> dict:
        """Plain data (the JSON of ``sewtol run FILE refine``)."""
        outs = [self.objective] + [c.output for c in self.constraints]
        return {
            "mechanism": self.mechanism, "objective": self.objective, "unit": self.unit,
            "adjust": list(self.adjust),
            "parameters": {k: float(v) for k, v in self.changed.items()},
            "today": {o: self.before[o] for o in outs},
            "refined": {o: self.after[o] for o in outs},
            "ratio": self.ratio,
            "bounds": {k: list(v) for k, v in self.bounds.items()},
            "constraints": [{"output": c.output, "lower": c.lower, "upper": c.upper,
                             "doc": c.doc} for c in self.constraints],
            "active_bounds": self.active_bounds,
            "active_constraints": self.active_constraints,
            "restarts": self.restarts.to_dict("records"),
            "spread": self.spread, "polished_gain": self.polished_gain,
            "polished": None if self.polished is None else self.polished.to_dict("records"),
            "polished_spread": self.polished_spread,
            "local_from_start": self.local_from_start,
            "confirmation": self.confirmation(),
            "influence": self.influence.to_dict("records"),
            "rows": self.parameters.to_dict("records"),
            "seed": self.seed, "seconds": self.seconds, "options": self.options,
        }

    def plot(self, ax=None):
        """The objective's curve over the driving angle, today and refined (a line_deviation
        objective: the needle's d(phi)); returns the axes."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(7, 3.5))
        if self.curve_before is None:
            raise ParameterError("objective", "must be a line_deviation output to plot a curve",
                                 self.objective)
        for cur, label in ((self.curve_before, "today"), (self.curve_after, "refined")):
            v = cur["value"]
            ax.plot(cur["q_deg"], v, label=f"{label}: {np.nanmax(v) - np.nanmin(v):.2f} "
                    f"{self.unit} peak to peak")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel("driving angle (deg)")
        ax.set_ylabel(f"deviation ({self.unit})")
        ax.set_xlim(0, 360)
        ax.legend(loc="best", fontsize=8)
        ax.set_title(f"{self.mechanism}: {self.objective} {self.objective_before:.2f} -> "
                     f"{self.objective_after:.2f} {self.unit}", fontsize=9)
        return ax


def influence(mech, design: dict, names: Sequence[str], objective: str, adjust=None,
              tolerances=None, fast: bool = True, bounds: Mapping | None = None) -> pd.DataFrame:
    """Degree of influence of each parameter on the adjusted objective at `design` (see the
    module docstring): slope (central difference at dp/10), slope * dp, and the objective's
    change at p + dp and p - dp; constraints are not applied."""
    prob = DesignProblem(mech, objective, {n: (0.0, 0.0) for n in names}, adjust, (), fast)
    steps = {n: _tol_step(mech, n, design[n], tolerances, bounds) for n in names}
    offsets = [(n, frac) for n in names for frac in (0.1, -0.1, 1.0, -1.0)]
    cols = {n: [float(design[n]) + (frac * steps[m] if m == n else 0.0) for m, frac in offsets]
            for n in names}
    rows = []
    nominal = mech.nominal_values()
    # the design's other changed values ride along (compensators are re-adjusted anyway)
    others = {k: float(v) for k, v in design.items()
              if k not in names and k in nominal and v != nominal[k]}
    values = {**{k: np.full(4 * len(names), v) for k, v in others.items()},
              **{n: np.array(cols[n]) for n in names}}
    y, _, ok = prob.adjusted(values)
    y = np.where(ok, y, np.nan)
    y0, _, ok0 = prob.adjusted({**{k: np.array([v]) for k, v in others.items()},
                                **{n: np.array([float(design[n])]) for n in names}})
    j0 = float(y0[0]) if ok0[0] else float("nan")
    for i, n in enumerate(names):
        up_s, dn_s, up, dn = y[4 * i:4 * i + 4]
        dp = steps[n]
        slope = (up_s - dn_s) / (0.2 * dp)
        rows.append({"parameter": n, "value": float(design[n]), "step": dp,
                     "step_source": _step_source(mech, n, tolerances),
                     "slope_per_unit": slope, "influence": slope * dp,
                     "change_up": up - j0, "change_down": dn - j0})
    f = pd.DataFrame(rows)
    return f.assign(rank=f["influence"].abs().rank(ascending=False, method="min").astype(int))


def _tol_step(mech, name, value, tolerances, bounds) -> float:
    t = _tolerance_of(name, tolerances)
    if t is not None:
        return 0.5 * (t[1] - t[0])
    if _is_length(mech, name):
        return 0.01 * abs(float(value))
    lo, hi = (bounds or {}).get(name) or default_bounds(mech, [name])[name]
    return 0.01 * (hi - lo)


def _is_length(mech, name) -> bool:
    return any(p.name == name and p.rule == "positive" for p in mech.parameters)


def _tolerance_of(name, tolerances):
    items = () if tolerances is None else tolerances.active().items
    return next(((float(t.lower), float(t.upper)) for t in items if t.param == name), None)


def _step_source(mech, name, tolerances) -> str:
    if _tolerance_of(name, tolerances) is not None:
        return f"tolerance ({tolerances.name})"
    return "1 % of the value" if _is_length(mech, name) else "1 % of the box width"


def bound_row(name: str, today: float, value: float, box: tuple[float, float],
              label: str) -> dict:
    """A parameter's row of a design table: today, `label` (its value), change, box, and
    at_bound "low"/"high" within 1e-4 of the box's width of an end ("" inside)."""
    lo, hi = box
    eps = 1e-4 * (hi - lo)
    return {"parameter": name, "today": today, label: value, "change": value - today, "low": lo,
            "high": hi, "at_bound": "low" if value <= lo + eps else "high" if value >= hi - eps
            else ""}


def refine(mech: Mechanism, parameters: Sequence[str] | Mapping | None = None, *,
           objective: str | None = None, adjust: Sequence[str] | Mapping | None = None,
           constraints: Sequence[Constraint] | None = None, seed: int = 0,
           restarts: int = 3, popsize: int = 12, maxiter: int = 200, tol: float = 1e-7,
           polish: bool | str = True, polish_evaluations: int = 1500,
           local_search: bool = True, tolerances: ToleranceSet | None = None,
           fast: bool = True, starts: pd.DataFrame | None = None) -> RefineResult:
    """Minimise `objective` of the adjusted nominal design over `parameters` (see the module
    docstring).

    Parameters
    ----------
    mech : mechanism
        Any mechanism of the protocol (a mechanism file, sewtol.mechanism.load).
    parameters : sequence of str, mapping or None
        The parameters refined: names (default boxes, `default_bounds`) or name -> (low, high)
        absolute bounds; None: `default_parameters(mech)` (the links and the pivots).
    objective : str or None
        The output minimised (default the mechanism's first output).
    adjust : compensators or None
        What the assembler sets on the nominal design before the objective is read: names of
        the mechanism's compensators or parameter -> (low, high); None: every compensator of
        the mechanism; () or []: none.
    constraints : sequence of Constraint or None
        None: `default_constraints(mech)` (transmission >= 40 deg).
    seed : int
        The restarts' Generators are ``np.random.default_rng(seed).spawn(restarts)``.
    restarts, popsize, maxiter : int
        Differential evolution: restarts, population per parameter, generations.
    tol : float
        Differential evolution's relative convergence tolerance.
    polish : bool or str
        True or "nelder-mead": polish the best restart by Nelder-Mead; "minimax": polish
        every restart's best (and, with `local_search`, today's design) by `minimax_polish`
        (a line_deviation objective with measure sum_extremes), the refined design being the
        best polished one; `polished` then holds a row per start; False: no polish.
    polish_evaluations : int
        The most designs each Nelder-Mead (the polish, the local search) evaluates.
    local_search : bool
        Also run that Nelder-Mead from today's design alone (the contrast of a local search).
    tolerances : ToleranceSet or None
        The steps of the degree of influence (else 1 % of each value).
    fast : bool
        Use the mechanism's plug-ins (exact adjuster, kernel) where they apply.
    starts : DataFrame or None
        Restarts already run (an earlier result's `restarts` table, a column per refined
        parameter): the search is not repeated, these are polished (to re-polish a search).

    Returns
    -------
    RefineResult
        The refined design beside today's, the restarts, the confirmation, the degree of
        influence and the deviation curves.

    Raises
    ------
    ParameterError
        For an unknown parameter or output, a branch, a bad box or a bad search setting.
    """
    from scipy.optimize import differential_evolution, minimize

    from sewtol.studies.adjusting import boxes_of

    t0 = time.perf_counter()
    objective = objective or mech.output_names[0]
    mech.output(objective)
    if parameters is None:
        parameters = default_parameters(mech)
    if isinstance(parameters, Mapping):
        defaults = default_bounds(mech, [k for k, v in parameters.items() if v is None])
        bounds = {k: defaults[k] if v is None else _box(k, v) for k, v in parameters.items()}
        default_bounds(mech, list(bounds))  # names and branches checked
    else:
        bounds = default_bounds(mech, list(parameters))
    if not bounds:
        raise ParameterError("parameters", "must name at least one parameter", [])
    for name, (lo, hi) in bounds.items():
        if not lo < hi:
            raise ParameterError(name, "box must have low < high", (lo, hi))
    for k in ("restarts", "popsize", "maxiter"):
        v = locals()[k]
        if not (isinstance(v, (int, np.integer)) and v >= 1):
            raise ParameterError(k, "must be an integer >= 1", v)
    constraints = default_constraints(mech) if constraints is None else list(constraints)
    prob = DesignProblem(mech, objective, bounds, adjust, constraints, fast)
    names = prob.names
    nominal = mech.nominal_values()
    start = {k: float(v) for k, v in nominal.items()}
    x_today = np.array([nominal[n] for n in names], float)
    inside = all(bounds[n][0] <= nominal[n] <= bounds[n][1] for n in names)
    lo = np.array([bounds[n][0] for n in names])
    hi = np.array([bounds[n][1] for n in names])

    rows = []
    if starts is not None:
        missing = [n for n in names if n not in starts.columns]
        if missing:
            raise ParameterError("starts", "must hold a column per refined parameter", missing)
        rows = starts.to_dict("records")
    searched = 0 if starts is not None else restarts
    for child_seed, rng in zip(range(searched), np.random.default_rng(seed).spawn(searched),
                               strict=True):
        t = time.perf_counter()
        prob.nfev = 0
        res = differential_evolution(prob, list(zip(lo, hi, strict=True)), rng=rng,
                                     popsize=popsize, maxiter=maxiter, tol=tol, polish=False,
                                     init="latinhypercube", vectorized=True, updating="deferred",
                                     mutation=(0.5, 1.0), recombination=0.9)
        rows.append({"restart": child_seed, "objective": float(res.fun),
                     **{n: float(v) for n, v in zip(names, res.x, strict=True)},
                     "generations": int(res.nit), "evaluations": int(prob.nfev),
                     "seconds": time.perf_counter() - t, "converged": bool(res.success)})
    table = pd.DataFrame(rows)
    best = table.loc[table["objective"].idxmin()]
    x_best = np.array([best[n] for n in names], float)
    f_best = float(best["objective"])

    def scaled(z):
        return prob(lo + np.clip(z, 0.0, 1.0) * (hi - lo))

    nm_options = {"xatol": 1e-9, "fatol": 1e-7, "maxfev": polish_evaluations,
                  "adaptive": True}
    gain = 0.0
    t_polish = time.perf_counter()
    polished = None
    if polish not in (True, False, "nelder-mead", "minimax"):
        raise ParameterError("polish", "must be True, False, 'nelder-mead' or 'minimax'", polish)
    if polish == "minimax":
        boxes = boxes_of(mech, prob.adjust)
        starts = [(int(r_["restart"]), np.array([r_[n] for n in names], float))
                  for _, r_ in table.iterrows()]
        if inside and local_search:
            starts.append(("today", x_today))
        prow_ = []
        for label, x0 in starts:
            t = time.perf_counter()
            x, f = _minimax_rounds(prob, mech, objective, start, names, x0, bounds, boxes,
                                   constraints)
            prow_.append({"start": label, "objective": f,
                          **{n: float(v) for n, v in zip(names, x, strict=True)},
                          "seconds": time.perf_counter() - t})
        polished = pd.DataFrame(prow_)
        k = int(polished["objective"].idxmin())
        if polished.loc[k, "objective"] < f_best:
            gain = f_best - float(polished.loc[k, "objective"])
            x_best = np.array([polished.loc[k, n] for n in names], float)
    elif polish:
        r = minimize(scaled, (x_best - lo) / (hi - lo), method="Nelder-Mead",
                     bounds=[(0.0, 1.0)] * len(names), options=nm_options)
        if r.fun < f_best:
            gain = f_best - float(r.fun)
            x_best = lo + np.clip(r.x, 0, 1) * (hi - lo)
    t_local = time.perf_counter()
    local = float("nan")
    if inside and local_search:
        r = minimize(scaled, (x_today - lo) / (hi - lo), method="Nelder-Mead",
                     bounds=[(0.0, 1.0)] * len(names), options=nm_options)
        local = float(r.fun)
    t_end = time.perf_counter()

    outs = [c.output for c in constraints]
    refined_vals = {**start, **{n: float(v) for n, v in zip(names, x_best, strict=True)}}
    after = prob.outputs_at(refined_vals, outs)
    before = prob.outputs_at(start, outs)
    refined = {**refined_vals, **after.pop("_settings")}
    today = {**start, **before.pop("_settings")}
    units = {p.name: p.unit for p in mech.parameters}
    prow = [{"parameter": n, "unit": units[n],
             **bound_row(n, start[n], refined[n], bounds[n], "refined")} for n in names]
    for k in sorted(set(refined) - set(names)):
        if refined[k] != start[k]:  # the compensators' settings
            prow.append({"parameter": k, "unit": units[k], "today": today.get(k, start[k]),
                         "refined": refined[k], "change": refined[k] - today.get(k, start[k]),
                         "low": np.nan, "high": np.nan, "at_bound": ""})
    infl = influence(mech, refined, names, objective, prob.adjust, tolerances, fast, bounds)
    cb = ca = None
    if mech.output(objective).type == "line_deviation" and hasattr(mech, "curve"):
        q = mech.angles_rad()
        cb, ca = (pd.DataFrame({"q_deg": np.degrees(q), "value": mech.curve(
            objective, {k: np.array([v]) for k, v in design.items()}, q)[0]})
            for design in (today, refined))
    return RefineResult(
        mechanism=mech.name, objective=objective, unit=mech.output(objective).unit,
        adjust=tuple(prob.adjust) if not isinstance(prob.adjust, Mapping)
        else tuple(prob.adjust), bounds=bounds, constraints=tuple(constraints), start=today,
        refined=refined, before=before, after=after, parameters=pd.DataFrame(prow),
        restarts=table, polished_gain=gain, local_from_start=local, influence=infl,
        curve_before=cb, curve_after=ca, seed=int(seed), seconds=time.perf_counter() - t0,
        polished=polished,
        options={"adjust_boxes": boxes_of(mech, prob.adjust), "restarts": restarts,
                 "popsize": popsize, "maxiter": maxiter, "tol": tol,
                 "polish": polish, "polish_evaluations": polish_evaluations,
                 "local_search": local_search, "penalty": PENALTY,
                 "seconds_search": t_polish - t0, "seconds_polish": t_local - t_polish,
                 "seconds_local_search": t_end - t_local})


def _minimax_rounds(prob, mech, objective, start, names, x0, bounds, boxes, constraints,
                    rounds: int = 4, gain_tol: float = 1e-5):
    """minimax_polish from x0, repeated from its own result while it gains more than
    gain_tol; each result is re-read exactly (prob: the compensators re-adjusted, constraints
    applied). Returns (x, penalised objective) of the best."""
    x_best = np.asarray(x0, float)
    f_best = float(prob(x_best))
    # the compensators start at their adjusted settings
    _, settings, _ = prob.adjusted(prob.values(x_best[None, :]))
    design = {**start, **dict(zip(names, x_best, strict=True)),
              **{k: float(v[0]) for k, v in settings.items() if np.isfinite(v[0])}}
    for _ in range(rounds):
        for margin in (1e-3, 1e-2):  # a wider margin where the exact re-reading fails one
            vals, _, _ = minimax_polish(mech, objective, design, bounds, boxes, constraints,
                                        margin=margin)
            x = np.array([vals[n] for n in names], float)
            f = float(prob(x))
            if f < PENALTY:
                break
        if not f < f_best - gain_tol:
            if f < f_best:
                x_best, f_best = x, f
            break
        x_best, f_best = x, f
        design = {**design, **vals}
    return x_best, f_best


def minimax_polish(mech, objective: str, design: Mapping, bounds: Mapping,
                   adjust_boxes: Mapping, constraints: Sequence[Constraint] = (),
                   samples: int = 2880, maxiter: int = 200, step: float = 1e-6,
                   margin: float = 1e-3):
    """A local polish for a minimax objective: SLSQP on the epigraph form of a line_deviation
    output with measure sum_extremes (the needle's SumDelta).

    SumDelta = max(max d, 0) + max(-min d, 0) is not smooth where two extremes of d(q) trade,
    which is where its optimum lies; a Nelder-Mead stalls there. In epigraph form it is smooth:
    minimise t_plus + t_minus over the refined parameters, the compensators' settings (inside
    their boxes) and t_plus, t_minus >= 0, subject to d(q_k) <= t_plus and -d(q_k) <= t_minus at
    `samples` driving angles and to `constraints` (Chebyshev approximation, Polukhin's own
    criterion), each constraint held `margin` (in its scale) inside its limit, so that the
    exact re-reading (the compensators re-optimised) still meets it. The Jacobian is a forward
    difference (`step` of each box), all columns in one vectorised evaluation. Returns
    (values, t_plus + t_minus on the samples, SLSQP's message): the values hold every refined
    parameter and compensator; the caller re-reads the objective with its exact adjuster
    (the sampled maximum lies below the exact one)."""
    from scipy.optimize import minimize

    o = mech.output(objective)
    if o.type != "line_deviation" or o.fields.get("measure") != "sum_extremes":
        raise ParameterError("objective", "must be a line_deviation output with measure "
                             "sum_extremes for the minimax polish", objective)
    names = list(bounds) + [k for k in adjust_boxes if k not in bounds]
    box = {**{k: tuple(map(float, v)) for k, v in adjust_boxes.items()},
           **{k: tuple(map(float, v)) for k, v in bounds.items()}}
    lo = np.array([box[n][0] for n in names])
    hi = np.array([box[n][1] for n in names])
    q = np.arange(samples) * 2 * np.pi / samples
    fixed = {k: float(v) for k, v in design.items() if k not in names}
    nz = len(names)

    def values(Z):
        X = lo + np.clip(Z, 0.0, 1.0) * (hi - lo)
        m = X.shape[0]
        return {**{k: np.full(m, v) for k, v in fixed.items()},
                **{n: X[:, i] for i, n in enumerate(names)}}

    def g_of(Z):
        """(curves (m, q), constraint margins (m, c)): margins >= 0 where a limit holds."""
        v = values(Z)
        d = mech.curve(objective, v, q)
        cols = []
        if constraints:
            ev = mech.evaluate(v, [c.output for c in constraints])
            for c in constraints:
                y = np.asarray(ev.outputs[c.output], float)
                if c.lower is not None:
                    cols.append((y - c.lower) / c.scale - margin)
                if c.upper is not None:
                    cols.append((c.upper - y) / c.scale - margin)
        marg = np.stack(cols, axis=1) if cols else np.zeros((len(d), 0))
        return np.nan_to_num(d, nan=1e6), np.nan_to_num(marg, nan=-1e3)

    cache = {}

    def evaluated(z):
        key = z.tobytes()
        if key not in cache:
            Z = np.vstack([z[:nz], z[:nz] + step * np.eye(nz)])
            d, marg = g_of(Z)
            cache.clear()
            cache[key] = (d, marg)
        return cache[key]

    def cons(z):
        d, marg = evaluated(z)
        return np.concatenate([z[nz] - d[0], z[nz + 1] + d[0], marg[0]])

    def jac(z):
        d, marg = evaluated(z)
        dd = ((d[1:] - d[0]) / step).T  # (q, nz)
        dm = ((marg[1:] - marg[0]) / step).T
        k = d.shape[1]
        top = np.hstack([-dd, np.ones((k, 1)), np.zeros((k, 1))])
        mid = np.hstack([dd, np.zeros((k, 1)), np.ones((k, 1))])
        bot = np.hstack([dm, np.zeros((dm.shape[0], 2))])
        return np.vstack([top, mid, bot])

    x0 = np.array([float(design[n]) for n in names])
    z0 = (x0 - lo) / (hi - lo)
    d0, _ = g_of(z0[None, :])
    z0 = np.concatenate([np.clip(z0, 0, 1), [max(d0[0].max(), 0.0), max(-d0[0].min(), 0.0)]])
    r = minimize(lambda z: z[nz] + z[nz + 1], z0,
                 jac=lambda z: np.r_[np.zeros(nz), 1.0, 1.0], method="SLSQP",
                 bounds=[(0.0, 1.0)] * nz + [(0.0, None)] * 2,
                 constraints=[{"type": "ineq", "fun": cons, "jac": jac}],
                 options={"maxiter": maxiter, "ftol": 1e-10})
    x = lo + np.clip(r.x[:nz], 0.0, 1.0) * (hi - lo)
    return {n: float(v) for n, v in zip(names, x, strict=True)}, float(r.fun), str(r.message)


def _box(name, v) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise ParameterError(name, "box must be (low, high)", v) from None
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ParameterError(name, "box must be finite", v)
    return lo, hi
