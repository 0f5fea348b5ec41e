"""Fused numba kernel for the needle drive's beta optimisation, one machine per thread.

Same mathematics as the numpy path (engine groups + metrics.extremes + needle_208.beta), written as
scalar code so nothing is allocated in the inner loops:
- the second four-bar from the rocker angle in closed form, with analytic d/dtheta, d2/dtheta2;
- extremes of d over the rocker interval: a grid, then safeguarded Newton on the best local
  maxima and minima (as metrics.extremes);
- beta*: a coarse grid over the regulating range (full extremes, as the numpy path), then
  golden-section search in which each trial beta re-polishes the extremes found at the previous
  trial (warm start) plus the interval ends, so a trial costs ~30 point evaluations, not ~100.
tests/test_kernels.py holds it to the numpy reference.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# parameter columns passed to the kernel, in this order
FIELDS = ("AB", "BC", "BE", "CD", "CBE", "Ax", "Ay", "Dx", "Dy", "branch_C", "beta_sense",
          "guide_x", "guide_y", "guide_angle", "guide_shift_um")
_INVPHI = (math.sqrt(5.0) - 1.0) / 2.0
N_CAND = 3
# needle_208.DEAD_POINT_DEG as the sine the kernel compares with (kept equal by a test)
SIN_DEAD_POINT = math.sin(math.radians(1.0))


@nb.njit(cache=True, fastmath=False)
def needle_point(p, beta_deg, th):
    """The needle point E (mm) and its first two derivatives w.r.t. the rocker angle:
    (Ex, Ey, E'x, E'y, E''x, E''y), NaN where B-C-D does not close or is within 1 deg of a dead
    point. Independent of the guide (its angle and shift): an outer search over the guide angle
    projects the same points on each trial normal (window.outer_batch)."""
    AB, BC, BE, CD, CBE, ax, ay, dx, dy, br, bs = (
        p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10])
    a = th + bs * beta_deg * math.pi / 180.0
    ca, sa = math.cos(a), math.sin(a)
    bx, by = ax + AB * ca, ay + AB * sa
    b1x, b1y = -AB * sa, AB * ca
    b2x, b2y = -AB * ca, -AB * sa
    # dyad B-C-D: C at BC from B and CD from D, on side br of B->D
    ddx, ddy = dx - bx, dy - by
    L = math.sqrt(ddx * ddx + ddy * ddy)
    aa = (BC * BC - CD * CD + L * L) / (2.0 * L)
    h2 = BC * BC - aa * aa
    if h2 < 0.0:
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan
    h = math.sqrt(h2)
    cx = bx + (aa * ddx - br * h * ddy) / L
    cy = by + (aa * ddy + br * h * ddx) / L
    u1x, u1y = cx - bx, cy - by
    u2x, u2y = cx - dx, cy - dy
    det = u1x * u2y - u1y * u2x
    if abs(det) < SIN_DEAD_POINT * BC * CD:  # dead point of B-C-D: counted as not running
        return np.nan, np.nan, np.nan, np.nan, np.nan, np.nan
    r1 = u1x * b1x + u1y * b1y
    c1x = (r1 * u2y) / det
    c1y = (-r1 * u2x) / det
    w1x, w1y = c1x - b1x, c1y - b1y
    r1 = u1x * b2x + u1y * b2y - (w1x * w1x + w1y * w1y)
    r2 = -(c1x * c1x + c1y * c1y)
    c2x = (r1 * u2y - u1y * r2) / det
    c2y = (u1x * r2 - r1 * u2x) / det
    # E = B + BE e(ang(B->C) + CBE)
    vx, vy = u1x, u1y
    v1x, v1y = c1x - b1x, c1y - b1y
    v2x, v2y = c2x - b2x, c2y - b2y
    r2v = vx * vx + vy * vy
    cr1 = vx * v1y - vy * v1x
    dt1 = vx * v1x + vy * v1y
    om = cr1 / r2v
    al = (vx * v2y - vy * v2x) / r2v - 2.0 * cr1 * dt1 / (r2v * r2v)
    ang = math.atan2(vy, vx) + CBE * math.pi / 180.0
    ex, ey = BE * math.cos(ang), BE * math.sin(ang)
    Ex = bx + ex
    Ey = by + ey
    E1x = b1x - om * ey
    E1y = b1y + om * ex
    E2x = b2x - al * ey - om * om * ex
    E2y = b2y + al * ex - om * om * ey
    return Ex, Ey, E1x, E1y, E2x, E2y


@nb.njit(cache=True, fastmath=False)
def guide_normal(p):
    """The guide's normal (nx, ny) and offset (mm): d = nx Ex + ny Ey - offset."""
    g = p[13] * math.pi / 180.0
    nx, ny = math.cos(g), -math.sin(g)
    return nx, ny, nx * p[11] + ny * p[12] + p[14] * 1e-3


@nb.njit(cache=True, fastmath=False)
def guide_offset(p, beta_deg, th):
    """d (mm, relative to the guide) and its first two derivatives w.r.t. the rocker angle."""
    Ex, Ey, E1x, E1y, E2x, E2y = needle_point(p, beta_deg, th)
    if math.isnan(Ex):
        return np.nan, np.nan, np.nan
    nx, ny, off = guide_normal(p)
    return nx * Ex + ny * Ey - off, nx * E1x + ny * E1y, nx * E2x + ny * E2y


@nb.njit(cache=True)
def _polish(p, beta, t, lo, hi, h, sgn, iters):
    """Safeguarded Newton towards a max (sgn=1) or min (sgn=-1) within [t-h, t+h] and [lo, hi]."""
    tl = max(t - h, lo)
    th_ = min(t + h, hi)
    for _ in range(iters):
        f, f1, f2 = guide_offset(p, beta, t)
        f1 *= sgn
        f2 *= sgn
        if f2 < 0.0:
            step = -f1 / f2
        else:
            step = h / 4.0 if f1 > 0 else -h / 4.0
        t = min(max(t + step, tl), th_)
    f, _, _ = guide_offset(p, beta, t)
    return t, f


@nb.njit(cache=True)
def _extremes_full(p, beta, lo, hi, n_grid, n_newton, cand):
    """Max and min of d by grid + Newton; cand receives the polished locations (2*N_CAND)."""
    h = (hi - lo) / (n_grid - 1)
    fs = np.empty(n_grid)
    for k in range(n_grid):
        f, _, _ = guide_offset(p, beta, lo + h * k)
        if math.isnan(f):
            return np.nan, np.nan
        fs[k] = f
    fmax = -np.inf
    fmin = np.inf
    for sgn_i in range(2):
        sgn = 1.0 if sgn_i == 0 else -1.0
        score = np.empty(n_grid)
        for k in range(n_grid):
            v = sgn * fs[k]
            left = sgn * fs[k - 1] if k > 0 else -np.inf
            right = sgn * fs[k + 1] if k < n_grid - 1 else -np.inf
            score[k] = v if (v >= left and v >= right) else -np.inf
        order = np.argsort(score)
        for j in range(N_CAND):
            k = order[n_grid - 1 - j]
            t0 = lo + h * k
            if score[k] == -np.inf:
                cand[sgn_i * N_CAND + j] = t0
                continue
            t, f = _polish(p, beta, t0, lo, hi, h, sgn, n_newton)
            cand[sgn_i * N_CAND + j] = t
            if sgn > 0:
                fmax = max(fmax, f)
            else:
                fmin = min(fmin, f)
        for k in range(n_grid):
            if sgn > 0:
                fmax = max(fmax, fs[k])
            else:
                fmin = min(fmin, fs[k])
    return fmax, fmin


@nb.njit(cache=True)
def _extremes_warm(p, beta, lo, hi, h, cand):
    """Re-polish the previous extremes at a nearby beta, and take the interval ends too."""
    fmax = -np.inf
    fmin = np.inf
    for sgn_i in range(2):
        sgn = 1.0 if sgn_i == 0 else -1.0
        for j in range(N_CAND):
            t, f = _polish(p, beta, cand[sgn_i * N_CAND + j], lo, hi, h, sgn, 4)
            if math.isnan(f):
                return np.nan, np.nan
            cand[sgn_i * N_CAND + j] = t
            if sgn > 0:
                fmax = max(fmax, f)
            else:
                fmin = min(fmin, f)
    for t in (lo, hi):
        f, _, _ = guide_offset(p, beta, t)
        fmax = max(fmax, f)
        fmin = min(fmin, f)
    return fmax, fmin


@nb.njit(cache=True)
def _trial(p, beta, lo, hi, h, cand, n_grid, warm):
    if warm:
        return _extremes_warm(p, beta, lo, hi, h, cand)
    return _extremes_full(p, beta, lo, hi, n_grid, 8, cand)


@nb.njit(cache=True)
def _total(fmax, fmin):
    return (max(fmax, 0.0) + max(-fmin, 0.0)) * 1e3


@nb.njit(cache=True)
def _optimise_one(p, lo, hi, blo, bhi, n_beta, xtol, n_grid, warm):
    cand = np.empty(2 * N_CAND)
    best = np.inf
    ib = -1
    step = (bhi - blo) / (n_beta - 1)
    for k in range(n_beta):
        fmax, fmin = _extremes_full(p, blo + step * k, lo, hi, n_grid, 8, cand)
        if not math.isnan(fmax):
            tot = _total(fmax, fmin)
            if tot < best:
                best = tot
                ib = k
    if ib < 0:
        return np.nan, np.nan, np.nan
    a = blo + step * max(ib - 1, 0)
    b = blo + step * min(ib + 1, n_beta - 1)
    h = (hi - lo) / (n_grid - 1)
    c = b - _INVPHI * (b - a)
    d = a + _INVPHI * (b - a)
    fmax, fmin = _extremes_full(p, c, lo, hi, n_grid, 8, cand)
    fc = _total(fmax, fmin)
    fmax, fmin = _trial(p, d, lo, hi, h, cand, n_grid, warm)
    fd = _total(fmax, fmin)
    while abs(b - a) >= xtol:
        if fc < fd:
            b = d
            d = c
            fd = fc
            c = b - _INVPHI * (b - a)
            fmax, fmin = _trial(p, c, lo, hi, h, cand, n_grid, warm)
            fc = _total(fmax, fmin)
        else:
            a = c
            c = d
            fc = fd
            d = a + _INVPHI * (b - a)
            fmax, fmin = _trial(p, d, lo, hi, h, cand, n_grid, warm)
            fd = _total(fmax, fmin)
    x = 0.5 * (a + b)
    # the reported figures come from a full (cold) evaluation at beta*
    fmax, fmin = _extremes_full(p, x, lo, hi, n_grid, 8, cand)
    return x, max(fmax, 0.0) * 1e3, max(-fmin, 0.0) * 1e3


@nb.njit(cache=True, parallel=True)
def optimise_beta_batch(P, lo, hi, blo, bhi, n_beta, xtol, n_grid, warm=True):
    """beta*, Delta+, Delta- (um) per machine; rows of P follow FIELDS.

    warm=False repeats the numpy reference's search step for step (same numbers); warm=True
    re-polishes the previous extremes at each golden trial (about 2x faster; on machines whose
    SumDelta(beta) has several nearly equal minima it may settle in another basin)."""
    n = P.shape[0]
    out = np.empty((n, 3))
    for i in nb.prange(n):
        if math.isnan(lo[i]) or math.isnan(hi[i]):
            out[i, 0] = out[i, 1] = out[i, 2] = np.nan
            continue
        b, pl, mi = _optimise_one(P[i], lo[i], hi[i], blo, bhi, n_beta, xtol, n_grid, warm)
        out[i, 0] = b
        out[i, 1] = pl
        out[i, 2] = mi
    return out


@nb.njit(cache=True, parallel=True)
def deviation_batch(P, beta, lo, hi, n_grid):
    """Delta+, Delta- (um) per machine at its beta."""
    n = P.shape[0]
    out = np.empty((n, 2))
    for i in nb.prange(n):
        cand = np.empty(2 * N_CAND)
        fmax, fmin = _extremes_full(P[i], beta[i], lo[i], hi[i], n_grid, 8, cand)
        out[i, 0] = max(fmax, 0.0) * 1e3
        out[i, 1] = max(-fmin, 0.0) * 1e3
        if math.isnan(fmax):
            out[i, 0] = out[i, 1] = np.nan
    return out


def pack(c: dict) -> np.ndarray:
    """Parameter columns (n, 1) to the kernel's (n, len(FIELDS)) matrix."""
    n = next(iter(c.values())).shape[0]
    return np.ascontiguousarray(np.column_stack(
        [np.broadcast_to(np.asarray(c[f], float).reshape(-1, 1), (n, 1))[:, 0] for f in FIELDS]))
