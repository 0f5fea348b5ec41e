"""Optimisation of the regulating angle beta with the guide fixed, batched over machines.

beta* minimises SumDelta over the regulating range exactly (the sliding-window optimum of
mechanisms/needle_208/adjust.py: the global minimum, and where SumDelta is flat the centre of the plateau,
reported as beta_low/high_deg); the window where SumDelta <= limit is found by bisection
outwards from beta* on a grid of grid_step_deg. Every machine of a batch steps together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.optimize import bisect_root, golden_min

DEFAULT_RANGE_DEG = (10.0, 35.0)
DEFAULT_LIMIT_UM = 10.0


@dataclass(frozen=True)
class BetaOptimum:
    """Per machine: beta* (deg), the deviation figures there (um) and the window (deg).

    window_low/high_deg are NaN where even beta* exceeds the limit; where the window reaches the
    end of the searched range it is clipped there and `window_clipped` is True.
    beta_low/high_deg: the plateau of the optimum (SumDelta within 1e-3 um of the minimum);
    beta_deg is its centre; `at_bound`: the plateau reaches the end of the searched range.
    """

    beta_deg: np.ndarray
    plus_um: np.ndarray
    minus_um: np.ndarray
    total_um: np.ndarray
    window_low_deg: np.ndarray
    window_high_deg: np.ndarray
    window_clipped: np.ndarray
    limit_um: float
    range_deg: tuple[float, float]
    beta_low_deg: np.ndarray | None = None
    beta_high_deg: np.ndarray | None = None
    at_bound: np.ndarray | None = None


def total_at(c: dict, beta_deg) -> np.ndarray:
    """SumDelta (um) of each machine at its beta (array of length n)."""
    return nm.deviation_figures(nm.with_values(c, beta=beta_deg)).total_um


def totals_on_grid(c: dict, betas) -> np.ndarray:
    """SumDelta (um) of n machines at each of G betas: shape (n, G); NaN where it cannot run."""
    n = next(iter(c.values())).shape[0]
    betas = np.asarray(betas, float)
    cg = nm.with_values(nm.repeat(c, betas.size), beta=np.tile(betas, n))
    return nm.deviation_figures(cg).total_um.reshape(n, betas.size)


def check_range(range_deg, limit_um) -> None:
    lo, hi = range_deg
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ParameterError("beta_range_deg", "must be a finite interval with low < high", range_deg)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)


def optimise_beta_columns(c: dict, range_deg=DEFAULT_RANGE_DEG, limit_um=DEFAULT_LIMIT_UM,
                          grid_step_deg: float = 0.5, window: bool = True,
                          engine: str = "numba") -> BetaOptimum:
    """beta* per machine; with window=False the window is left NaN (half the work)."""
    from sewtol.mechanisms.needle_208.adjust import optimise

    check_range(range_deg, limit_um)
    lo, hi = map(float, range_deg)
    n = next(iter(c.values())).shape[0]
    c = {k: np.broadcast_to(np.asarray(v, float).reshape(-1, 1), (n, 1)).copy()
         for k, v in c.items()}
    opt = optimise(c, {"beta": (lo, hi)}, engine=engine)
    b_opt = opt.settings["beta"]
    dead = ~np.isfinite(b_opt)
    figs = nm.deviation_figures(nm.with_values(c, beta=np.where(dead, 0.5 * (lo + hi), b_opt)))
    figs = nm.DeviationFigures(*(np.where(dead, np.nan, v)
                                 for v in (figs.plus_um, figs.minus_um, figs.total_um)))
    extra = dict(beta_low_deg=opt.low["beta"], beta_high_deg=opt.high["beta"],
                 at_bound=opt.at_bound["beta"])

    nan = np.full(n, np.nan)
    if not window:
        return BetaOptimum(b_opt, figs.plus_um, figs.minus_um, figs.total_um,
                           nan, nan, np.zeros(n, bool), float(limit_um), (lo, hi), **extra)
    g = max(int(np.ceil((hi - lo) / grid_step_deg)) + 1, 3)
    betas = np.linspace(lo, hi, g)
    tot = totals_on_grid(c, betas)
    exceed = ~(tot <= limit_um)  # NaN (cannot run) counts as exceeding
    idx = np.arange(g)
    b_safe = np.where(dead, lo, b_opt)[:, None]
    left_j = np.where(exceed & (betas[None, :] < b_safe), idx, -1).max(axis=1)
    right_j = np.where(exceed & (betas[None, :] > b_safe), idx, g).min(axis=1)
    inside = figs.total_um <= limit_um

    def crossing(fixed_end, j, none_value):
        has = (j != none_value) & inside
        edge = betas[np.clip(j, 0, g - 1)]
        root = bisect_root(lambda x: total_at(c, x) - limit_um,
                           np.where(has, edge, b_opt), b_opt, xtol=1e-7)
        return np.where(has, root, np.where(inside, fixed_end, np.nan)), inside & ~has

    w_lo, clip_lo = crossing(lo, left_j, -1)
    w_hi, clip_hi = crossing(hi, right_j, g)
    return BetaOptimum(
        beta_deg=np.where(dead, nan, b_opt), plus_um=figs.plus_um, minus_um=figs.minus_um,
        total_um=figs.total_um, window_low_deg=w_lo, window_high_deg=w_hi,
        window_clipped=clip_lo | clip_hi, limit_um=float(limit_um), range_deg=(lo, hi),
        **extra,
    )


def optimise_beta(params, range_deg=DEFAULT_RANGE_DEG, limit_um=DEFAULT_LIMIT_UM,
                  grid_step_deg: float = 0.5, window: bool = True) -> BetaOptimum:
    """beta* and its window for one machine or a batch (guide fixed as in params)."""
    c, _ = nm.columns(params)
    return optimise_beta_columns(c, range_deg, limit_um, grid_step_deg, window)


@dataclass(frozen=True)
class FittedOptimum:
    """beta that minimises the minimum-zone width (guide free), and that fitted guide."""

    beta_deg: np.ndarray
    zone: nm.MinimumZone


def optimise_beta_fitted_guide(c: dict, range_deg=DEFAULT_RANGE_DEG,
                               grid_step_deg: float = 0.5) -> FittedOptimum:
    """Joint optimum of beta and the guide: minimise the zone width over beta (per machine)."""
    check_range(range_deg, DEFAULT_LIMIT_UM)
    lo, hi = map(float, range_deg)
    n = next(iter(c.values())).shape[0]
    g = max(int(np.ceil((hi - lo) / grid_step_deg)) + 1, 3)
    betas = np.linspace(lo, hi, g)
    cg = nm.with_values(nm.repeat(c, g), beta=np.tile(betas, n))
    widths = nm.minimum_zone(cg).width_um.reshape(n, g)
    i = np.argmin(np.where(np.isnan(widths), np.inf, widths), axis=1)

    def width(b):
        return nm.minimum_zone(nm.with_values(c, beta=b)).width_um

    b_opt, _ = golden_min(width, betas[np.maximum(i - 1, 0)], betas[np.minimum(i + 1, g - 1)],
                          xtol=1e-7)
    return FittedOptimum(b_opt, nm.minimum_zone(nm.with_values(c, beta=b_opt)))
