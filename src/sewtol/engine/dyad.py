"""RRR dyad: the joint J of two links hinged to two known moving points.

|J - P1| = r1, |J - P2| = r2, and J lies on the side `branch` of the directed line P1 -> P2:
branch = +1 puts J on the left (cross(P2 - P1, J - P1) > 0), -1 on the right. The transfer
functions follow from differentiating the two distance constraints, a 2x2 linear system whose
determinant cross(J - P1, J - P2) vanishes only at a dead point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.engine.motion import Motion


@dataclass(frozen=True)
class Closure:
    """How well a dyad closes: miss_mm = 0 where it assembles, else the gap (mm) to closing.

    transmission_deg is the angle between the dyad's two links folded into [0, 90]: 0 is a
    dead point, where the joint can pass to the other assembly (a branch flip).
    """

    miss_mm: np.ndarray
    transmission_deg: np.ndarray | None = None

    @property
    def ok(self) -> np.ndarray:
        return self.miss_mm == 0.0


def _solve2(u1, u2, b1, b2):
    """Solve Re(conj(u1) z) = b1, Re(conj(u2) z) = b2 for the complex z."""
    a1, c1 = u1.real, u1.imag
    a2, c2 = u2.real, u2.imag
    det = a1 * c2 - c1 * a2
    x = (b1 * c2 - c1 * b2) / det
    y = (a1 * b2 - b1 * a2) / det
    return x + 1j * y


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def joint(p1, r1, p2, r2, branch):
    """The joint J (complex) of the dyad on the points p1, p2 (complex) and the miss (mm):
    rrr's position without its transfer functions (NaN where it cannot close)."""
    r1 = np.asarray(r1, float)
    r2 = np.asarray(r2, float)
    d = p2 - p1
    dist = np.abs(d)
    miss = np.maximum(np.maximum(dist - (r1 + r2), np.abs(r1 - r2) - dist), 0.0)
    # coincident centres (closer than 1e-12 mm): no joint is defined (none, or a circle of them)
    apart = dist > 1e-12
    miss = np.where(apart, miss, np.inf)
    dist = np.where(apart, dist, np.nan)
    a = (r1 * r1 - r2 * r2 + dist * dist) / (2.0 * dist)
    h2 = r1 * r1 - a * a
    # rounding can leave h2 a hair below zero at an exact dead point; that point still closes
    h = np.sqrt(np.where(miss > 0.0, np.nan, np.maximum(h2, 0.0)))
    unit = d / dist
    return p1 + unit * (a + 1j * np.asarray(branch, float) * h), miss


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rrr(p1: Motion, r1, p2: Motion, r2, branch) -> tuple[Motion, Closure]:
    """Joint J of the dyad P1-J-P2. Where it cannot close J is NaN and Closure says by how much."""
    j, miss = joint(p1.p, r1, p2.p, r2, branch)
    r1 = np.asarray(r1, float)
    r2 = np.asarray(r2, float)
    u1 = j - p1.p
    u2 = j - p2.p
    dj = _solve2(u1, u2, (u1.conjugate() * p1.dp).real, (u2.conjugate() * p2.dp).real)
    w1 = dj - p1.dp
    w2 = dj - p2.dp
    ddj = _solve2(
        u1, u2,
        (u1.conjugate() * p1.ddp).real - (w1.conjugate() * w1).real,
        (u2.conjugate() * p2.ddp).real - (w2.conjugate() * w2).real,
    )
    sin_gamma = np.abs((u1.conjugate() * u2).imag) / (r1 * r2)
    transmission = np.degrees(np.arcsin(np.minimum(sin_gamma, 1.0)))
    return Motion(j, dj, ddj), Closure(np.broadcast_to(miss, j.shape), transmission)
