"""Exact maximum and minimum of a smooth function over an interval, batched over machines.

A grid finds the basins; the best local maxima (and minima) are then polished by safeguarded
Newton steps using the analytic first and second derivatives, so the extreme values do not
depend on the grid. With the defaults the result is converged far below 0.001 um on the needle
path (tests compare with a 200,000-point sweep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Extremes:
    fmax: np.ndarray
    tmax: np.ndarray
    fmin: np.ndarray
    tmin: np.ndarray


def _local_peaks(f):
    """Mask of grid points not below either neighbour (endpoints compare with one side)."""
    left = np.concatenate([np.full(f.shape[:-1] + (1,), -np.inf), f[..., :-1]], axis=-1)
    right = np.concatenate([f[..., 1:], np.full(f.shape[:-1] + (1,), -np.inf)], axis=-1)
    return (f >= left) & (f >= right)


def _candidates(f, k):
    score = np.where(_local_peaks(f), f, -np.inf)
    score = np.where(np.isnan(score), -np.inf, score)
    return np.argsort(score, axis=-1)[..., -k:]


def interval_extremes(fn, lo, hi, n_grid: int = 48, n_candidates: int = 3,
                      n_newton: int = 8) -> Extremes:
    """Max and min of fn over [lo, hi] per machine.

    fn(t) takes t of shape (n, m) and returns (f, df/dt, d2f/dt2) of that shape. lo and hi have
    shape (n,). Machines whose function is NaN anywhere on the grid get NaN extremes.
    """
    lo = np.asarray(lo, float).reshape(-1, 1)
    hi = np.asarray(hi, float).reshape(-1, 1)
    s = np.linspace(0.0, 1.0, n_grid)
    t = lo + (hi - lo) * s
    f, _, _ = fn(t)
    h = (hi - lo) / (n_grid - 1)
    k = min(n_candidates, n_grid)
    imax = _candidates(f, k)
    imin = _candidates(-f, k)
    tc = np.take_along_axis(t, np.concatenate([imax, imin], axis=-1), axis=-1)
    sign = np.concatenate([np.ones(k), -np.ones(k)])  # +1: polish a maximum, -1: a minimum
    t_lo = np.maximum(tc - h, lo)
    t_hi = np.minimum(tc + h, hi)
    tt = tc
    for _ in range(n_newton):
        g, dg, ddg = fn(tt)
        dg, ddg = sign * dg, sign * ddg
        # Newton on the derivative where the function is concave in the searched sense,
        # otherwise a quarter-cell step uphill
        step = np.where(ddg < 0.0, -dg / np.where(ddg < 0.0, ddg, 1.0), np.sign(dg) * h / 4)
        tt = np.clip(tt + step, t_lo, t_hi)
    g, _, _ = fn(tt)
    gmax, gmin = g[..., :k], g[..., k:]
    # never worse than the grid itself
    jmax = np.argmax(np.where(np.isnan(gmax), -np.inf, gmax), axis=-1)[..., None]
    jmin = np.argmin(np.where(np.isnan(gmin), np.inf, gmin), axis=-1)[..., None]
    fmax = np.take_along_axis(gmax, jmax, -1)[..., 0]
    fmin = np.take_along_axis(gmin, jmin, -1)[..., 0]
    tmax = np.take_along_axis(tt[..., :k], jmax, -1)[..., 0]
    tmin = np.take_along_axis(tt[..., k:], jmin, -1)[..., 0]
    gridmax = np.max(f, axis=-1)
    gridmin = np.min(f, axis=-1)
    use_grid_max = gridmax > fmax
    use_grid_min = gridmin < fmin
    tmax = np.where(use_grid_max, np.take_along_axis(t, np.argmax(f, -1)[..., None], -1)[..., 0], tmax)
    tmin = np.where(use_grid_min, np.take_along_axis(t, np.argmin(f, -1)[..., None], -1)[..., 0], tmin)
    fmax = np.maximum(fmax, gridmax)
    fmin = np.minimum(fmin, gridmin)
    bad = np.any(np.isnan(f), axis=-1)
    nan = np.full_like(fmax, np.nan)
    return Extremes(np.where(bad, nan, fmax), tmax, np.where(bad, nan, fmin), tmin)
