"""Worst case of SumDelta over the tolerance box, by bounded optimisation.

Corners are not enough for a nonlinear path (a lateral shift and a shape change can peak
inside the box), so every corner (up to 2^10) and the centre are evaluated as one batch, and the
best starts are polished by L-BFGS-B inside the box. Two cases: beta fixed at the nominal
machine's beta*, and beta re-optimised on each trial machine (the max over the box of the min
over beta); with a strategy (needle_208.compensators) the adjusted case is the max over the box of
the joint optimum over the strategy's compensators (needle_208.adjustment.adjust). The search is a
heuristic over the box (corners, centre, L-BFGS-B from the best three): the reported worst case
is never below any point it evaluated, but it is not proven global.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy.optimize import minimize

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.evaluate import evaluate
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208


@dataclass(frozen=True)
class WorstCase:
    case: str
    total_um: float
    corner_total_um: float
    point: dict  # deviation per parameter (mm)
    beta_deg: float
    interior: bool  # True when the worst point is not a corner
    # the worst machine's adjusted beta*: its plateau reaches an end of the searched range
    beta_at_bound: bool = False

    def to_row(self) -> dict:
        row = {"case": self.case, "total_um": self.total_um,
               "worst_corner_total_um": self.corner_total_um, "beta_deg": self.beta_deg,
               "beta_at_bound": self.beta_at_bound, "interior": self.interior}
        row.update({f"{k}_mm": v for k, v in self.point.items()})
        return row


def _objective(nominal, names, adjust, range_deg, strategy=None):
    def totals(X):
        X = np.atleast_2d(X)
        dev = {k: X[:, i] for i, k in enumerate(names)}
        if adjust and strategy is not None:
            from sewtol.mechanisms.needle_208.adjustment import adjust as adjust_machines
            from sewtol.mechanisms.needle_208.strategies import columns_of

            out = adjust_machines(columns_of(nominal, dev), strategy, plateaus=False)
            return np.where(np.isnan(out.total_um), np.inf, out.total_um), out
        out = evaluate(nominal, dev, adjust=adjust, range_deg=range_deg)
        t = out.total_adjusted_um if adjust else out.total_fixed_um
        return np.where(np.isnan(t), np.inf, t), out
    return totals


def worst_case(nominal, tolerances: ToleranceSet | str, adjust: bool, range_deg=sb.DEFAULT_RANGE_DEG,
               starts: int = 3, strategy=None) -> WorstCase:
    """The worst SumDelta over the tolerance box: beta fixed (adjust=False), beta re-optimised
    per trial machine (adjust=True), or, with adjust=True and a strategy, the joint optimum over
    the strategy's compensators per trial machine."""
    tolerances = needle_set(tolerances)
    tol = tolerances.active()
    names = tol.params
    if len(names) > 10:
        raise ParameterError("tolerances", "worst case enumerates corners; at most 10 parameters",
                             len(names))
    lo = np.array([t.lower for t in tol.items])
    hi = np.array([t.upper for t in tol.items])
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    totals = _objective(nominal, names, adjust, range_deg, strategy)
    cands = np.vstack([corners, 0.5 * (lo + hi)])
    val, _ = totals(cands)
    corner_best = float(np.max(val[:-1]))
    order = np.argsort(-val)[:starts]
    scale = np.where(hi > lo, hi - lo, 1.0)
    best_x, best_v = cands[order[0]], float(val[order[0]])
    for i in order:
        def neg(z):
            return -float(totals(lo + z * scale)[0][0])
        z0 = (cands[i] - lo) / scale
        res = minimize(neg, z0, method="L-BFGS-B", bounds=[(0, 1)] * len(names),
                       options={"eps": 1e-6, "maxiter": 200})
        if -res.fun > best_v:
            best_v, best_x = float(-res.fun), lo + res.x * scale
    _, out = totals(best_x)
    at_corner = bool(np.all(np.isclose(best_x, lo) | np.isclose(best_x, hi)))
    at_bound = False
    if adjust and strategy is not None:
        beta = float(out.settings["beta"][0]) if "beta" in out.settings else float(nominal.beta)
        case = f"adjusted_{strategy.name}"
        for comp in strategy.compensators:
            if comp.name == "beta":
                eps = 1e-6 * (comp.high - comp.low)
                at_bound = bool(out.plateau_low["beta"][0] <= comp.low + eps
                                or out.plateau_high["beta"][0] >= comp.high - eps)
    else:
        beta = float(out.beta_opt_deg[0]) if adjust else float(nominal.beta)
        case = "adjusted_beta" if adjust else "fixed_beta"
        at_bound = bool(adjust and out.beta_at_bound[0])
    return WorstCase(case, best_v, corner_best,
                     dict(zip(names, map(float, best_x), strict=True)), beta, not at_corner,
                     at_bound)


def worst_case_table(nominal: Needle208, tolerances: ToleranceSet | str,
                     range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                     strategy: Strategy | None = None) -> pd.DataFrame:
    """The worst SumDelta over the tolerance box, with beta fixed and after adjustment.

    Every corner of the box and its centre are evaluated as one batch; the three worst are
    polished by L-BFGS-B inside the box, so a worst point inside the box is found too.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters); its beta* is the fixed case's beta.
    tolerances : ToleranceSet or str
        The box: every tolerance between its lower and upper limit.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    strategy : Strategy or None
        The adjusted case: None for beta re-optimised, or a strategy's joint optimum.

    Returns
    -------
    pandas.DataFrame
        Rows ``fixed_beta`` and the adjusted case, with ``total_um`` (the worst SumDelta),
        ``worst_corner_total_um``, ``beta_deg``, ``interior`` (True when the worst point is not
        a corner) and the worst point's deviation per parameter (``NAME_mm``).
    """
    tolerances = needle_set(tolerances)
    return pd.DataFrame([worst_case(nominal, tolerances, a, range_deg,
                                    strategy=strategy if a else None).to_row()
                         for a in (False, True)])
