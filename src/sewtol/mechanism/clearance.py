"""Joint clearances of a mechanism file: the `[[clearances]]` tables, checked into Clearance data.

A revolute pair gives a radial clearance (``radial_mm``) or an ISO 286 fit at a pin diameter; a
prismatic pair the gap across its guide (or a fit) and the guide's length. Stored as the
diametral clearance range (hole minus shaft, mm). A revolute clearance enters the model as two
pair parameters, the journal's offset r = (dx, dy) mm from the bearing's centre (the
effective-link model; r = 0 is the ideal model, bit for bit): the group that makes the joint's
point moves the next link's journal by r; a dyad's link 1 turns about p1 + r, and an
``on_body`` group fixed to link 1 sees link 1's point (link 2's - r). Prismatic pairs are data
the guide-pair criterion reads (`sewtol.studies.clearance`). docs/clearances.md, "The model".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sewtol import engine
from sewtol.errors import ParameterError, real
from sewtol.fits import check_diameter, iso_fit

PAIRS = ("revolute", "prismatic")
KEYS = ("joint", "pair", "radial_mm", "gap_mm", "fit", "diameter_mm", "length_mm", "doc")
# where each group type has its pairs: point fields (and "name", the group's own point or
# angle) that are revolute joints, and the group whose body slides in a prismatic pair
REVOLUTE_AT = {"crank": ("center", "name"), "rrr": ("name", "p1", "p2"), "rrp": ("name", "p1"),
               "rpr": ("pivot", "block")}
PRISMATIC_AT = ("rrp", "rpr", "spatial_slider")
DYADS = ("rrr", "rrp")  # groups whose own point is the joint of their two links


def offset_names(joint: str) -> tuple[str, str]:
    """The pair parameters of a revolute pair: its journal's offset (dx, dy) in mm."""
    return f"{joint}_dx_mm", f"{joint}_dy_mm"


def polar_names(joint: str) -> tuple[str, str]:
    """The journal's offset in polar form, as parameters a study may vary
    (`sewtol.studies.clearance.clearance_variables`): the square of its length (mm^2: uniform
    in [0, c^2] is a journal uniform over the clearance's disc) and its direction (deg)."""
    return f"{joint}_r2_mm2", f"{joint}_phi_deg"


def pair_offsets(clearances, cols: dict) -> dict:
    """joint -> complex offset r = dx + i dy (mm, shaped (m, 1)) of every revolute pair with a
    clearance, from the evaluation's columns; plus sqrt(r2) e^(i phi) where the columns hold
    the polar form too (`polar_names`)."""
    out = {}
    for c in clearances:
        if c.pair == "revolute":
            dx, dy = offset_names(c.joint)
            r = np.asarray(cols[dx], float) + 1j * np.asarray(cols[dy], float)
            r2, phi = polar_names(c.joint)
            if r2 in cols and phi in cols:
                rho = np.sqrt(np.maximum(np.asarray(cols[r2], float), 0.0))
                r = r + rho * np.exp(1j * np.radians(np.asarray(cols[phi], float)))
            out[c.joint] = r
    return out


PAIR_SUFFIXES = ("_dx_mm", "_dy_mm", "_r2_mm2")  # the pair parameters' and polar offsets' names


def journals_off_centre(state) -> bool:
    """Whether any machine of an evaluation's state has a journal off its bearing's centre (an
    output computed from the parameters by a closed form of its own does not see them)."""
    values = getattr(state, "values", None) or {}  # a kernel called without a state: none
    return any(k.endswith(PAIR_SUFFIXES) and np.any(np.asarray(v) != 0)
               for k, v in values.items())


def shifted(point, r):
    """The point moved by the constant offset r (its transfer functions unchanged)."""
    return engine.Motion(point.p + r, point.dp, point.ddp)


def on_body_view(group, points: dict, link1: dict, groups) -> dict:
    """The points an on_body group sees: a dyad's joint as its link 1 holds it when the group's
    origin or direction also names the dyad's p1 (the body is fixed to link 1)."""
    named = [group.fields.get("origin"), *(group.fields.get("direction") or ())]
    p1 = {g.name: g.fields.get("p1") for g in groups if g.type in DYADS}
    view = points
    for s in named:
        if s in link1 and p1.get(s) in named:
            view = dict(view) if view is points else view
            view[s] = link1[s]
    return view


@dataclass(frozen=True)
class Clearance:
    """The clearance of one pair. ``clearance_min_mm`` <= ``clearance_max_mm`` are diametral
    (hole minus shaft, >= 0); a radial clearance c is half of it. ``length_mm`` is the guide's
    length of a prismatic pair (None for a revolute one); ``fit`` and ``diameter_mm`` say where
    the range came from when a fit was given."""

    joint: str
    pair: str
    clearance_min_mm: float
    clearance_max_mm: float
    length_mm: float | None = None
    fit: str | None = None
    diameter_mm: float | None = None
    doc: str = ""
    line: int = 0

    def __post_init__(self):
        if self.pair not in PAIRS:
            raise ParameterError("pair", f"must be one of {', '.join(PAIRS)}", self.pair)
        lo, hi = self.clearance_min_mm, self.clearance_max_mm
        if not (real(lo, finite=True) and real(hi, finite=True) and 0.0 <= lo <= hi):
            raise ParameterError("clearance_mm", "must be 0 <= min <= max, finite (mm)", (lo, hi))
        if (self.pair == "prismatic") != (self.length_mm is not None):
            raise ParameterError("length_mm", "is required for a prismatic pair and only for one",
                                 self.length_mm)
        if self.length_mm is not None and not (real(self.length_mm, finite=True) and self.length_mm > 0):
            raise ParameterError("length_mm", "must be a positive length in mm", self.length_mm)

    @property
    def radial_min_mm(self) -> float:
        return self.clearance_min_mm / 2

    @property
    def radial_max_mm(self) -> float:
        return self.clearance_max_mm / 2

    @property
    def tilt_max_deg(self) -> float | None:
        """A prismatic pair's largest tilt of the slider in its guide, atan(gap / length) (small:
        gap / length rad); None for a revolute pair."""
        if self.length_mm is None:
            return None
        return math.degrees(math.atan2(self.clearance_max_mm, self.length_mm))


def pair_joints(groups) -> dict[str, set[str]]:
    """The names a clearance may take, per pair kind, from the file's groups."""
    revolute, prismatic = set(), set()
    for g in groups:
        for f in REVOLUTE_AT.get(g.type, ()):
            revolute.add(g.name if f == "name" else g.fields[f])
        if g.type in PRISMATIC_AT:
            prismatic.add(g.name)
    return {"revolute": revolute, "prismatic": prismatic}


def _range(value, what: str) -> tuple[float, float]:
    """A value or [min, max] in mm, as (min, max)."""
    pair = value if isinstance(value, list) else [value, value]
    if len(pair) != 2 or not all(real(v, finite=True) for v in pair) or not 0 <= pair[0] <= pair[1]:
        raise ParameterError(what, "must be a number >= 0 or [min, max] with 0 <= min <= max "
                                   "(mm)", value)
    return float(pair[0]), float(pair[1])


def parse_clearances(table, groups, locate) -> tuple[Clearance, ...]:
    """The checked [[clearances]] of a file. `locate(path)` gives the "FILE:LINE: " prefix and
    the line of a TOML path, so a refusal points at the line."""
    if table is None:
        return ()
    if not isinstance(table, list):
        prefix, _ = locate(("clearances",))
        raise ParameterError(f"{prefix}[[clearances]]", "must be an array of tables", table)
    joints = pair_joints(groups)
    out, seen = [], set()
    for i, c in enumerate(table):
        path = ("clearances", i)
        prefix, line = locate(path)
        where = f"{prefix}[[clearances]] #{i + 1}"
        try:
            out.append(_clearance(c, joints, line))
        except ParameterError as exc:
            key = exc.field if isinstance(c, dict) and exc.field in c else None
            if key is not None:
                prefix, _ = locate(path + (key,))
                where = f"{prefix}[[clearances]] #{i + 1}"
            raise ParameterError(f"{where}.{exc.field}", exc.rule, exc.value) from None
        if (out[-1].joint, out[-1].pair) in seen:
            raise ParameterError(f"{where}.joint", f"has a {out[-1].pair} clearance already",
                                 out[-1].joint)
        seen.add((out[-1].joint, out[-1].pair))
    return tuple(out)


def _clearance(c, joints, line) -> Clearance:
    if not isinstance(c, dict):
        raise ParameterError("table", "must be a table { joint = ..., fit = ... }", c)
    for k in c:
        if k not in KEYS:
            raise ParameterError(k, f"unknown key; allowed: {', '.join(KEYS)}", k)
    pair = c.get("pair", "revolute")
    if pair not in PAIRS:
        raise ParameterError("pair", f"must be one of {', '.join(PAIRS)}", pair)
    valid = sorted(joints[pair])
    if not isinstance(c.get("joint"), str) or c["joint"] not in joints[pair]:
        what = ("a joint point of a crank, rrr, rrp or rpr group" if pair == "revolute"
                else "an rrp, rpr or spatial_slider group")
        raise ParameterError("joint", f"must name {what}: {', '.join(valid) or 'none in this file'}",
                             c.get("joint"))
    width = "radial_mm" if pair == "revolute" else "gap_mm"
    other = "gap_mm" if pair == "revolute" else "radial_mm"
    if other in c:
        raise ParameterError(other, f"is not a key of a {pair} pair (give {width})", c[other])
    given = [k for k in (width, "fit") if k in c]
    if len(given) != 1:
        raise ParameterError(width, f"give exactly one of {width}, fit", given)
    if ("diameter_mm" in c) != ("fit" in c):
        raise ParameterError("diameter_mm", "goes with fit, and fit needs it", c.get("diameter_mm"))
    length = c.get("length_mm")
    if pair == "revolute" and length is not None:
        raise ParameterError("length_mm", "is a key of a prismatic pair only", length)
    if pair == "prismatic" and length is None:
        raise ParameterError("length_mm", "is required for a prismatic pair (the guide's "
                                          "length, mm)", None)
    doc = c.get("doc", "")
    if not isinstance(doc, str):
        raise ParameterError("doc", "must be a string", doc)
    fit = diameter = None
    if "fit" in c:
        diameter = check_diameter(c["diameter_mm"])
        f = iso_fit(c["fit"], diameter)
        if f.kind != "clearance":
            raise ParameterError("fit", f"must be a clearance fit for a pair that moves (this is "
                                        f"{f.kind}: {f.clearance_min_um:g} to "
                                        f"{f.clearance_max_um:g} um)", c["fit"])
        fit, lo, hi = c["fit"], f.clearance_min_um / 1000, f.clearance_max_um / 1000
    else:
        lo, hi = _range(c[width], width)
        if pair == "revolute":
            lo, hi = 2 * lo, 2 * hi
    return Clearance(joint=c["joint"], pair=pair, clearance_min_mm=lo, clearance_max_mm=hi,
                     length_mm=None if length is None else _length(length), fit=fit,
                     diameter_mm=diameter, doc=doc, line=line)


def _length(v) -> float:
    if not (real(v, finite=True) and v > 0):
        raise ParameterError("length_mm", "must be a positive length in mm", v)
    return float(v)
