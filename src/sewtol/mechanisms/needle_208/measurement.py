"""The needle's compensators set from a measured deviation (sewtol.measurement_error).

Per machine the fitter reads d at the crank angles phi_k with an error e_k (um) each; for any
settings the reading is

    m_k = n(a).(E(phi_k; beta, CD) - N1) * 1000 + e_k - shift        (um)

with E from the fused position kernel (kernels/positions.py, the engine's topology, tested
against the plain loop), a the guide's angle (its own plus the angle compensator's offset), N1
the guide's point and shift the guide shift. The measured SumDelta is max(0, max m) + max(0,
-min m). The settings chosen minimise it:

- the guide shift in closed form on the measured band (`adjustment.shift_optimum`, as the exact
  adjuster does on the true band);
- the guide angle by golden section over its box: over +-0.1 deg the reading is linear in the
  angle to 1e-6 of itself, so the measured SumDelta is convex in it (a maximum of linear
  functions minus a minimum of them);
- beta on a grid of BETA_GRID_DEG over its box, then golden section around the three best
  local minima of the grid (the measured SumDelta has plateaus and kinks in beta, as the true
  one does);
- CD on a grid of OUTER_GRID points over its box, then golden section around the two best.

The machine's figures are then the TRUE ones at those settings (`metrics.deviation_figures`,
exact extremes), with the status of `adjustment.adjust`. The settings are in each compensator's
own terms (beta absolute, the others offsets from the as-built value). A discrete compensator
(steps) is refused: a fitter setting from a reading picks a shim by the reading, which is not
modelled here.
"""

from __future__ import annotations

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.adjustment import Adjustment, shift_optimum, status_of
from sewtol.mechanisms.needle_208.compensators import Strategy
from sewtol.mechanisms.needle_208.kernels import POSITION_FIELDS as FIELDS
from sewtol.mechanisms.needle_208.kernels import positions_serial

NAMES = ("beta", "guide_shift_um", "guide_angle", "CD")
BETA_GRID_DEG = 0.5
OUTER_GRID = 25  # CD: every 0.025 mm over +-0.3 mm (13 points missed the optimum by 1.3 um on 1 of 40)
GOLDEN = {"beta": 30, "guide_angle": 32, "CD": 20}  # iterations: brackets to < 1e-5 of a unit
INVPHI = (np.sqrt(5.0) - 1.0) / 2.0


def _pack(c) -> np.ndarray:
    n = max(np.asarray(c[f]).size for f in FIELDS)
    return np.ascontiguousarray(np.column_stack(
        [np.broadcast_to(np.asarray(c[f], float).reshape(-1), (n,)) for f in FIELDS]))


def _col(c, name, n) -> np.ndarray:
    return np.broadcast_to(np.asarray(c[name], float).reshape(-1), (n,)).copy()


def readings_um(E, gx, gy, angle_deg, noise_um) -> np.ndarray:
    """The reading m_k without the guide shift (um), (n, K): n(a).(E - N1) * 1000 + e_k."""
    a = np.radians(angle_deg)[:, None]
    return ((E[..., 0] - gx[:, None]) * np.cos(a)
            - (E[..., 1] - gy[:, None]) * np.sin(a)) * 1e3 + noise_um


def _keep(best, score, x, aux):
    s, bx, baux = best
    better = score < s
    return (np.where(better, score, s), np.where(better, x, bx),
            {k: np.where(better, aux[k], baux[k]) for k in aux})


def _golden(f, a, b, iters, best):
    """Golden section of f on [a, b] per machine; best = (score, x, aux) kept where improved."""
    x1, x2 = b - INVPHI * (b - a), a + INVPHI * (b - a)
    (f1, aux1), (f2, aux2) = f(x1), f(x2)
    best = _keep(_keep(best, f1, x1, aux1), f2, x2, aux2)
    for _ in range(iters):
        left = f1 <= f2
        a, b = np.where(left, a, x1), np.where(left, x2, b)
        xn = np.where(left, b - INVPHI * (b - a), a + INVPHI * (b - a))
        fn, auxn = f(xn)
        best = _keep(best, fn, xn, auxn)
        x1, x2 = np.where(left, xn, x2), np.where(left, x1, xn)
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
    return best


def _grid_then_golden(f, low, high, points, starts, iters, n, aux0):
    """f over a grid of `points` on [low, high], then golden section around the best `starts`
    local minima of the grid (between the grid neighbours); never worse than the grid."""
    grid = np.linspace(low, high, points)
    best = (np.full(n, np.inf), np.full(n, grid[0]), aux0)
    vals = []
    for g in grid:
        s, aux = f(np.full(n, g))
        best = _keep(best, s, np.full(n, g), aux)
        vals.append(s)
    vals = np.stack(vals, axis=1)
    left = np.concatenate([np.full((n, 1), np.inf), vals[:, :-1]], axis=1)
    right = np.concatenate([vals[:, 1:], np.full((n, 1), np.inf)], axis=1)
    score = np.where((vals <= left) & (vals <= right) & np.isfinite(vals), vals, np.inf)
    rows = np.arange(n)
    for _ in range(starts):
        i = np.argmin(score, axis=1)
        if not np.isfinite(score[rows, i]).any():
            break
        score[rows, i] = np.inf
        a, b = grid[np.maximum(i - 1, 0)], grid[np.minimum(i + 1, grid.size - 1)]
        best = _golden(f, a, b, iters, best)
    return best


def measured_settings(c: dict, strategy: Strategy, phi_rad, noise_um) -> tuple:
    """(measured SumDelta (um), settings) per machine: the optimum of the reading over the
    strategy's compensators (module docstring); settings in each compensator's own terms."""
    comps = {k.name: k for k in strategy.compensators}
    for k in comps.values():
        if k.name not in NAMES:
            raise ParameterError("measurement_error", "sets the needle's compensators "
                                 f"{', '.join(NAMES)} from a reading", k.name)
        if k.discrete:
            raise ParameterError("measurement_error", "needs continuous compensators (a shim "
                                 "chosen from a reading is not modelled)", k.name)
    P0 = _pack(c)
    n = P0.shape[0]
    phi = np.asarray(phi_rad, float)
    noise = np.broadcast_to(np.asarray(noise_um, float), (n, phi.size))
    gx, gy = _col(c, "guide_x", n), _col(c, "guide_y", n)
    own_angle, own_shift = _col(c, "guide_angle", n), _col(c, "guide_shift_um", n)
    shift, angle = comps.get("guide_shift_um"), comps.get("guide_angle")
    beta, cd = comps.get("beta"), comps.get("CD")
    zeros = np.zeros(n)

    def at_angle(E, offset):
        m = readings_um(E, gx, gy, own_angle + offset, noise)
        bad = ~np.all(np.isfinite(m), axis=1)  # a position where the drive does not close
        total = shift_optimum(np.where(bad, 0.0, m.max(axis=1)),
                              np.where(bad, 0.0, m.min(axis=1)), own_shift, shift)[0]
        return np.where(bad | ~np.isfinite(total), np.inf, total)

    def by_angle(P):
        E = positions_serial(P, phi)
        if angle is None:
            return at_angle(E, zeros), {"guide_angle": zeros}
        s, x, _ = _golden(lambda x: (at_angle(E, x), {}), np.full(n, angle.low),
                          np.full(n, angle.high), GOLDEN["guide_angle"],
                          (np.full(n, np.inf), zeros, {}))
        return s, {"guide_angle": x}

    def by_beta(P):
        if beta is None:
            s, aux = by_angle(P)
            return s, {**aux, "beta": P[:, 8].copy()}

        def f(x):
            Q = P.copy()
            Q[:, 8] = x
            return by_angle(Q)

        s, x, aux = _grid_then_golden(
            f, beta.low, beta.high, int(round((beta.high - beta.low) / BETA_GRID_DEG)) + 1, 3,
            GOLDEN["beta"], n, {"guide_angle": zeros})
        return s, {**aux, "beta": x}

    cd_col = FIELDS.index("CD")
    if cd is None:
        score, aux = by_beta(P0)
        aux["CD"] = zeros
    else:
        own_cd = P0[:, cd_col].copy()

        def g(x):
            Q = P0.copy()
            Q[:, cd_col] = own_cd + x
            return by_beta(Q)

        score, x, aux = _grid_then_golden(g, cd.low, cd.high, OUTER_GRID, 2, GOLDEN["CD"], n,
                                          {"guide_angle": zeros, "beta": zeros})
        aux["CD"] = x
    settings = {name: aux[name] for name in comps if name != "guide_shift_um"}
    if shift is not None:  # the closed-form shift on the final reading
        Q = P0.copy()
        if beta is not None:
            Q[:, 8] = aux["beta"]
        if cd is not None:
            Q[:, cd_col] = P0[:, cd_col] + aux["CD"]
        m = readings_um(positions_serial(Q, phi), gx, gy, own_angle + aux["guide_angle"],
                        noise)
        settings["guide_shift_um"] = shift_optimum(m.max(axis=1), m.min(axis=1), own_shift,
                                                   shift)[1]
    return score, settings


def adjust_measured(c: dict, strategy: Strategy, limit_um: float, phi_rad, noise_um,
                    ) -> tuple[Adjustment, np.ndarray]:
    """Each machine (columns c, (n, 1)) set from its reading (`measured_settings`), figured at
    those settings with the exact extremes: the Adjustment (status as `adjustment.adjust`;
    plateaus are the settings themselves) and the measured SumDelta (um) the fitter saw."""
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    strategy.check_names(list(c))
    before_feas = nm.feasibility(c)
    before = nm.deviation_figures(c, before_feas).total_um
    measured, settings = measured_settings(c, strategy, phi_rad, noise_um)
    final = dict(c)
    for comp in strategy.compensators:
        s = np.asarray(settings[comp.name], float).reshape(-1, 1)
        final[comp.name] = np.broadcast_to(comp.value(c[comp.name], s),
                                           c[comp.name].shape).copy()
    feas = nm.feasibility(final)
    figs = nm.deviation_figures(final, feas)
    dead = ~np.isfinite(figs.total_um)
    out, at_limit = {}, {}
    for comp in strategy.compensators:
        x = np.where(dead, np.nan, settings[comp.name])
        out[comp.name] = x
        eps = 1e-6 * (comp.high - comp.low)
        at_limit[comp.name] = (x <= comp.low + eps) | (x >= comp.high - eps)
    dead_point = np.where(dead, before_feas.dead_point, feas.dead_point)
    status = status_of(figs.total_um, limit_um, dead_point)
    adj = Adjustment(strategy, float(limit_um), before, figs.total_um, figs.plus_um,
                     figs.minus_um, figs.total_um, status, out, dict(out), dict(out), at_limit)
    return adj, np.where(np.isfinite(measured), measured, np.nan)
