"""The 208-class overlock needle drive: two four-bars in series, zero mobility.

Topology (the source's data and these conventions: docs/needle_208.md):

    crank F-L (LF)  ->  RRR dyad L-M-A (LM, AM; M on side branch_M of L->A)
    rocker angle theta = ang(A->M); second arm B = A + AB e(theta + beta_sense*beta)
    RRR dyad B-C-D (BC, CD; C on side branch_C of B->D)
    needle-bar point E on the ternary rod: E = B + BE e(ang(B->C) + CBE), CBE = 180 nominal

Units: lengths mm, angles degrees at this boundary (radians inside), the guide shift in um.
The guide is the line through (guide_x, guide_y) with direction u = (sin a, cos a),
a = guide_angle measured from the vertical (top leaning to +x for a > 0); its normal
n = (cos a, -sin a) points to the right of u. d = n.(E - G) - guide_shift_um/1000.

E depends on the crank only through theta, and theta swings between two extremes reached when
crank and connecting rod are collinear, so the path is computed on the rocker interval.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources

import numpy as np

from sewtol import engine
from sewtol.engine.dyad import joint
from sewtol.errors import AssemblyError
from sewtol.mechanisms import params as P

LENGTHS = ("LF", "LM", "AM", "AB", "BC", "BE", "CD")
DEG = np.pi / 180.0
# a dyad whose links come closer than this to collinear during the cycle is at a dead point,
# where the real joint can flip to the other assembly: single runs refuse it, studies count it
DEAD_POINT_DEG = 1.0


@dataclass(frozen=True)
class Needle208:
    """Every dimension of the 208 needle drive: one machine, or a batch of machines.

    Frozen and validated at construction (lengths > 0, finite values, branch signs +/-1). Each
    field is a float, or all are equal-length arrays for a batch. Vary a machine by copying:
    ``m.override(CD=30.01)``. Lengths in mm, angles in deg; frame origin at the main shaft F,
    x to the right, y up.

    Parameters
    ----------
    LF, LM : float
        Crank radius F-L and connecting rod L-M (mm); source 6.75 and 58.
    AM, AB : float
        The two rocker arms on the upper shaft A (mm); source 17 and 10.
    BC, BE : float
        The ternary rod: middle head B to rear head C and to the needle-bar head E (mm);
        source 20 and 40.
    CD : float
        The rear rocker C-D (mm); source 30.
    CBE : float
        The angle of the ternary rod at B from B->C to B->E (deg); 180 is collinear.
    beta : float
        The regulating angle between the arms AM and AB (deg), set at assembly.
    Ax, Ay, Dx, Dy : float
        The upper-shaft axis A and the rear rocker's pivot D (mm); not published, taken from
        the frame.
    guide_x, guide_y : float
        A point of the guide line (mm); source N1 = (38.5, 79.729).
    guide_angle : float
        The guide's inclination from the vertical (deg); positive leans its top towards +x.
    guide_shift_um : float
        A shift of the guide along its normal (um); 0 leaves it where the frame puts it.
    branch_M, branch_C : float
        The assembly branch of M (left of L->A: +1) and of C (left of B->D: +1).
    beta_sense : float
        +1: AB lies counter-clockwise of AM by beta; -1: clockwise.

    Examples
    --------
    >>> from sewtol import Needle208
    >>> m = Needle208.nominal()          # the default frame's nominal machine
    >>> m.override(CD=30.01).CD
    30.01
    """

    LF: float
    LM: float
    AM: float
    AB: float
    BC: float
    BE: float
    CD: float
    CBE: float
    beta: float
    Ax: float
    Ay: float
    Dx: float
    Dy: float
    guide_x: float
    guide_y: float
    guide_angle: float
    guide_shift_um: float = 0.0
    branch_M: float = 1.0
    branch_C: float = 1.0
    beta_sense: float = 1.0

    def __post_init__(self):
        P.freeze(self)
        for name in LENGTHS:
            P.positive(name, getattr(self, name))
        for name in ("CBE", "beta", "Ax", "Ay", "Dx", "Dy", "guide_x", "guide_y", "guide_angle",
                     "guide_shift_um"):
            P.finite(name, getattr(self, name))
        for name in ("branch_M", "branch_C", "beta_sense"):
            P.branch(name, getattr(self, name))

    @classmethod
    def nominal(cls, frame=None) -> Needle208:
        """The reconstructed nominal machine of a named frame (package data, see
        needle_208.frames).

        studies/calibrate_needle_208.py rebuilds the frames.

        Parameters
        ----------
        frame : str, Frame or None
            A frame name (``"sewtol-0.1"``, ``"window"``, ``"table41"``), a
            `sewtol.mechanisms.needle_208.frames.Frame`, or None for the default frame (``DEFAULT_FRAME``).

        Returns
        -------
        Needle208
            The nominal machine: the source's link lengths on that frame's pivots and guide.
        """
        from sewtol.mechanisms.needle_208.frames import resolve

        return cls(**resolve(frame).params)

    def override(self, **changes: float) -> Needle208:
        """A copy with some parameters changed (validated like a new machine).

        Parameters
        ----------
        **changes : float
            New values by parameter name (mm, deg, um); an unknown name fails and lists the
            valid ones.

        Returns
        -------
        Needle208
            The changed copy; this machine is unchanged.
        """
        return P.override(self, changes)


def load_nominal_record() -> dict:
    """The geometry file of sewtol 0.1 (kept so old reports stay reproducible; it is the frame
    `sewtol-0.1`)."""
    here = resources.files("sewtol.mechanisms.needle_208")
    text = here.joinpath("data", "needle_208.json").read_text()
    return json.loads(text)


# --- kernels (pure, vectorised; `c` holds parameter columns from params.column) ---------------


def _arm_angle(c) -> np.ndarray:
    return c["beta_sense"] * c["beta"] * DEG


@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def rocker_interval(c):
    """Exact rocker extremes (rad), lo < hi, and the miss of the first dyad at its worst crank angle.

    The extremes are where crank and connecting rod are collinear: |FM| = LM + LF (extended) and
    |FM| = LM - LF (folded). Among the two intersections of each circle pair, the one on the
    assembly branch (M on side branch_M of L->A) is kept.
    """
    F = engine.fixed(0.0, 0.0)
    A = engine.fixed(c["Ax"], c["Ay"])
    thetas = []
    for reach, sense in ((c["LM"] + c["LF"], 1.0), (c["LM"] - c["LF"], -1.0)):
        best = None
        for side in (1.0, -1.0):
            M, _ = joint(F.p, reach, A.p, c["AM"], side)  # no transfer functions needed
            unit = (M - F.p) / np.abs(M - F.p)
            L = F.p + sense * c["LF"] * unit
            cross = ((A.p - L).conjugate() * (M - L)).imag
            match = np.sign(cross) == c["branch_M"]
            th = np.angle(M - A.p)
            best = th if best is None else np.where(match, th, best)
        thetas.append(best)
    t1, t2 = thetas
    half = np.angle(np.exp(1j * (t2 - t1)))
    lo = np.where(half > 0, t1, t1 + half)
    hi = lo + np.abs(half)
    # first dyad over a full crank turn: |A - L| spans |FA| -/+ LF
    fa = np.abs(A.p - F.p)
    miss = np.maximum.reduce([
        fa + c["LF"] - (c["LM"] + c["AM"]),
        np.abs(c["LM"] - c["AM"]) - (fa - c["LF"]),
        np.zeros_like(fa + c["LF"]),
    ])
    # where it misses most: L farthest from A (phi = ang(F->A) + 180) or nearest (phi = ang(F->A))
    far = fa + c["LF"] - (c["LM"] + c["AM"]) >= np.abs(c["LM"] - c["AM"]) - (fa - c["LF"])
    phi_fail = np.angle(A.p - F.p) + np.where(far, np.pi, 0.0)
    return lo, hi, miss, phi_fail


def _bd_extreme_distances(c, lo, hi):
    """(theta, |D - B|) at every rocker angle where |D - B| can be extreme on [lo, hi]: the
    interval ends and, if inside, where B points at D or away from it.

    |D - B|^2 = AD^2 + AB^2 - 2 AB AD cos(theta + off - ang(A->D)), so those are the only places.
    """
    v = (c["Dx"] - c["Ax"]) + 1j * (c["Dy"] - c["Ay"])
    g = np.angle(v)
    off = _arm_angle(c)
    t_near = lo + np.mod(g - off - lo, 2 * np.pi)
    t_far = lo + np.mod(g - off + np.pi - lo, 2 * np.pi)
    ts = (lo, hi, np.where(t_near <= hi, t_near, lo), np.where(t_far <= hi, t_far, lo))
    return [(t, np.abs(v - c["AB"] * np.exp(1j * (t + off)))) for t in ts]


def _transmission(r1, r2, s):
    """Angle between links r1, r2 whose far ends are s apart, folded into [0, 90] deg."""
    cos_g = np.clip((r1 * r1 + r2 * r2 - s * s) / (2 * r1 * r2), -1.0, 1.0)
    g = np.degrees(np.arccos(cos_g))
    return np.minimum(g, 180.0 - g)


def transmission_extremes(c, lo, hi):
    """Exact smallest transmission angle (deg) of L-M-A over a crank turn and of B-C-D over the
    rocker interval, with the angle where it occurs (crank phi, rocker theta; rad).

    The angle is monotonic in the distance between the dyad's outer points, so its smallest
    value sits where that distance is extreme: |A - L| = |FA| -/+ LF, and |D - B| at the
    interval ends or where B points at or away from D.
    """
    fa = np.hypot(c["Ax"], c["Ay"])
    g_near = _transmission(c["LM"], c["AM"], fa - c["LF"])
    g_far = _transmission(c["LM"], c["AM"], fa + c["LF"])
    phi_a = np.arctan2(c["Ay"], c["Ax"])
    g1 = np.minimum(g_near, g_far)
    phi1 = np.where(g_near <= g_far, phi_a, phi_a + np.pi)
    candidates = _bd_extreme_distances(c, lo, hi)
    g2 = np.full(np.shape(candidates[0][1]), np.inf)
    t2 = np.zeros_like(g2)
    for t, dist in candidates:
        gt = _transmission(c["BC"], c["CD"], dist)
        better = gt < g2
        g2 = np.where(better, gt, g2)
        t2 = np.where(better, t, t2)
    return g1, phi1, g2, t2


def second_dyad_miss(c, lo, hi):
    """How far dyad B-C-D is from closing over theta in [lo, hi], and the worst theta (rad)."""
    candidates = _bd_extreme_distances(c, lo, hi)
    worst_miss = np.zeros(np.shape(candidates[0][1]))
    worst_t = np.broadcast_to(lo, worst_miss.shape).astype(float)
    for t, dist in candidates:
        miss = np.maximum(np.maximum(dist - (c["BC"] + c["CD"]), np.abs(c["BC"] - c["CD"]) - dist), 0)
        worse = miss > worst_miss
        worst_miss = np.where(worse, miss, worst_miss)
        worst_t = np.where(worse, t, worst_t)
    return worst_miss, worst_t


def chain_from_rocker(c, rocker: engine.Angle) -> dict[str, engine.Motion]:
    """B, C, E for a given rocker angle state (derivatives w.r.t. whatever drives the rocker)."""
    A = engine.fixed(c["Ax"], c["Ay"])
    D = engine.fixed(c["Dx"], c["Dy"])
    B = engine.polar(A, c["AB"], rocker + _arm_angle(c))
    C, closure = engine.rrr(B, c["BC"], D, c["CD"], c["branch_C"])
    E = engine.polar(B, c["BE"], engine.direction(B, C) + c["CBE"] * DEG)
    return {"B": B, "C": C, "E": E, "closure_BCD": closure}


def chain_from_crank(c, phi_rad) -> dict:
    """Every joint over crank angles phi (rad); derivatives are transfer functions d/dphi."""
    F = engine.fixed(0.0, 0.0)
    A = engine.fixed(c["Ax"], c["Ay"])
    L = engine.polar(F, c["LF"], engine.driving_angle(phi_rad))
    M, closure_lma = engine.rrr(L, c["LM"], A, c["AM"], c["branch_M"])
    theta = engine.direction(A, M)
    out = chain_from_rocker(c, theta)
    out.update({"L": L, "M": M, "theta": theta, "closure_LMA": closure_lma})
    return out


def guide_frame(c):
    """Unit direction u, unit normal n (complex) and the shifted guide point G (mm)."""
    a = c["guide_angle"] * DEG
    u = np.sin(a) + 1j * np.cos(a)
    n = np.cos(a) - 1j * np.sin(a)
    G = c["guide_x"] + 1j * c["guide_y"] + n * (c["guide_shift_um"] * 1e-3)
    return u, n, G


def project(n, z):
    """Real dot product n.z of complex vectors."""
    return (np.conjugate(n) * z).real


def check_assembly(params: Needle208) -> None:
    """Raise AssemblyError naming the dyad and angle if a single machine cannot run a full turn."""
    c = P.column(params, None)
    lo, hi, miss1, phi_fail = rocker_interval(c)
    if float(miss1) > 0:
        raise AssemblyError("L-M-A", np.degrees(float(phi_fail)) % 360, float(miss1),
                            P.as_dict(params), "crank angle; the crank cannot make a full turn")
    miss2, t_fail = second_dyad_miss(c, lo, hi)
    if float(miss2) > 0:
        raise AssemblyError("B-C-D", np.degrees(float(t_fail)), float(miss2), P.as_dict(params),
                            "rocker angle theta = ang(A->M)")
    g1, phi1, g2, t2 = transmission_extremes(c, lo, hi)
    for group, gmin, at, what in (("L-M-A", g1, phi1, "crank angle"),
                                  ("B-C-D", g2, t2, "rocker angle theta = ang(A->M)")):
        if float(gmin) < DEAD_POINT_DEG:
            raise AssemblyError(group, np.degrees(float(at)) % 360, 0.0, P.as_dict(params),
                                f"{what}; dead point: the links are {float(gmin):.3f} deg from "
                                f"collinear (< {DEAD_POINT_DEG:g}), the joint can flip to its "
                                "other assembly (branch flip)")
