"""The presser foot's own analysis: the spring's identifiability (the follow threshold, the
holding acceleration, the family of springs the contact cycle cannot tell apart;
docs/presser_foot.md)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.presser_foot import model as PF


def follow_threshold_m_s2(params: PF.PresserFoot, step_deg: float = 0.01) -> float:
    """The least holding acceleration (F + m g) / m (m/s^2, F = the spring force on the
    material) for which the foot rides on the seat all the way down to the material, at the
    machine's omega_n / omega: max over the seat's path above the material of
    y'' + 2 zeta nu y' - nu^2 (y_m - y), times omega^2, and at least 0 (the foot must press on
    the material to stay there). Above it the cycle is the kinematic one
    (loss and regain where the seat passes the material) whatever the spring, mass and preload."""
    if P.batch_size(params) is not None:
        raise ParameterError("params", "must be one machine, not a batch", P.batch_size(params))
    nu, z = float(params.nu), float(params.damping_ratio)
    ym = float(params.material_mm)

    def need(phi):
        y, d1, d2 = PF.slider(phi, params.crank_mm, params.rod_mm, params.offset_mm)
        return np.where(y <= ym, d2 + 2 * z * nu * d1 - nu * nu * (ym - y), -np.inf)

    phi = np.radians(np.arange(0.0, 360.0, step_deg))
    v = need(phi)
    i = int(np.argmax(v))
    lo, hi = phi[i] - np.radians(step_deg), phi[i] + np.radians(step_deg)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        c, d = hi - g * (hi - lo), lo + g * (hi - lo)
        if need(c) > need(d):
            hi = d
        else:
            lo = c
    best = max(float(need(0.5 * (lo + hi))), float(v[i]))
    # and the foot must press on the material (F + m g >= 0) to stay there
    return max(best * float(params.speed_rad_s) ** 2 / 1e3, 0.0)


def holding_m_s2(params: PF.PresserFoot):
    """(F + m g) / m of the machine(s), m/s^2."""
    return (np.asarray(params.preload_n) + np.asarray(params.mass_kg) * PF.GRAVITY_M_S2) \
        / np.asarray(params.mass_kg)


def scaled_family(params: PF.PresserFoot, factors) -> PF.PresserFoot:
    """Machines with mass, spring rate and preload all times each factor: one point of the
    family the contact cycle cannot tell apart (k/m and (F + m g)/m unchanged)."""
    f = np.asarray(factors, float)
    return dataclasses.replace(params, mass_kg=params.mass_kg * f,
                               stiffness_n_per_mm=params.stiffness_n_per_mm * f,
                               preload_n=params.preload_n * f)
