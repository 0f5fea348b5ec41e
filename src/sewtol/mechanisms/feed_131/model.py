"""Feed chains of the 131-42+3 class: lower and upper feed dogs ("vertical differential").

Built group by group in the source's order (docs/feed_131.md, steps 1-23), with the
analysis program's data. Frame origin O1 (main shaft), x right, y up, lengths mm, angles deg
counter-clockwise from +x, phi = main-shaft angle. "RRR dyad X-J-Y, J left of X->Y" is
engine.rrr(X, XJ, Y, YJ, +1).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sewtol import engine
from sewtol.errors import AssemblyError
from sewtol.mechanisms import params as P

DEG = np.pi / 180.0

# a dyad closer than this to collinear is at a dead point (possible branch flip); checked on the
# sampled cycle (single runs: every 0.5 deg; studies: the 720-point grid)
DEAD_POINT_DEG = 1.0

# the folder's mechanism file holds the parameters once: names, nominal values and rules
PARAMETERS = tomllib.loads(Path(__file__).with_name("mechanism.toml").read_text())["parameters"]


def _file_fields(cls):
    """The dataclass of `cls` with a float field per parameter of the file, its nominal the
    default."""
    for name, spec in PARAMETERS.items():
        cls.__annotations__[name] = float
        setattr(cls, name, float(spec["nominal"]))
    return dataclass(frozen=True)(cls)


@_file_fields
class Feed131:
    """Every length, pivot, phase and setting of the 131-42+3 feed chains (mm, deg).

    Frozen and validated at construction. The fields and their defaults are the [parameters] of
    the folder's mechanism.toml, in its order (the source's analysis-program data, written
    once). The names follow the points of the chains (docs/feed_131.md lists the 23 steps): a
    two-letter name is the length between two points (``O4K`` is O4 to K), ``..x``/``..y`` a
    fixed pivot's coordinates, ``.._angle`` the angle of an arm on its rocker. Frame origin O1
    (the main shaft), x to the right, y up; angles counter-clockwise from +x.

    Parameters
    ----------
    O1F, lift_phase : float
        Lower lift eccentric: radius (mm) and phase (deg), F = O1 + O1F e(phi + lift_phase).
    O4x, O4y, O4K, FK, O4M, M_angle : float
        The lift rocker at O4 (mm), its links and the arm O4M at M_angle (deg) from O4K.
    O1A1, feed_phase : float
        Feed eccentric: radius (mm) and phase (deg), A1 = O1 + O1A1 e(phi + feed_phase).
    O2x, O2y, O2D, b : float
        The stitch regulator: pivot O2 (mm), arm O2D (mm) and the setting b (deg), which sets
        the stitch length and, past its neutral, reverses the feed.
    DB, A1B, O3x, O3y, O3C, BC, O3E, E_angle : float
        The feed chain to the feed rocker at O3 and its arm O3E at E_angle (deg) from O3C.
    MN, EN, EP, PN, tooth1_u, tooth1_v : float
        The lower dog bar (the right triangle E-N-P) and its middle tooth Q1 along and across
        the bar (mm).
    dog_bar_program : float
        0: the exact right triangle (default); 1: the analysis program's arithmetic, whose
        tooth sits about 2.3 um further along the bar.
    O6x, O6y, O6R, CR, O6S, RS, O8x, O8y, O8V, SV, O8W, Xx, Xy, XL, WL : float
        The upper dog's horizontal chain, driven from joint C of the lower feed chain (mm).
    O5x, O5y, O5A2, upper_phase : float
        The upper lift eccentric on its own shaft O5: radius (mm) and phase (deg).
    upper_sense : float
        -1 (the source): A2 = O5 + O5A2 e(upper_phase - phi); +1: e(upper_phase + phi).
    O7x, O7y, O7H, A2H, O7I, Ux, Uy, UJ, IJ, UY, Y_angle : float
        The upper lift chain (mm) and the arm UY at Y_angle (deg) from UJ.
    slot_offset, tooth2_u, tooth2_v : float
        The upper dog holder's slot offset from L and the middle tooth Q2 (mm).
    plate_mm : float
        The needle-plate level H (mm); the lower dog works above it.
    material_mm : float
        The material thickness (mm); the upper dog works below plate_mm + material_mm.
    """

    LENGTHS = tuple(k for k, spec in PARAMETERS.items() if spec.get("rule") == "positive")

    def __post_init__(self):
        P.freeze(self)
        for f in P.field_names(type(self)):
            P.finite(f, getattr(self, f))
        for f in self.LENGTHS:
            P.positive(f, getattr(self, f))
        if not np.all(np.isin(np.asarray(self.dog_bar_program, float), (0.0, 1.0))):
            raise P.ParameterError("dog_bar_program", "must be 0 (exact right triangle) or 1 "
                                   "(the analysis program's arithmetic)", self.dog_bar_program)
        if not np.all(np.isin(np.asarray(self.upper_sense, float), (-1.0, 1.0))):
            raise P.ParameterError("upper_sense", "must be -1 (A2 turns as upper_phase - phi) or "
                                   "+1 (upper_phase + phi)", self.upper_sense)
        if np.any(np.asarray(self.material_mm) < 0):
            raise P.ParameterError("material_mm", "must not be negative", self.material_mm)
        s = (self.O6R**2 + self.O6S**2 - self.RS**2) / (2 * self.O6R * self.O6S)
        if np.any(np.abs(np.asarray(s)) > 1):
            raise P.ParameterError("RS", "the triangle O6-R-S must close: |O6R - O6S| <= RS <= "
                                   "O6R + O6S", self.RS)

    def override(self, **changes: float) -> Feed131:
        """A copy with some parameters changed (validated like a new machine).

        Parameters
        ----------
        **changes : float
            New values by parameter name (mm, deg); an unknown name fails and lists the valid
            ones.

        Returns
        -------
        Feed131
            The changed copy; this machine is unchanged.
        """
        return P.override(self, changes)


def chains(c: dict, phi_rad) -> dict:
    """Every joint of both chains over phi; derivatives are d/dphi. Closures per dyad."""
    O1 = engine.fixed(0.0, 0.0)
    fx = engine.fixed
    closure, transmission = {}, {}

    def dyad(name, p1, r1, p2, r2, branch):
        j, cl = engine.rrr(p1, r1, p2, r2, branch)
        closure[name] = cl.miss_mm
        transmission[name] = cl.transmission_deg
        return j

    phi = engine.driving_angle(phi_rad)
    # lower dog: lift chain
    F = engine.polar(O1, c["O1F"], phi + c["lift_phase"] * DEG)
    O4 = fx(c["O4x"], c["O4y"])
    K = dyad("O4-K-F", O4, c["O4K"], F, c["FK"], 1.0)
    M = engine.polar(O4, c["O4M"], engine.direction(O4, K) + c["M_angle"] * DEG)
    # feed chain with the stitch regulator
    A1 = engine.polar(O1, c["O1A1"], phi + c["feed_phase"] * DEG)
    D = engine.polar(fx(c["O2x"], c["O2y"]), c["O2D"],
                     engine.Angle(*(np.asarray(v) for v in ((90 + c["b"]) * DEG, 0.0, 0.0))))
    B = dyad("D-B-A1", D, c["DB"], A1, c["A1B"], -1.0)
    O3 = fx(c["O3x"], c["O3y"])
    C = dyad("O3-C-B", O3, c["O3C"], B, c["BC"], 1.0)
    E = engine.polar(O3, c["O3E"], engine.direction(O3, C) + c["E_angle"] * DEG)
    # dog bar: right triangle E-N-P, axis u = unit(E->N) turned by atan(PN/EP)
    N = dyad("M-N-E", M, c["MN"], E, c["EN"], 1.0)
    u = engine.direction(E, N) + np.arctan2(c["PN"], c["EP"])
    # the program's u is longer than a unit vector by hypot(EP, PN) / EN: its tooth point is the
    # exact one scaled about E by that factor
    bar_scale = np.where(c["dog_bar_program"] == 1.0, np.hypot(c["EP"], c["PN"]) / c["EN"], 1.0)
    Q1 = engine.on_body(E, u, bar_scale * (c["tooth1_u"] + 1j * c["tooth1_v"]))
    # upper dog: horizontal chain driven from C
    O6 = fx(c["O6x"], c["O6y"])
    R = dyad("O6-R-C", O6, c["O6R"], C, c["CR"], 1.0)
    g4 = np.arccos((c["O6R"] ** 2 + c["O6S"] ** 2 - c["RS"] ** 2) / (2 * c["O6R"] * c["O6S"]))
    S = engine.polar(O6, c["O6S"], engine.direction(O6, R) - g4)
    O8 = fx(c["O8x"], c["O8y"])
    V = dyad("O8-V-S", O8, c["O8V"], S, c["SV"], 1.0)
    W = engine.polar(O8, c["O8W"], engine.direction(O8, V) + np.pi)
    L = dyad("X-L-W", fx(c["Xx"], c["Xy"]), c["XL"], W, c["WL"], 1.0)
    # upper lift chain on its own shaft O5, turning with -phi
    sense = c["upper_sense"]
    A2 = engine.polar(fx(c["O5x"], c["O5y"]), c["O5A2"],
                      engine.Angle(c["upper_phase"] * DEG + sense * phi.a, sense * phi.da,
                                   sense * phi.dda))
    O7 = fx(c["O7x"], c["O7y"])
    H = dyad("O7-H-A2", O7, c["O7H"], A2, c["A2H"], 1.0)
    I = engine.polar(O7, c["O7I"], engine.direction(O7, H) + np.pi)
    U = fx(c["Ux"], c["Uy"])
    J = dyad("U-J-I", U, c["UJ"], I, c["IJ"], -1.0)
    Y = engine.polar(U, c["UY"], engine.direction(U, J) + c["Y_angle"] * DEG)
    # dog holder: RPR group (slot at offset from L, block at Y)
    f, cl = engine.rpr(L, Y, c["slot_offset"])
    closure["L-slot-Y"] = cl.miss_mm
    Q2 = engine.on_body(L, f, c["tooth2_u"] + 1j * (c["slot_offset"] - c["tooth2_v"]))
    return {"F": F, "K": K, "M": M, "A1": A1, "D": D, "B": B, "C": C, "E": E, "N": N, "Q1": Q1,
            "R": R, "S": S, "V": V, "W": W, "L": L, "A2": A2, "H": H, "I": I, "J": J, "Y": Y,
            "Q2": Q2, "holder_angle": f, "closure": closure, "transmission": transmission}


def check_assembly(params: Feed131, phi_rad) -> None:
    """Raise AssemblyError naming the first dyad (in chain order) that fails, and where."""
    c = P.column(params, None)
    out = chains(c, np.asarray(phi_rad, float))
    for name, miss in out["closure"].items():
        miss = np.broadcast_to(miss, np.shape(phi_rad))
        if np.any(miss > 0):
            k = int(np.argmax(miss))
            phi = float(np.degrees(np.ravel(phi_rad)[k]))
            raise AssemblyError(name, phi, float(np.ravel(miss)[k]), P.as_dict(params),
                                "main-shaft angle phi")
    for name, g in out["transmission"].items():
        g = np.broadcast_to(g, np.shape(phi_rad))
        k = int(np.nanargmin(g)) if np.ndim(g) else 0
        if float(np.ravel(g)[k]) < DEAD_POINT_DEG:
            raise AssemblyError(name, float(np.degrees(np.ravel(phi_rad)[k])), 0.0,
                                P.as_dict(params),
                                f"main-shaft angle phi; dead point: the links are "
                                f"{float(np.ravel(g)[k]):.3f} deg from collinear "
                                f"(< {DEAD_POINT_DEG:g}), the joint can flip to its other "
                                "assembly (branch flip)")
