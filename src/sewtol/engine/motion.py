"""Motion of a point or an angle together with its first and second transfer functions.

Points are complex numbers (x + iy, mm). Every array broadcasts over (samples, angles); the
derivatives are taken with respect to the driving angle q (radians) of the chain, so a state is
(value, d/dq, d2/dq2). Positions, transfer functions and everything built on them are float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _arr(x, dtype=float):
    return np.asarray(x, dtype=dtype)


@dataclass(frozen=True)
class Motion:
    """A point: position p, first transfer function dp = dp/dq, second ddp = d2p/dq2 (mm, mm/rad...)."""

    p: np.ndarray
    dp: np.ndarray
    ddp: np.ndarray

    @property
    def x(self) -> np.ndarray:
        return self.p.real

    @property
    def y(self) -> np.ndarray:
        return self.p.imag


@dataclass(frozen=True)
class Angle:
    """An angle (radians) with its first and second transfer functions."""

    a: np.ndarray
    da: np.ndarray
    dda: np.ndarray

    def __add__(self, offset_rad) -> Angle:
        return Angle(self.a + offset_rad, self.da, self.dda)

    def __sub__(self, offset_rad) -> Angle:
        return Angle(self.a - offset_rad, self.da, self.dda)


def fixed(x, y) -> Motion:
    """A frame point."""
    p = _arr(x) + 1j * _arr(y)
    z = np.zeros_like(p)
    return Motion(p, z, z)


def driving_angle(q) -> Angle:
    """The chain's input angle itself: dq/dq = 1, d2q/dq2 = 0."""
    q = _arr(q)
    return Angle(q, np.ones_like(q), np.zeros_like(q))


def direction(start: Motion, end: Motion) -> Angle:
    """Angle of the vector start->end and its transfer functions (the link need not be rigid)."""
    v = end.p - start.p
    dv = end.dp - start.dp
    ddv = end.ddp - start.ddp
    r2 = (v.conjugate() * v).real
    cross_v_dv = (v.conjugate() * dv).imag
    dot_v_dv = (v.conjugate() * dv).real
    da = cross_v_dv / r2
    dda = (v.conjugate() * ddv).imag / r2 - 2.0 * cross_v_dv * dot_v_dv / (r2 * r2)
    return Angle(np.angle(v), da, dda)


def on_body(origin: Motion, angle: Angle, local) -> Motion:
    """Point fixed on a body that carries `origin` and turns with `angle`.

    `local` is the point's complex coordinate in the body frame (mm): X = origin + local e^{i angle}.
    A rigid point on a link, a crank pin and a rocker arm are all this.
    """
    rot = np.exp(1j * angle.a) * local
    p = origin.p + rot
    dp = origin.dp + 1j * angle.da * rot
    ddp = origin.ddp + (1j * angle.dda - angle.da**2) * rot
    return Motion(p, dp, ddp)


def polar(center: Motion, radius, angle: Angle) -> Motion:
    """center + radius e^{i angle}: a crank, or an arm of given length at a given angle."""
    return on_body(center, angle, _arr(radius))
