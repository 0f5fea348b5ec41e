"""The worst case of one output over the tolerance box, of any mechanism (the protocol): every
corner and the centre as one batch, the best `starts` polished by L-BFGS-B inside the box (never
below a point evaluated, not proven global; `monotone_on_axes` supports the corner answer).
With compensators the output is the adjusted one on every trial machine. Linear relations cut
the box to a polytope whose vertices are the candidates and SLSQP the polish; a relation that
is not linear is refused. See docs/mechanism_files.md.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.law import refuse_conditioned
from sewtol.protocol import machines
from sewtol.relations import polytope_vertices
from sewtol.studies.adjusting import Adjusted, adjusted, evaluated
from sewtol.studies.scan import checked
from sewtol.tolerances import ToleranceSet

# 2**14 corners in one batch (the needle's sets with the housing have up to 14 tolerances)
MAX_CORNER_PARAMS = 14
# central-difference step of the local search, as a fraction of each tolerance width
FD_STEP = 1e-4


@dataclass(frozen=True)
class Search:
    """starts: the best corners (or centre) polished; step: central-difference step (fraction
    of each width), or None for scipy's forward differences of step `eps`; failures: "skip"
    (a machine that cannot run is left out) or "worst" (it counts as the worst value)."""

    starts: int = 1
    maxiter: int = 100
    step: float | None = FD_STEP
    eps: float = 1e-6
    failures: str = "skip"


@dataclass(frozen=True)
class Extreme:
    """One extreme: its value, the best corner's, the point (deviation per parameter), whether
    it lies inside the box, and the adjusted result of the machine there (with compensators)."""

    extreme: str
    value: float
    corner_value: float
    point: dict
    interior: bool
    adjusted: Adjusted | None = None


@dataclass(frozen=True)
class WorstCaseResult:
    mechanism: str
    tolerances: str
    output: str
    rows: pd.DataFrame  # extreme (max/min), value, corner_value, interior, deviations
    corners: int
    failed_corners: int
    monotone_on_axes: bool | None
    adjust: str | None = None
    extremes: tuple[Extreme, ...] = ()

    method = ("every corner and the centre of the tolerance box, then L-BFGS-B inside the box "
              "from the best corner (never below any evaluated point); not proven global: the "
              "corner answer is exact when the output is monotone in each parameter over the box")

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "tolerances": self.tolerances,
                "output": self.output, "adjust": self.adjust, "method": self.method,
                "corners": self.corners,
                "failed_corners": self.failed_corners,
                "monotone_on_axes": self.monotone_on_axes,
                "rows": self.rows.to_dict("records")}


def worst_case(mech, tolerances: ToleranceSet, output: str, maxiter: int = 100, adjust=None, *,
               extremes=("max", "min"), search: Search | None = None, axes: bool = True,
               fast: bool = True, **options) -> WorstCaseResult:
    """Largest and smallest `output` over the tolerance box (see the module docstring); with
    `adjust` (compensators as `adjusting.adjusted` takes them) of the output adjusted on each
    trial machine. `search` defaults to Search(maxiter=maxiter); axes: check monotonicity
    along the axes; fast: use the mechanism's plug-ins; options go to its strategy adjuster."""
    mech.output(output)
    if isinstance(adjust, str) and adjust not in mech.compensators:
        raise ParameterError("adjust", "must name a compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")", adjust)
    search = search or Search(maxiter=maxiter)
    tol = checked(mech, tolerances)
    names = tol.params
    if len(names) > MAX_CORNER_PARAMS:
        raise ParameterError("tolerances", f"worst case enumerates corners; at most "
                             f"{MAX_CORNER_PARAMS} toleranced parameters", len(names))
    lo = np.array([t.lower for t in tol.items])
    hi = np.array([t.upper for t in tol.items])
    cut = linear_relations(tol)
    # a matched pair lies in one class: a union of sub-boxes this search does not walk
    refuse_conditioned(tol, selective="matches parts in classes, which the worst case does not "
                       "search; state the matched pairs' limit as a relation instead")

    def values(X):
        X = np.atleast_2d(X)
        return machines(mech, {k: X[:, i] for i, k in enumerate(names)})

    def f(X):
        if adjust is not None:
            return adjusted(mech, values(X), adjust, output, fast=fast, **options).value
        return evaluated(mech, values(X), output, fast=fast)

    if cut is None:
        corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
        cands = np.vstack([corners, 0.5 * (lo + hi)])
    else:
        corners = polytope_vertices(lo, hi, *cut)
        if not len(corners):
            raise ParameterError(tol.relations[0].where, "leave(s) nothing of the tolerance box",
                                 [r.expr for r in tol.relations])
        # the vertices' mean lies inside the polytope (it is convex)
        cands = np.vstack([corners, corners.mean(axis=0)])
    val = f(cands)
    failed = int(np.sum(np.isnan(val[:-1])))
    width = hi - lo
    found = []
    for extreme in extremes:
        sign = 1.0 if extreme == "max" else -1.0
        bad = np.inf if search.failures == "worst" else -np.inf

        def score(X, sign=sign, bad=bad):
            y = sign * f(X)
            return np.where(np.isnan(y), bad, y)

        s = np.where(np.isnan(val), bad, sign * val)
        if not np.isfinite(s).any() and search.failures == "skip":
            raise ParameterError("tolerances", f"no corner of the box gives a value of {output} "
                                 "(every machine fails)", tolerances.name)
        order = [int(np.argmax(s))] if search.starts == 1 else np.argsort(-s)[:search.starts]
        best_x, best_s = cands[order[0]], float(s[order[0]])
        corner_s = float(np.max(s[:-1]))
        for i in order:
            z0 = (cands[i] - lo) / width
            res = _polish(f, score, z0, lo, width, cut, sign, search)
            x_opt = lo + np.clip(res.x, 0.0, 1.0) * width
            if cut is not None and not _inside(x_opt, cut):
                continue  # SLSQP may end a hair outside the relations: that point is not a machine
            v_opt = float(score(x_opt)[0])
            if v_opt > best_s:
                best_s, best_x = v_opt, x_opt
        at_corner = bool(np.all(np.isclose(best_x, lo) | np.isclose(best_x, hi))) if cut is None \
            else bool(np.any(np.all(np.isclose(corners, best_x), axis=1)))
        at = None if adjust is None else adjusted(mech, values(best_x), adjust, output,
                                                  fast=fast, **options)
        found.append(Extreme(extreme, sign * best_s, sign * corner_s,
                             dict(zip(names, map(float, best_x), strict=True)), not at_corner,
                             at))
    rows = pd.DataFrame([{"extreme": e.extreme,
                          "output": output if adjust is None else f"{output}_adjusted",
                          "value": e.value, "corner_value": e.corner_value,
                          "interior": e.interior,
                          **{f"{k}_dev": v for k, v in e.point.items()}} for e in found])
    return WorstCaseResult(mech.name, tolerances.name, output, rows, len(corners), failed,
                           _monotone_on_axes(f, lo, hi) if axes else None,
                           adjust if isinstance(adjust, str) else None, tuple(found))


def linear_relations(tol: ToleranceSet):
    """(a, lower, upper) of the set's relations over its parameters' deviations (a: one row
    per relation, the constant moved into the limits), None without relations; a relation
    that is not linear is refused in one line."""
    if not tol.relations:
        return None
    names = tol.params
    rows, lower, upper = [], [], []
    for r in tol.relations:
        if r.linear is None:
            raise ParameterError(f"{r.where}.expr", "must be linear in the deviations for the "
                                 "worst case (sums of parameters times numbers: its region "
                                 "then has vertices to start from)", r.expr)
        coef, const = r.linear
        # a parameter of zero width deviates by 0: its term drops out
        rows.append([coef.get(p, 0.0) for p in names])
        lower.append(r.lower - const)
        upper.append(r.upper - const)
    return np.array(rows), np.array(lower), np.array(upper)


def _inside(x, cut, rtol: float = 1e-9) -> bool:
    """True when x keeps every linear relation (to rtol of the largest term)."""
    a, lower, upper = cut
    ax = a @ x
    tol = rtol * (1.0 + np.abs(a) @ np.abs(x))
    return bool(np.all((ax >= lower - tol) & (ax <= upper + tol)))


def _polish(f, score, z0, lo, width, cut, sign, search):
    """L-BFGS-B from z0 inside the box scaled to [0, 1]; with relations (`cut`) SLSQP, the
    relations as linear constraints lower <= a (lo + z width) <= upper."""
    from scipy.optimize import minimize

    kw = {"method": "L-BFGS-B"}
    if cut is not None:
        a, lower, upper = cut
        az, base = a * width[None, :], a @ lo
        cons = []
        for k in range(len(a)):
            if np.isfinite(lower[k]):
                cons.append({"type": "ineq", "fun": lambda z, k=k: az[k] @ z + base[k] - lower[k],
                             "jac": lambda z, k=k: az[k]})
            if np.isfinite(upper[k]):
                cons.append({"type": "ineq", "fun": lambda z, k=k: upper[k] - base[k] - az[k] @ z,
                             "jac": lambda z, k=k: -az[k]})
        kw = {"method": "SLSQP", "constraints": cons}
    bounds = [(0.0, 1.0)] * len(z0)
    if search.step is None:
        def neg(z):
            return -float(score(lo + (z if cut is None else np.clip(z, 0, 1)) * width)[0])

        return minimize(neg, z0, bounds=bounds, **kw,
                        options={"eps": search.eps, "maxiter": search.maxiter})
    return minimize(_central(f, lo, width, sign, search.step), z0, jac=True, bounds=bounds,
                    options={"maxiter": search.maxiter}, **kw)


def _central(f, lo, width, sign, step):
    """-value and -gradient at z (the box scaled to [0, 1]): value and central differences in
    one batch of 2d + 1 machines; a machine that cannot run scores -1e12."""
    def neg_and_grad(z):
        d = len(z)
        pts = [z] + [np.clip(z + dz, 0, 1) for i in range(d)
                     for dz in (step * np.eye(d)[i], -step * np.eye(d)[i])]
        y = sign * f(lo + np.array(pts) * width)
        y = np.where(np.isnan(y), -1e12, y)
        g = np.array([(y[1 + 2 * i] - y[2 + 2 * i]) / (pts[1 + 2 * i][i] - pts[2 + 2 * i][i])
                      if pts[1 + 2 * i][i] != pts[2 + 2 * i][i] else 0.0 for i in range(d)])
        return -float(y[0]), -g
    return neg_and_grad


def _monotone_on_axes(f, lo, hi, points: int = 7) -> bool:
    """True if the output is monotone along every axis of the box through its centre."""
    centre = 0.5 * (lo + hi)
    X = []
    for i in range(len(lo)):
        for t in np.linspace(lo[i], hi[i], points):
            x = centre.copy()
            x[i] = t
            X.append(x)
    y = f(np.array(X)).reshape(len(lo), points)
    if np.isnan(y).any():
        return False
    d = np.diff(y, axis=1)
    tol = 1e-12 * np.maximum(1.0, np.abs(y).max())
    return bool(np.all(np.all(d >= -tol, axis=1) | np.all(d <= tol, axis=1)))
