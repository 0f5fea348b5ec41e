"""The group table: every `type` a `[[groups]]` entry may name, its fields and its builder.

A builder receives its fields already resolved -- points as engine.Motion, angles as
engine.Angle, numbers and expressions as arrays shaped (m, 1) in the file's units -- plus the
driving angle q (engine.Angle over the sampled angles), and returns the group's point or angle
and its Closure (None for groups that always assemble). Fields whose name ends in _deg are in
degrees; builders turn them into radians. Register a new group with `register_group`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sewtol import engine

DEG = np.pi / 180.0

# field kinds: "point" (name of a point defined earlier), "angle" (name of an angle defined
# earlier), "expr" (number or expression), "branch" (number or expression that is +1 or -1),
# "direction" ([P, Q], two points defined earlier)
KINDS = ("point", "angle", "expr", "branch", "direction")


@dataclass(frozen=True)
class GroupType:
    """A group type: what it produces ("point" or "angle"), its fields (name -> (kind,
    default)); a default of None means required), fields of which exactly one must be given
    (`one_of`), and the builder."""

    type: str
    produces: str
    fields: dict[str, tuple[str, object]]
    builder: Callable
    one_of: tuple[tuple[str, ...], ...] = field(default=())
    doc: str = ""
    requires: str = ""  # a module the builder imports; a file naming the type without it is refused


GROUPS: dict[str, GroupType] = {}


def register_group(type_name: str, builder: Callable, *, produces: str = "point",
                   fields: dict[str, tuple[str, object]] | None = None,
                   one_of: tuple[tuple[str, ...], ...] = (), doc: str = "",
                   requires: str = "") -> GroupType:
    """Add a group type to the table (a file can then name it in `type`).

    builder(q: engine.Angle, **fields) -> (engine.Motion or engine.Angle, engine.Closure or
    None); `fields` maps each field name to (kind, default) with kind one of KINDS and default
    None for a required field."""
    if produces not in ("point", "angle"):
        raise ValueError(f"produces must be 'point' or 'angle', not {produces!r}")
    for name, (kind, _) in (fields or {}).items():
        if kind not in KINDS:
            raise ValueError(f"field {name}: kind must be one of {KINDS}, not {kind!r}")
    gt = GroupType(type_name, produces, dict(fields or {}), builder, tuple(one_of), doc, requires)
    GROUPS[type_name] = gt
    return gt


def _point(q, x, y):
    return engine.fixed(x, y), None


def _crank(q, center, radius, phase_deg, sense):
    ang = engine.Angle(sense * q.a + phase_deg * DEG, sense * q.da, sense * q.dda)
    return engine.polar(center, radius, ang), None


def _on_body(q, origin, u, v, offset_deg, direction=None, angle=None):
    base = direction if direction is not None else angle
    return engine.on_body(origin, base + offset_deg * DEG, u + 1j * v), None


def _rrp(q, p1, r, x, y, angle_deg, branch):
    return engine.rrp(p1, r, x, y, angle_deg * DEG, branch)


def _spatial_rocker(q, a, b, c, e, f, g, alpha_deg, branch):
    # the spatial crank-rocker lives in engine/spatial.py (another module); imported here so
    # the table can name it before that module exists in a build
    from sewtol.engine import spatial  # type: ignore[attr-defined]

    return spatial.spatial_rocker(q, a, b, c, e, f, g, alpha_deg * DEG, branch)


def _spatial_slider(q, a, b, e, f, alpha_deg, branch):
    from sewtol.engine import spatial  # type: ignore[attr-defined]

    return spatial.spatial_slider(q, a, b, e, f, alpha_deg * DEG, branch)


register_group("point", _point, fields={"x": ("expr", None), "y": ("expr", None)},
               doc="frame point (x, y) mm")
register_group("crank", _crank, fields={
    "center": ("point", None), "radius": ("expr", None), "phase_deg": ("expr", 0.0),
    "sense": ("branch", 1.0)},
    doc="crank pin center + radius e^{i(sense q + phase)}")
register_group("rrr", lambda q, **f: engine.rrr(**f), fields={
    "p1": ("point", None), "r1": ("expr", None), "p2": ("point", None), "r2": ("expr", None),
    "branch": ("branch", None)},
    doc="RRR dyad: joint at r1 from p1 and r2 from p2, on the left of p1->p2 for branch +1")
register_group("on_body", _on_body, fields={
    "origin": ("point", None), "direction": ("direction", None), "angle": ("angle", None),
    "offset_deg": ("expr", 0.0), "u": ("expr", None), "v": ("expr", 0.0)},
    one_of=(("direction", "angle"),),
    doc="origin + (u + i v) e^{i(base + offset)}, base = ang(direction) or a named angle")
register_group("rpr", lambda q, **f: engine.rpr(**f), produces="angle", fields={
    "pivot": ("point", None), "block": ("point", None), "offset": ("expr", 0.0)},
    doc="RPR group: angle of the slotted body pivoted at `pivot`, the block at `block`")
register_group("rrp", _rrp, fields={
    "p1": ("point", None), "r": ("expr", None), "x": ("expr", None), "y": ("expr", None),
    "angle_deg": ("expr", None), "branch": ("branch", None)},
    doc="RRP group: joint at r from p1 on the fixed line through (x, y) at angle_deg")
register_group("spatial_rocker", _spatial_rocker, produces="angle", fields={
    "a": ("expr", None), "b": ("expr", None), "c": ("expr", None), "e": ("expr", None),
    "f": ("expr", None), "g": ("expr", None), "alpha_deg": ("expr", None),
    "branch": ("branch", 1.0)},
    doc="spatial crank-rocker (engine.spatial): the rocker angle psi of the driving angle",
    requires="sewtol.engine.spatial")
register_group("spatial_slider", _spatial_slider, fields={
    "a": ("expr", None), "b": ("expr", None), "e": ("expr", None), "f": ("expr", None),
    "alpha_deg": ("expr", None), "branch": ("branch", 1.0)},
    doc="spatial crank-slider (engine.spatial): the slider's ball joint C = (e, s), s along "
        "the guide",
    requires="sewtol.engine.spatial")
