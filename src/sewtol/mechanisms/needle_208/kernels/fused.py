"""The needle point and the guide's deviation d as scalar numba functions, with analytic
d/dtheta and d2/dtheta2 (the second four-bar from the rocker angle in closed form): the same
mathematics as the engine's groups, nothing allocated. The exact optimiser and the fixed-beta
figures (kernels/window.py) evaluate d through them, on a machine's row of the matrix
`kernels.pack` lays out. tests/test_kernels.py holds them to the numpy path.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

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
    nx, ny, off = guide_normal(p)
    return guide_offset_on(p, beta_deg, th, nx, ny, off)


@nb.njit(cache=True, fastmath=False)
def guide_offset_on(p, beta_deg, th, nx, ny, off):
    """guide_offset with the guide's normal and offset given (guide_normal(p), taken once per
    machine: two of the nine sines and cosines of a call; the same d bit for bit)."""
    Ex, Ey, E1x, E1y, E2x, E2y = needle_point(p, beta_deg, th)
    if math.isnan(Ex):
        return np.nan, np.nan, np.nan
    return nx * Ex + ny * Ey - off, nx * E1x + ny * E1y, nx * E2x + ny * E2y

