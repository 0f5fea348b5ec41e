"""Crank (eccentric): the driving link of a chain, turning about a frame point."""

from __future__ import annotations

import numpy as np

from sewtol.engine.motion import Motion, driving_angle, fixed, polar


def crank(center_x, center_y, radius, q, phase_rad=0.0, sense: float = 1.0) -> Motion:
    """Crank pin at center + radius e^{i(sense q + phase)}; sense = -1 turns the other way.

    Derivatives are with respect to q, so the pin's first transfer function is its velocity per
    unit crank speed (mm/rad).
    """
    ang = driving_angle(q)
    ang = type(ang)(sense * ang.a + phase_rad, sense * ang.da, sense * ang.dda)
    return polar(fixed(center_x, center_y), np.asarray(radius, float), ang)
