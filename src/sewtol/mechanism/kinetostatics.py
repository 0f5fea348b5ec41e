"""Quasi-static joint forces of a file mechanism (kinetostatics at a uniform crank speed), found
through its pair parameters: by virtual work, the force a revolute pair with a clearance
carries is the generalised force of its journal offset, Q_j = sum_k (dp_k/dr_j)^T P_k = -N
(P_k the loads: applied forces, weights, inertia forces -m a), with dp_k/dr_j by central
differences of the real model; the loaded contact direction is Q_j / |Q_j|. Rigid links, point
loads at points the file draws, no rotary inertia, friction or impact, first order in the
clearances (docs/clearances.md, "Loaded mode"). The M6 needle's Newton-Euler solution
(`sewtol.mechanisms.m6_needle.model.reactions`) is the independent check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError, real
from sewtol.mechanism.clearance import offset_names

G_M_S2 = 9.81  # gravity along -y of the file's frame (every built-in has y up)
H_MM = 1e-4    # finite-difference step of the offsets (as the clearance Jacobian's)
MM = 1e-3


def _number(field: str, v, rule: str, ok) -> float:
    if not (real(v, finite=True) and ok(v)):
        raise ParameterError(field, rule, v)
    return float(v)


@dataclass(frozen=True)
class PointLoad:
    """A load at a point the file draws, on the body that holds the point as the model names
    it (`sewtol.mechanism.clearance`): a crank pin or a frame point is the next link's journal,
    a dyad's joint its second link's.

    ``mass_kg``: a point mass there (its weight and its inertia force -m a at the crank speed).
    ``force_N`` along ``direction_deg`` (from +x): a constant force, or with ``against_motion``
    a force of that size that opposes the point's motion along the direction (its sign flips
    where the point's velocity along it does: a needle's penetration and friction)."""

    point: str
    mass_kg: float = 0.0
    force_N: float = 0.0
    direction_deg: float = 0.0
    against_motion: bool = False
    doc: str = ""

    def __post_init__(self):
        if not isinstance(self.point, str) or not self.point:
            raise ParameterError("point", "must name a point of the mechanism", self.point)
        _number("mass_kg", self.mass_kg, "must be a finite mass >= 0 (kg)", lambda v: v >= 0)
        _number("force_N", self.force_N, "must be a finite force (N)", lambda v: True)
        _number("direction_deg", self.direction_deg, "must be a finite angle (deg)",
                lambda v: True)
        if not isinstance(self.against_motion, bool):
            raise ParameterError("against_motion", "must be true or false", self.against_motion)


def speed_rad_s(mech, rpm: float | None) -> float:
    """The crank's angular speed (rad/s) from `rpm`, or the file's ``rpm`` when None."""
    rpm = mech.header.rpm if rpm is None else rpm
    if rpm is None:
        raise ParameterError("rpm", "the file states no rpm: give the crank speed", rpm)
    return _number("rpm", rpm, "must be a finite speed > 0 (rev/min)", lambda v: v > 0) \
        * 2.0 * np.pi / 60.0


def load_forces(state, loads, omega_rad_s: float) -> dict[str, np.ndarray]:
    """point -> the resultant load (N, complex x + i y, shape (m, angles)) of `loads` on the
    machines of `state` at the crank speed: applied forces, weights, inertia forces."""
    out = {}
    for ld in loads:
        if ld.point not in state.points:
            raise ParameterError("point", "must name a point of the mechanism: "
                                 + ", ".join(sorted(state.points)), ld.point)
        pt = state.points[ld.point]
        f = np.zeros(state.shape, complex)
        if ld.mass_kg:
            accel = pt.ddp * omega_rad_s ** 2 * MM
            f = f + ld.mass_kg * (-1j * G_M_S2 - accel)
        if ld.force_N:
            u = np.exp(1j * np.radians(ld.direction_deg))
            if ld.against_motion:
                along = (np.conjugate(u) * pt.dp).real  # the point's velocity along u (sign)
                f = f - ld.force_N * np.sign(along) * u
            else:
                f = f + ld.force_N * u
        out[ld.point] = out.get(ld.point, 0) + f
    return out


@dataclass(frozen=True)
class JointForces:
    """Quasi-static joint forces over the turn: ``force_N[j]`` the force (complex x + i y, N,
    shape (machines, angles)) with which the journal of revolute pair j presses on its bearing,
    at the crank speed ``rpm``; ``status`` per machine (a machine that cannot close, or passes a
    dead point, has NaN forces)."""

    q_deg: np.ndarray
    rpm: float
    force_N: dict
    status: np.ndarray

    def magnitudes(self):
        import pandas as pd

        m, k = next(iter(self.force_N.values())).shape
        f = pd.DataFrame({"machine": np.repeat(np.arange(m), k), "q_deg": np.tile(self.q_deg, m)})
        for j, v in self.force_N.items():
            f[f"{j}_N"] = np.abs(v).reshape(-1)
            f[f"{j}_direction_deg"] = np.degrees(np.angle(v)).reshape(-1)
        return f

    to_dataframe = magnitudes


def joint_forces(mech, values: dict | None, loads, rpm: float | None = None,
                 h_mm: float = H_MM) -> JointForces:
    """The force in every revolute pair with a clearance of `mech` (their journals centred),
    per machine of `values` and crank angle, under `loads` (PointLoad) at `rpm` (default the
    file's): Q_j = sum_k (dp_k/dr_j)^T P_k, see the module's docstring."""
    pairs = tuple(c for c in getattr(mech, "clearances", ()) if c.pair == "revolute")
    if not pairs:
        raise ParameterError("clearances", "the mechanism file declares no revolute "
                                           "[[clearances]]", getattr(mech, "name", mech))
    loads = tuple(loads)
    if not loads or not all(isinstance(ld, PointLoad) for ld in loads):
        raise ParameterError("loads", "must be one or more PointLoad", loads)
    omega = speed_rad_s(mech, rpm)
    values = dict(values or {})
    for c in pairs:  # the forces are taken with the journals centred
        for name in offset_names(c.joint):
            values.pop(name, None)
    state = mech.state(values)
    status, _ = mech.status_of(state)
    forces = load_forces(state, loads, omega)
    m = state.shape[0]
    names = [n for c in pairs for n in offset_names(c.joint)]
    cols, _ = mech.columns(values)
    big = {k: np.repeat(np.asarray(v, float)[:, 0][None, :], 2 * len(names), axis=0).reshape(-1)
           for k, v in cols.items() if k in mech.parameter_names}
    for k, name in enumerate(names):
        col = np.zeros(2 * len(names) * m)
        col[2 * k * m:(2 * k + 1) * m] = h_mm
        col[(2 * k + 1) * m:(2 * k + 2) * m] = -h_mm
        big[name] = col
    moved = mech.state(big)
    out = {}
    for i, c in enumerate(pairs):
        q = np.zeros(state.shape)
        gen = []
        for axis in (0, 1):
            k = 2 * i + axis
            g = np.zeros(state.shape)
            for point, f in forces.items():
                p = moved.points[point].p.reshape(len(names), 2, m, -1)
                dp = (p[k, 0] - p[k, 1]) / (2.0 * h_mm)
                g = g + (np.conjugate(dp) * f).real
            gen.append(g)
        q = gen[0] + 1j * gen[1]
        q[status != "ok"] = np.nan
        out[c.joint] = q
    return JointForces(np.degrees(mech.angles_rad()), float(omega * 60.0 / (2.0 * np.pi)), out,
                       status)
