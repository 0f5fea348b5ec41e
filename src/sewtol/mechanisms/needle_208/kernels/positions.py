"""Needle-drive positions over (machines x crank angles): a fused numba kernel and the plain
per-angle Python loop it is measured and tested against (benchmarks/throughput.py).

Both follow the engine's topology exactly (mechanisms/needle_208/model.py): crank F-L, dyad L-M-A,
arm B = A + AB e(ang(A->M) + beta_sense beta), dyad B-C-D, E = B + BE e(ang(B->C) + CBE). The
arm and the ternary rod are rotations by constant complex factors and the crank angles are
shared by all machines, so no transcendental function is called per position.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

FIELDS = ("LF", "LM", "AM", "AB", "BC", "BE", "CD", "CBE", "beta", "Ax", "Ay", "Dx", "Dy",
          "branch_M", "branch_C", "beta_sense")


def pack(params) -> np.ndarray:
    """(n, len(FIELDS)) matrix of a single machine or a batch."""
    cols = [np.atleast_1d(np.asarray(getattr(params, f), float)) for f in FIELDS]
    n = max(c.size for c in cols)
    return np.ascontiguousarray(np.column_stack([np.broadcast_to(c, (n,)) for c in cols]))


def _loop_one(p, phi):
    """E for one machine at one crank angle, in plain Python (the reference)."""
    LF, LM, AM, AB, BC, BE, CD, CBE, beta, ax, ay, dx, dy, bm, bc, bs = p
    lx, ly = LF * math.cos(phi), LF * math.sin(phi)
    # dyad L-M-A
    ux, uy = ax - lx, ay - ly
    d = math.hypot(ux, uy)
    a = (LM * LM - AM * AM + d * d) / (2 * d)
    h2 = LM * LM - a * a
    if h2 < 0:
        return math.nan, math.nan
    h = math.sqrt(h2)
    mx = lx + (a * ux - bm * h * uy) / d
    my = ly + (a * uy + bm * h * ux) / d
    # arm B at beta from AM
    ang = math.atan2(my - ay, mx - ax) + bs * math.radians(beta)
    bx, by = ax + AB * math.cos(ang), ay + AB * math.sin(ang)
    # dyad B-C-D
    ux, uy = dx - bx, dy - by
    d = math.hypot(ux, uy)
    a = (BC * BC - CD * CD + d * d) / (2 * d)
    h2 = BC * BC - a * a
    if h2 < 0:
        return math.nan, math.nan
    h = math.sqrt(h2)
    cx = bx + (a * ux - bc * h * uy) / d
    cy = by + (a * uy + bc * h * ux) / d
    ang = math.atan2(cy - by, cx - bx) + math.radians(CBE)
    return bx + BE * math.cos(ang), by + BE * math.sin(ang)


def positions_loop(P: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """E (n, m, 2) by a plain per-angle Python loop."""
    out = np.empty((P.shape[0], phi.size, 2))
    for i in range(P.shape[0]):
        p = tuple(float(v) for v in P[i])
        for k, f in enumerate(phi):
            out[i, k] = _loop_one(p, float(f))
    return out


@nb.njit(cache=True, error_model="numpy")
def _row(p, cphi, sphi, out):
    """E of one machine at every crank angle into out (m, 2)."""
    ox = np.empty(cphi.size)
    oy = np.empty(cphi.size)
    _row_soa(p, cphi, sphi, ox, oy)
    for k in range(cphi.size):
        out[k, 0] = ox[k]
        out[k, 1] = oy[k]


@nb.njit(cache=True, error_model="numpy")
def _row_soa(p, cphi, sphi, ox, oy):
    """The fused chain over the crank angles into contiguous x and y arrays: branch-free, and
    with numpy's error model (no division-by-zero check; sqrt of a negative number is NaN, which
    marks a dyad that cannot close exactly as a branch would) LLVM vectorises it (vsqrtpd):
    about 4.8x the scalar loop with interleaved stores, bit-identical results."""
    LF, LM, AM, AB, BC, BE, CD = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    ax, ay, dx, dy, bm, bc = p[9], p[10], p[11], p[12], p[13], p[14]
    ra = p[15] * p[8] * math.pi / 180.0
    arm_c, arm_s = AB / AM * math.cos(ra), AB / AM * math.sin(ra)
    rc = p[7] * math.pi / 180.0
    rod_c, rod_s = BE / BC * math.cos(rc), BE / BC * math.sin(rc)
    k1 = LM * LM - AM * AM
    k2 = BC * BC - CD * CD
    lm2 = LM * LM
    bc2 = BC * BC
    for k in range(cphi.size):
        lx = LF * cphi[k]
        ly = LF * sphi[k]
        ux, uy = ax - lx, ay - ly
        d2 = ux * ux + uy * uy
        inv = 1.0 / d2
        a = 0.5 * (k1 + d2) * inv  # a / d
        h = math.sqrt(lm2 * inv - a * a)  # h / d; NaN where L-M-A cannot close
        mx = lx + a * ux - bm * h * uy
        my = ly + a * uy + bm * h * ux
        vx, vy = mx - ax, my - ay
        bx = ax + arm_c * vx - arm_s * vy
        by = ay + arm_s * vx + arm_c * vy
        ux, uy = dx - bx, dy - by
        d2 = ux * ux + uy * uy
        inv = 1.0 / d2
        a = 0.5 * (k2 + d2) * inv
        h = math.sqrt(bc2 * inv - a * a)  # NaN where B-C-D cannot close
        wx = a * ux - bc * h * uy  # C - B
        wy = a * uy + bc * h * ux
        ox[k] = bx + rod_c * wx - rod_s * wy
        oy[k] = by + rod_s * wx + rod_c * wy


@nb.njit(cache=True)
def positions_kernel_serial(P, phi):
    """As positions_kernel, on one thread (the per-core figure of the benchmark)."""
    out = np.empty((P.shape[0], phi.size, 2))
    # the crank angles are shared by every machine: their cosines and sines are taken once
    cphi, sphi = np.cos(phi), np.sin(phi)
    for i in range(P.shape[0]):
        _row(P[i], cphi, sphi, out[i])
    return out


@nb.njit(cache=True, parallel=True)
def positions_kernel(P, phi):
    """E (n, m, 2) for n machines at m crank angles, machines spread over threads."""
    out = np.empty((P.shape[0], phi.size, 2))
    cphi, sphi = np.cos(phi), np.sin(phi)
    for i in nb.prange(P.shape[0]):
        _row(P[i], cphi, sphi, out[i])
    return out


def positions_chunked(P: np.ndarray, phi: np.ndarray, chunk_machines: int = 256):
    """Yield (start, E) chunks so memory stays bounded for any number of positions."""
    for s in range(0, P.shape[0], chunk_machines):
        yield s, positions_kernel(P[s:s + chunk_machines], phi)
