"""The output table: every `type` an `[[outputs]]` entry may name, and the custom registry.

An output reduces the motion over the sampled cycle to one number per machine. Its function
receives its fields resolved (points as engine.Motion shaped (m, samples), angles as
engine.Angle, expressions as arrays (m, 1), `group` as the group's name, choices as strings)
and the evaluation state (points, angles, closures, q_rad, rpm), and returns an array (m,).
`register_output(kind, fn, fields=...)` adds a kind that files name with type = "custom".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

DEG = np.pi / 180.0
COORD_MEASURES = ("max", "min", "range", "argmax_deg", "argmin_deg")
LINE_MEASURES = ("sum_extremes", "max_abs", "range")


@dataclass(frozen=True)
class OutputType:
    """fields: name -> (kind, default, choices); kind one of point, angle, direction, expr,
    group, choice; default None means required. needs_rpm: [mechanism] rpm must be given."""

    type: str
    fields: dict[str, tuple]
    fn: Callable
    needs_rpm: bool = False
    one_of: tuple[tuple[str, ...], ...] = ()


def _reduce(values, q_rad, measure):
    """max/min/range over the cycle, or the driving angle (deg, in [0, 360)) where the value is
    largest/smallest."""
    if measure == "max":
        return np.max(values, axis=-1)
    if measure == "min":
        return np.min(values, axis=-1)
    if measure == "range":
        return np.max(values, axis=-1) - np.min(values, axis=-1)
    # NaN rows (machines that cannot close) give argmax 0; the evaluator blanks them anyway
    filled = np.nan_to_num(values, nan=-np.inf if measure == "argmax_deg" else np.inf)
    k = np.argmax(filled, axis=-1) if measure == "argmax_deg" else np.argmin(filled, axis=-1)
    return np.degrees(np.asarray(q_rad)[k]) % 360.0


def line_distance_um(state, point, x, y, angle_deg, shift_um, measure=None):
    """Signed distance d (um) of the point from a line through (x, y) leaning angle_deg from
    the vertical (top towards +x), moved shift_um along its normal n = (cos a, -sin a), at
    every driving angle: shape (machines, angles)."""
    a = angle_deg * DEG
    n = np.cos(a) - 1j * np.sin(a)
    g = x + 1j * y + n * (shift_um * 1e-3)
    return 1e3 * (np.conjugate(n) * (point.p - g)).real


def line_deviation(state, point, x, y, angle_deg, shift_um, measure):
    """Distance d (um) of the point from a line (line_distance_um), reduced over the cycle:
    sum_extremes = max(max d, 0) + max(-min d, 0) (the needle's SumDelta)."""
    d = line_distance_um(state, point, x, y, angle_deg, shift_um)
    if measure == "sum_extremes":
        return np.maximum(np.max(d, axis=-1), 0.0) + np.maximum(-np.min(d, axis=-1), 0.0)
    if measure == "max_abs":
        return np.max(np.abs(d), axis=-1)
    return np.max(d, axis=-1) - np.min(d, axis=-1)


def coordinate(state, point, axis, measure, angle_deg=0.0):
    """x, y, or (axis "along") the coordinate along the direction angle_deg from +x (a slider's
    position along its guide), reduced over the cycle."""
    if axis == "along":
        a = angle_deg * DEG
        return _reduce(point.x * np.cos(a) + point.y * np.sin(a), state.q_rad, measure)
    return _reduce(point.x if axis == "x" else point.y, state.q_rad, measure)


def angle_output(state, measure, angle=None, direction=None):
    base = angle if angle is not None else direction
    # unwrapped over the cycle so a rocker swinging through +-180 deg has its true range
    a = np.degrees(np.unwrap(np.broadcast_to(base.a, state.shape), axis=-1))
    return _reduce(a, state.q_rad, measure)


def _omega(state):
    return state.rpm * 2.0 * np.pi / 60.0


def speed(state, point, measure):
    """Largest speed (m/s) at constant shaft speed: |dp/dq| omega."""
    return np.max(np.abs(point.dp), axis=-1) * _omega(state) * 1e-3


def acceleration(state, point, measure):
    """Largest acceleration (m/s^2) at constant shaft speed: |d2p/dq2| omega^2."""
    return np.max(np.abs(point.ddp), axis=-1) * _omega(state) ** 2 * 1e-3


def transmission(state, group, measure):
    t = state.closures[group].transmission_deg
    return np.min(np.broadcast_to(t, state.shape), axis=-1)


OUTPUT_TYPES: dict[str, OutputType] = {
    "line_deviation": OutputType("line_deviation", {
        "point": ("point", None, None), "x": ("expr", None, None), "y": ("expr", None, None),
        "angle_deg": ("expr", None, None), "shift_um": ("expr", 0.0, None),
        "measure": ("choice", "sum_extremes", LINE_MEASURES)}, line_deviation),
    "coordinate": OutputType("coordinate", {
        "point": ("point", None, None), "axis": ("choice", None, ("x", "y", "along")),
        "angle_deg": ("expr", 0.0, None), "measure": ("choice", None, COORD_MEASURES)},
        coordinate),
    "angle": OutputType("angle", {
        "angle": ("angle", None, None), "direction": ("direction", None, None),
        "measure": ("choice", None, COORD_MEASURES)}, angle_output,
        one_of=(("angle", "direction"),)),
    "speed": OutputType("speed", {"point": ("point", None, None),
                                  "measure": ("choice", "max", ("max",))}, speed, True),
    "acceleration": OutputType("acceleration", {"point": ("point", None, None),
                                                "measure": ("choice", "max", ("max",))},
                               acceleration, True),
    "transmission": OutputType("transmission", {"group": ("group", None, None),
                                                "measure": ("choice", "min", ("min",))},
                               transmission),
}

# custom kinds (type = "custom", kind = NAME): e.g. "presser_contact" from the presser-foot
# module registers itself here
OUTPUTS: dict[str, OutputType] = {}
def providers() -> dict[str, str]:
    """Built-in custom kinds and the module that registers each, imported on first use: the
    OUTPUT_KINDS of the mechanism folders (sewtol.mechanisms). A file can only name a kind that
    is registered or declared there; nothing a file holds names a module."""
    from sewtol.mechanisms import declared

    return declared("OUTPUT_KINDS")


def provide(kind: str) -> OutputType | None:
    """The registered output kind, importing its provider module first if need be."""
    if kind not in OUTPUTS and kind in (known := providers()):
        import importlib

        try:
            importlib.import_module(known[kind])
        except ImportError:
            return None
    return OUTPUTS.get(kind)


def register_output(kind: str, fn: Callable, fields: dict[str, tuple] | None = None,
                    needs_rpm: bool = False) -> OutputType:
    """Add a custom output kind. fn(state, **fields) -> array (m,); fields as in OutputType
    (name -> (kind, default, choices)); a file can then use type = "custom", kind = NAME."""
    ot = OutputType(kind, dict(fields or {}), fn, needs_rpm)
    OUTPUTS[kind] = ot
    return ot
