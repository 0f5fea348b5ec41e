"""Embroidery presser foot with an elastic link (Vitebsk semi-automatic machine).

A crank-slider drives the seat D along a straight line (y: the seat's distance from the crank
axis, downwards: y(phi) = sqrt(L^2 - (r sin phi)^2) + r cos phi + a, lowest at phi = 0); the
foot's lug rests on the seat, pushed down by a preloaded spring and gravity, and moves freely
as a damped oscillator about its balance x_eq when contact is lost (the seat accelerating down
faster than the foot can follow, or the foot's sole stopping on the material). Contact returns
by a plastic impact. Separation = seat minus foot (mm). Angles reported are shaft angles
theta = phi + phase_deg (phase_deg fitted). Only k/m, (F + m g)/m and the geometry enter the
motion. The model and every assumption: this folder's README.md (docs/presser_foot.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.mechanism.clearance import journals_off_centre
from sewtol.mechanisms import params as P
from sewtol.mechanisms.presser_foot import kernel as K

GRAVITY_M_S2 = 9.81
STATUS = ("ok", "never_lost", "never_held", "not_regained", "cannot_assemble")
# The source's table (wire diameter d; crank angle where contact is lost and regained; largest
# separation). in_trend = False: the two rows the source's own trend marks as misprints.
SOURCE_TABLE = (
    # d_mm, loss_deg, regain_deg, separation_mm, in_trend
    (0.32, 278.0, 353.0, 6.010, True),
    (0.41, 278.0, 358.0, 6.190, True),
    (0.47, 278.0, 358.0, 6.231, True),
    (0.52, 278.0, 358.0, 6.244, True),
    (0.56, 278.0, 358.0, 6.251, True),
    (0.59, 278.0, 358.0, 6.254, True),
    (0.63, 278.0, 358.0, 6.256, True),
    (0.65, 278.0, 358.0, 6.257, True),
    (0.68, 278.0, 358.0, 6.306, False),
    (0.71, 278.0, 358.0, 6.259, True),   # first of "0.71 ... 0.88 (10 springs), 6.259 ... 6.262"
    (0.87, 278.0, 358.0, 6.050, False),
    (0.88, 278.0, 358.0, 6.262, True),   # last of the ten
)
# Assumed spring (not published): round wire of shear modulus G, mean coil diameter D, n
# active coils: k = G d^4 / (8 D^3 n). The table's springs differ only in d.
SPRING_SHEAR_MODULUS_N_MM2 = 78_500.0
SPRING_COIL_DIAMETER_MM = 6.0
SPRING_ACTIVE_COILS = 10.0


def spring_rate_n_per_mm(wire_mm, coil_mm=SPRING_COIL_DIAMETER_MM, coils=SPRING_ACTIVE_COILS,
                         shear_n_mm2=SPRING_SHEAR_MODULUS_N_MM2):
    """k = G d^4 / (8 D^3 n) of a helical spring of round wire (N/mm)."""
    d = np.asarray(wire_mm, float)
    return shear_n_mm2 * d**4 / (8.0 * coil_mm**3 * coils)


@dataclass(frozen=True)
class PresserFoot:
    """One machine (floats) or a batch (equal-length arrays). Lengths mm, angles deg."""

    crank_mm: float = 17.5
    rod_mm: float = 42.0
    offset_mm: float = 8.0
    speed_rad_s: float = 100.0
    phase_deg: float = 317.75      # fitted: shaft angle of the seat's lowest point (phi = 0)
    material_mm: float = 61.2804   # fitted: seat coordinate y where the sole meets the material
    mass_kg: float = 0.05          # assumed (not identifiable)
    stiffness_n_per_mm: float = 0.4466   # assumed spring: d = 0.56 mm (spring_rate_n_per_mm)
    preload_n: float = 8.0         # assumed: spring force with the foot on the material
    damping_ratio: float = 0.012   # source

    def __post_init__(self):
        P.freeze(self)
        for name in ("crank_mm", "rod_mm"):
            P.positive(name, getattr(self, name))
        P.finite("offset_mm", self.offset_mm)
        for name, rule in (("speed_rad_s", "must be a positive speed in rad/s"),
                           ("mass_kg", "must be a positive mass in kg"),
                           ("stiffness_n_per_mm", "must be a positive stiffness in N/mm")):
            v = np.asarray(getattr(self, name), float)
            if not np.all(np.isfinite(v)) or np.any(v <= 0.0):
                raise ParameterError(name, rule, P.show(getattr(self, name)))
        for name in ("phase_deg", "material_mm", "preload_n"):
            P.finite(name, getattr(self, name))
        z = np.asarray(self.damping_ratio, float)
        if not np.all(np.isfinite(z)) or np.any((z < 0.0) | (z >= 1.0)):
            raise ParameterError("damping_ratio", "must be in [0, 1) (underdamped)",
                                 P.show(self.damping_ratio))
        if np.any(np.asarray(self.crank_mm) >= np.asarray(self.rod_mm)):
            raise ParameterError("crank_mm", "must be shorter than rod_mm (the crank must turn)",
                                 P.show(self.crank_mm))

    def override(self, **changes) -> PresserFoot:
        return P.override(self, changes)

    # the normalised oscillator the kernel uses
    @property
    def nu(self):
        """Natural frequency over crank speed, omega_n / omega."""
        omega_n = np.sqrt(np.asarray(self.stiffness_n_per_mm) * 1e3 / np.asarray(self.mass_kg))
        return omega_n / np.asarray(self.speed_rad_s)

    @property
    def x_eq_mm(self):
        """Where spring and weight balance (seat coordinate y, mm): y_m + (F + m g) / k."""
        return np.asarray(self.material_mm) + (
            np.asarray(self.preload_n) + np.asarray(self.mass_kg) * GRAVITY_M_S2
        ) / np.asarray(self.stiffness_n_per_mm)


def slider(phi_rad, crank_mm, rod_mm, offset_mm):
    """Seat position y (mm) and its first and second derivatives d/dphi (mm/rad, mm/rad^2)."""
    phi = np.asarray(phi_rad, float)
    r, L, a = (np.asarray(v, float) for v in (crank_mm, rod_mm, offset_mm))
    s, c = np.sin(phi), np.cos(phi)
    S = np.sqrt(L * L - (r * s) ** 2)
    y = S + r * c + a
    d1 = -r * s - r * r * s * c / S
    d2 = -r * c - r * r * (c * c - s * s) / S - r**4 * s * s * c * c / S**3
    return y, d1, d2


@dataclass(frozen=True)
class ContactResult:
    """Per machine: shaft angles of loss (in [0, 360)) and regain (loss + lost interval, so it
    reads above 360 when contact returns in the next turn) (deg), lost interval (deg), largest
    separation (mm) of the turn's principal lost interval (the one with the largest
    separation), bounces, whether the foot rested on the material, whether contact was lost by
    the force (the foot flew), status, and how many lost intervals the turn has."""

    loss_deg: np.ndarray
    regain_deg: np.ndarray
    lost_deg: np.ndarray
    separation_mm: np.ndarray
    impacts: np.ndarray
    landed: np.ndarray
    lost_by_force: np.ndarray
    status: np.ndarray
    intervals: np.ndarray

    def to_dataframe(self) -> pd.DataFrame:
        return pd.DataFrame({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})

    def counts(self) -> dict[str, int]:
        """Machines per status; they add up to the number of machines."""
        return {s: int(np.sum(self.status == s)) for s in STATUS}


def evaluate(params: PresserFoot) -> ContactResult:
    """The contact cycle of every machine of `params` (a single machine gives arrays of 1)."""
    n = P.batch_size(params) or 1
    # the kernel's arguments in its order (nu and x_eq_mm are properties), then the phase
    names = ("crank_mm", "rod_mm", "offset_mm", "nu", "damping_ratio", "x_eq_mm", "material_mm")
    cols = {f: np.broadcast_to(np.asarray(getattr(params, f), float), (n,)).astype(float)
            for f in (*names, "phase_deg")}
    out = K.batch(*(cols[f] for f in names))
    status = np.array(STATUS, dtype=object)[out[:, 6].astype(int)]
    phase = cols["phase_deg"]
    loss = (out[:, 0] + phase) % 360.0
    return ContactResult(
        loss_deg=loss,
        # loss + lost interval: continuous across 360 (a regain in the next turn reads > 360)
        regain_deg=loss + out[:, 2],
        lost_deg=out[:, 2],
        separation_mm=out[:, 3],
        impacts=out[:, 4].astype(int),
        landed=out[:, 5].astype(bool),
        lost_by_force=out[:, 7].astype(bool),
        status=status.astype(str),
        intervals=out[:, 8].astype(int),
    )


def foot_path(params: PresserFoot, step_deg: float = 0.5) -> pd.DataFrame:
    """One machine over one shaft turn from its loss angle: seat and foot positions (mm) and
    whether they are in contact, by replaying the events of `evaluate` (the foot rides on the
    seat, flies as the exact free vibration, or rests on the material)."""
    if P.batch_size(params) is not None:
        raise ParameterError("params", "must be one machine, not a batch", P.batch_size(params))
    if not (0.001 <= step_deg <= 90.0):
        raise ParameterError("step_deg", "must be in [0.001, 90]", step_deg)
    res = evaluate(params)
    r, L, a = params.crank_mm, params.rod_mm, params.offset_mm
    phase = float(params.phase_deg)
    theta = np.arange(0.0, 360.0, step_deg)
    phi = np.radians(theta - phase)
    y = slider(phi, r, L, a)[0]
    foot = y.copy()
    contact = np.ones(theta.shape, bool)
    if res.status[0] == "ok":
        lo = np.radians(res.loss_deg[0] - phase)
        lost = np.radians(res.lost_deg[0])
        d = np.mod(phi - lo, 2 * np.pi)
        inside = d < lost
        contact[inside] = False
        # replay: flight from the loss with the seat's state, stops on the material
        yl, vl, _ = slider(lo, r, L, a)
        nu, z, xe, ym = float(params.nu), float(params.damping_ratio), float(params.x_eq_mm), \
            float(params.material_mm)
        landed = yl >= ym
        for i in sorted(np.nonzero(inside)[0], key=lambda j: d[j]):
            x = ym if landed else K.free(d[i], yl, vl, nu, z, xe)[0]
            landed = landed or x >= ym
            foot[i] = min(x, ym)
        if res.impacts[0] > 0 or res.intervals[0] > 1:
            raise ParameterError("params", "foot_path replays only cycles of one lost interval "
                                 "without bounces", (int(res.intervals[0]),
                                                     int(res.impacts[0])))
    return pd.DataFrame({"shaft_deg": theta, "seat_mm": y, "foot_mm": foot,
                         "contact": contact})


def source_springs(nominal: PresserFoot | None = None) -> PresserFoot:
    """A batch of one machine per row of SOURCE_TABLE: the nominal machine with the row's spring
    (rate from the wire diameter by spring_rate_n_per_mm; same coil, coils, mass and pressing
    force on the material, as assumed in docs/presser_foot.md)."""
    nominal = nominal or PresserFoot()
    d = np.array([row[0] for row in SOURCE_TABLE])
    return P.with_deviations(nominal, {
        "stiffness_n_per_mm": spring_rate_n_per_mm(d) - float(nominal.stiffness_n_per_mm)})


@dataclass(frozen=True)
class SourceFit:
    """The fit of phase_deg and material_mm to the source's table, and its residuals per row
    (model minus source: angles deg, separation mm)."""

    phase_deg: float
    material_mm: float
    rows: pd.DataFrame
    rms_angle_deg: float
    rms_separation_mm: float

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows.copy()


ANGLE_WEIGHT_DEG = 1.0        # the table prints whole degrees
SEPARATION_WEIGHT_MM = 0.01   # and separations to 0.001 mm; 0.01 mm ~ their scatter


def _wrap180(x):
    return (np.asarray(x, float) + 180.0) % 360.0 - 180.0


def fit_source(nominal: PresserFoot | None = None) -> SourceFit:
    """Least squares over the in-trend rows of SOURCE_TABLE (angles weighted 1/ANGLE_WEIGHT_DEG,
    separations 1/SEPARATION_WEIGHT_MM) for the phase and the material level; the spring, mass
    and preload stay as given (they do not enter while the foot follows the seat down to the
    material, which every row's spring does: docs/presser_foot.md)."""
    from scipy.optimize import minimize

    nominal = nominal or PresserFoot()
    table = np.array([row[:4] for row in SOURCE_TABLE], float)
    trend = np.array([row[4] for row in SOURCE_TABLE])
    springs = source_springs(nominal)

    def model(material_mm):
        return evaluate(dataclasses.replace(springs, phase_deg=0.0, material_mm=material_mm))

    def cost(x):
        res = model(x[0])
        if np.any(res.status != "ok"):
            return 1e12
        dl = _wrap180(table[:, 1] - res.loss_deg)[trend]
        dr = _wrap180(table[:, 2] - res.regain_deg)[trend]
        phase = float(np.mean(np.r_[dl, dr]))   # the optimal phase for this material level
        ds = (table[:, 3] - res.separation_mm)[trend]
        return float(np.sum(((dl - phase) / ANGLE_WEIGHT_DEG) ** 2)
                     + np.sum(((dr - phase) / ANGLE_WEIGHT_DEG) ** 2)
                     + np.sum((ds / SEPARATION_WEIGHT_MM) ** 2))

    y_top = float(np.asarray(nominal.crank_mm) + nominal.rod_mm + nominal.offset_mm)
    grid = np.linspace(y_top - 9.0, y_top - 3.0, 61)
    x0 = grid[int(np.argmin([cost([g]) for g in grid]))]
    opt = minimize(cost, [x0], method="Nelder-Mead",
                   options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 2000})
    material = float(opt.x[0])
    res = model(material)
    dl = _wrap180(table[:, 1] - res.loss_deg)
    dr = _wrap180(table[:, 2] - res.regain_deg)
    phase = float(np.mean(np.r_[dl[trend], dr[trend]])) % 360.0
    fitted = evaluate(dataclasses.replace(springs, phase_deg=phase, material_mm=material))
    rows = pd.DataFrame({
        "wire_mm": table[:, 0], "in_trend": trend,
        "stiffness_n_per_mm": np.asarray(springs.stiffness_n_per_mm),
        "source_loss_deg": table[:, 1], "model_loss_deg": fitted.loss_deg,
        "loss_residual_deg": _wrap180(fitted.loss_deg - table[:, 1]),
        "source_regain_deg": table[:, 2], "model_regain_deg": fitted.regain_deg,
        "regain_residual_deg": _wrap180(fitted.regain_deg - table[:, 2]),
        "source_separation_mm": table[:, 3], "model_separation_mm": fitted.separation_mm,
        "separation_residual_mm": fitted.separation_mm - table[:, 3],
        "status": fitted.status,
    })
    t = rows[rows.in_trend]
    ang = np.r_[t.loss_residual_deg, t.regain_residual_deg]
    return SourceFit(phase, material, rows, float(np.sqrt(np.mean(ang**2))),
                     float(np.sqrt(np.mean(t.separation_residual_mm**2))))


# --- the spring's identifiability (docs/presser_foot.md) -----------------------------------

def follow_threshold_m_s2(params: PresserFoot, step_deg: float = 0.01) -> float:
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
        y, d1, d2 = slider(phi, params.crank_mm, params.rod_mm, params.offset_mm)
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


def holding_m_s2(params: PresserFoot):
    """(F + m g) / m of the machine(s), m/s^2."""
    return (np.asarray(params.preload_n) + np.asarray(params.mass_kg) * GRAVITY_M_S2) \
        / np.asarray(params.mass_kg)


# --- the "presser_contact" output kind of mechanism files (type = "custom") -----------------
# Each field names a parameter of the file (or is a number); measure picks the output: the
# cycle's four figures, then its modes as numbers (contact_status: the index in STATUS)
MEASURES = ("loss_deg", "regain_deg", "lost_deg", "separation_mm", "contact_status", "impacts",
            "intervals", "lost_by_force")
_REQUIRED = ("expr", None, None)
PRESSER_CONTACT_FIELDS = {
    # name: (kind, default, choices) in the registry's form (default None: required)
    "crank_mm": _REQUIRED, "rod_mm": _REQUIRED, "offset_mm": _REQUIRED,
    "speed_rad_s": _REQUIRED, "phase_deg": ("expr", 0.0, None), "material_mm": _REQUIRED,
    "mass_kg": _REQUIRED, "stiffness_n_per_mm": _REQUIRED, "preload_n": _REQUIRED,
    "damping_ratio": ("expr", 0.012, None), "measure": ("choice", "separation_mm", MEASURES),
}


def _machines(resolved: dict) -> PresserFoot:
    cols = {k: np.asarray(v, float).reshape(-1) for k, v in resolved.items()}
    m = max(v.size for v in cols.values())
    cols = {k: (np.broadcast_to(v, (m,)).copy() if v.size in (1, m) else v)
            for k, v in cols.items()}
    return PresserFoot(**cols)


def presser_contact(values: dict[str, np.ndarray], **fields) -> dict[str, np.ndarray]:
    """Every contact output for the machines of `values` (parameter name -> array (m,)).

    fields: each name of PRESSER_CONTACT_FIELDS but `measure`, given as the name of a
    parameter in `values` or a number (defaults as in the table). Returns every measure of
    MEASURES (arrays (m,), the modes as floats) and status (strings). A machine that never loses
    contact has lost_deg = separation_mm = 0 and NaN angles, and status "never_lost"."""
    resolved = {}
    for name, (_, default, _) in PRESSER_CONTACT_FIELDS.items():
        spec = fields.get(name, default)
        if name == "measure":
            continue
        if spec is None:
            raise ParameterError(name, "is a required field of output kind presser_contact",
                                 None)
        if isinstance(spec, str) and spec not in values:
            raise ParameterError(name, "names no parameter; valid names are "
                                 + ", ".join(values), spec)
        resolved[name] = values[spec] if isinstance(spec, str) else spec
    unknown = sorted(set(fields) - set(PRESSER_CONTACT_FIELDS))
    if unknown:
        raise ParameterError(unknown[0], "unknown field of output kind presser_contact; valid "
                             "fields are " + ", ".join(PRESSER_CONTACT_FIELDS), unknown[0])
    res = evaluate(_machines(resolved))
    never = res.status == "never_lost"
    lost = np.where(never, 0.0, res.lost_deg)
    sep = np.where(never, 0.0, res.separation_mm)
    return {"loss_deg": res.loss_deg, "regain_deg": res.regain_deg, "lost_deg": lost,
            "separation_mm": sep, "status": res.status,
            "contact_status": np.select([res.status == s for s in STATUS],
                                        np.arange(len(STATUS), dtype=float), np.nan),
            "impacts": res.impacts.astype(float), "intervals": res.intervals.astype(float),
            "lost_by_force": res.lost_by_force.astype(float)}


def presser_contact_output(state, measure: str = "separation_mm", **fields) -> np.ndarray:
    """The registry's form, fn(state, **fields) -> array (m,): fields arrive resolved (arrays
    (m, 1) or numbers); `state` is not needed (the contact cycle is sampled by the kernel)."""
    if measure not in MEASURES:
        raise ParameterError("measure", "must be one of " + ", ".join(MEASURES), measure)
    if journals_off_centre(state):
        # the contact kernel is a closed form of the parameters: it would silently give the
        # ideal pairs' answer
        raise ParameterError(f"output presser_contact ({measure})", "is computed by the "
                             "presser's own kernel, which does not see joint clearances: study "
                             "an output of the file's points with journals off centre", measure)
    key = tuple((k, np.ascontiguousarray(v, float).reshape(-1).tobytes())
                for k, v in fields.items())
    return _cycle(key)[measure]


@functools.lru_cache(maxsize=2)
def _cycle(key: tuple) -> dict[str, np.ndarray]:
    """presser_contact of the machines in `key` (field -> float64 bytes), cached: the kernel
    gives every measure at once, so a block's outputs share one run."""
    out = presser_contact({k: np.frombuffer(b, float) for k, b in key}, **{k: k for k, _ in key})
    for v in out.values():
        v.setflags(write=False)  # shared by the block's outputs
    return out


def _register() -> None:
    from sewtol.mechanism.outputs import register_output

    register_output("presser_contact", presser_contact_output, fields=PRESSER_CONTACT_FIELDS)


_register()
