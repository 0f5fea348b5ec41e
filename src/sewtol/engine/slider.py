"""Groups with a prismatic pair.

RPR: a body pivoted at P carries a straight slot at perpendicular distance `offset` from P; a
block pivoted at Y slides in it. The body's angle f satisfies Y = P + offset e^{i(f+90)} + l e^{if},
l = sqrt(|PY|^2 - offset^2) (the block on the positive side of the slot's foot).

RRP: a joint J at distance r from a moving point P1 slides on a fixed line through G with
direction angle alpha; `branch` = +1 takes the intersection further along the line's direction.
"""

from __future__ import annotations

import numpy as np

from sewtol.engine.dyad import Closure
from sewtol.engine.motion import Angle, Motion, direction


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rpr(pivot: Motion, block: Motion, offset) -> tuple[Angle, Closure]:
    """Angle of the slotted body (radians) and whether the block can reach the slot."""
    offset = np.asarray(offset, float)
    v = block.p - pivot.p
    dv = block.dp - pivot.dp
    ddv = block.ddp - pivot.ddp
    q = np.abs(v)
    miss = np.maximum(np.abs(offset) - q, 0.0)
    l2 = np.where(miss > 0.0, np.nan, np.maximum(q * q - offset * offset, 0.0))
    ln = np.sqrt(l2)
    dq = (v.conjugate() * dv).real / q
    ddq = ((dv.conjugate() * dv).real + (v.conjugate() * ddv).real) / q - dq * dq / q
    # f = ang(v) - g with g = asin(offset/q); g' = -offset q'/(q l)
    g = np.arcsin(offset / q)
    dg = -offset * dq / (q * ln)
    ddg = -offset * (ddq / (q * ln) - dq * dq / (q * q * ln) - dq * dq / (ln**3))
    ang = direction(pivot, block)
    return Angle(ang.a - g, ang.da - dg, ang.dda - ddg), Closure(np.broadcast_to(miss, q.shape))


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rrp(p1: Motion, r, guide_x, guide_y, alpha_rad, branch) -> tuple[Motion, Closure]:
    """Joint J on the fixed line G + s e^{i alpha} with |J - P1| = r."""
    r = np.asarray(r, float)
    u = np.exp(1j * np.asarray(alpha_rad, float))
    g = np.asarray(guide_x, float) + 1j * np.asarray(guide_y, float)
    w = p1.p - g
    along = (u.conjugate() * w).real
    across = (u.conjugate() * w).imag
    disc = r * r - across * across
    miss = np.maximum(np.abs(across) - r, 0.0)
    root = np.sqrt(np.where(miss > 0.0, np.nan, np.maximum(disc, 0.0)))
    s = along + np.asarray(branch, float) * root
    j = g + s * u
    # constraint |J - P1|^2 = r^2 with J' = s' u: (J-P1).(s'u - P1') = 0
    e = j - p1.p
    eu = (e.conjugate() * u).real
    ds = (e.conjugate() * p1.dp).real / eu
    w1 = ds * u - p1.dp
    dds = ((e.conjugate() * p1.ddp).real - (w1.conjugate() * w1).real) / eu
    return Motion(j, ds * u, dds * u), Closure(np.broadcast_to(miss, j.shape))
