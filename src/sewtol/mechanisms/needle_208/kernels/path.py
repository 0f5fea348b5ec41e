"""The band of the needle path on a trial guide: E sampled on each machine's rocker interval and
projected, in one fused numba kernel.

Same geometry as mechanisms.needle_208.chain_from_rocker (positions only, no derivatives):
B = A + AB e(theta + beta_sense beta), dyad B-C-D on side branch_C, E = B + BE e(ang(B->C) + CBE).
Used by needle_208.adjustment, which projects one sampled path on many trial guides;
tests/test_strategies.py holds it to the engine.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

FIELDS = ("AB", "BC", "BE", "CD", "CBE", "Ax", "Ay", "Dx", "Dy", "branch_C", "beta_sense", "beta")


def pack(c: dict) -> np.ndarray:
    """Parameter columns (n, 1) to the kernel's (n, len(FIELDS)) matrix."""
    n = next(iter(c.values())).shape[0]
    return np.ascontiguousarray(np.column_stack(
        [np.broadcast_to(np.asarray(c[f], float).reshape(-1, 1), (n, 1))[:, 0] for f in FIELDS]))


@nb.njit(cache=True)
def _vertex(a, b, c):
    """Offset (in samples, from the middle one) and value of the parabola's vertex through three
    equally spaced samples; offset 0 and value b if the parabola is flat."""
    curv = a - 2.0 * b + c
    if curv == 0.0:
        return 0.0, b
    x = 0.5 * (a - c) / curv
    return x, b - 0.125 * (c - a) * (c - a) / curv


@nb.njit(cache=True)
def _refine(f, k, m, sgn):
    """The extreme near sample k (sgn=1: max, -1: min) by a parabola through its neighbours,
    kept only where the vertex lies within one sample of k and improves on the samples."""
    best = f[k]
    for j in (k - 1, k, k + 1):
        if j < 1 or j > m - 2:
            continue
        x, v = _vertex(f[j - 1], f[j], f[j + 1])
        if abs(x) <= 1.0 and sgn * (v - best) > 0.0:
            best = v
    return best


@nb.njit(cache=True)
def band_kernel(P, lo, hi, m, nx, ny):
    """Max and min (mm) of nx E_x + ny E_y over the rocker interval per machine, from m samples
    refined by parabolic interpolation at the best sample (NaN if any sample fails to close).
    Serial: the callers batch thousands of calls on small batches, where threads cost more."""
    n = P.shape[0]
    out = np.empty((n, 2))
    f = np.empty(m)
    for i in range(n):
        AB, BC, BE, CD, CBE = P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4]
        ax, ay, dx, dy, br, bs, beta = P[i, 5], P[i, 6], P[i, 7], P[i, 8], P[i, 9], P[i, 10], P[i, 11]
        off = bs * beta * math.pi / 180.0
        rc = CBE * math.pi / 180.0
        rod_c, rod_s = BE / BC * math.cos(rc), BE / BC * math.sin(rc)
        k2 = BC * BC - CD * CD
        bad = False
        kmax = 0
        kmin = 0
        for k in range(m):
            th = lo[i] + (hi[i] - lo[i]) * k / (m - 1)
            bx = ax + AB * math.cos(th + off)
            by = ay + AB * math.sin(th + off)
            ux, uy = dx - bx, dy - by
            d2 = ux * ux + uy * uy
            inv = 1.0 / d2
            a = 0.5 * (k2 + d2) * inv
            h2 = BC * BC * inv - a * a
            if not (h2 >= 0.0):
                bad = True
                break
            h = math.sqrt(h2)
            wx = a * ux - br * h * uy
            wy = a * uy + br * h * ux
            ex = bx + rod_c * wx - rod_s * wy
            ey = by + rod_s * wx + rod_c * wy
            f[k] = nx[i] * ex + ny[i] * ey
            if f[k] > f[kmax]:
                kmax = k
            if f[k] < f[kmin]:
                kmin = k
        if bad:
            out[i, 0] = out[i, 1] = np.nan
            continue
        out[i, 0] = _refine(f, kmax, m, 1.0)
        out[i, 1] = _refine(f, kmin, m, -1.0)
    return out
