"""Polukhin's spatial crank-rocker (RSSR) evaluated for a batch of machines, in Python.

The same mechanism, parameters, tolerances and outputs as
src/sewtol/mechanisms/spatial_crank_rocker/mechanism.toml, written a second time without the file
loader: the independent reference the tests check the file path against (test_spatial.py,
test_seed_files.py). Model and conventions: engine/spatial.py and
docs/spatial_crank_rocker.md. The nominal dimensions are illustrative (no machine's dimensions
are published).

Units: lengths mm, alpha in degrees at this boundary (radians inside); the driving angle is the
crank angle phi, sampled at `samples` equally spaced angles 0, 360/samples, ... deg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol import engine
from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P

# name: (unit, nominal, rule, doc), in the file's order
PARAMETERS = {
    "a": ("mm", 10.0, "positive", "crank AB"),
    "b": ("mm", 60.0, "positive", "coupler BC (ball joint to ball joint)"),
    "c": ("mm", 25.0, "positive", "rocker CD"),
    "e": ("mm", 55.0, "positive", "common normal OQ of the two axes"),
    "f": ("mm", 15.0, "finite", "OA: the crank's plane from O along the crank axis"),
    "g": ("mm", 20.0, "finite", "QD: the rocker's plane from Q along the rocker axis"),
    "alpha": ("deg", 90.0, "finite", "angle between the crank axis and the rocker axis"),
    "branch_psi": ("1", 1.0, "branch", "assembly of the rocker (+1 or -1)"),
}
OUTPUTS = (
    "rocker_swing_deg", "rocker_max_deg", "rocker_min_deg", "crank_at_rocker_max_deg",
    "crank_at_rocker_min_deg", "rocker_tip_speed_max_m_s", "transmission_min_deg",
)
# not in the file (the spec has no angular-rate output): max |psi'| in rad per rad of crank
EXTRA_OUTPUTS = ("rocker_rate_max",)
TOLERANCES = {"illustrative": {"a": 0.02, "b": 0.05, "c": 0.03, "e": 0.05, "f": 0.05,
                               "g": 0.05, "alpha": 0.1}}
SAMPLES = 720
CHUNK = 256
RPM = 4000.0
GROUP = "psi"
# as for the planar dyads: a transmission angle below this during the cycle is a dead point,
# where the real joint can pass to the other assembly
DEAD_POINT_DEG = 1.0
_RULES = {"positive": P.positive, "finite": P.finite, "branch": P.branch}


def nominal() -> dict[str, float]:
    """The illustrative nominal machine, by parameter name."""
    return {name: spec[1] for name, spec in PARAMETERS.items()}


@dataclass(frozen=True)
class Evaluation:
    """Outputs per machine (NaN where the machine failed), status "ok" | "cannot_close" |
    "dead_point" and the group that failed ("" where ok)."""

    outputs: dict
    status: np.ndarray
    failed_group: np.ndarray

    def to_dataframe(self):
        import pandas as pd

        frame = pd.DataFrame(self.outputs)
        frame["status"] = self.status
        frame["failed_group"] = self.failed_group
        return frame


def _batch(values: dict) -> tuple[dict[str, np.ndarray], int]:
    unknown = sorted(set(values) - set(PARAMETERS))
    if unknown:
        raise ParameterError(unknown[0], f"is not a parameter of spatial_crank_rocker (valid: "
                             f"{', '.join(PARAMETERS)})", values[unknown[0]])
    arrays = {}
    for name, (_, nom, rule, _) in PARAMETERS.items():
        v = np.asarray(values.get(name, nom), float)
        if v.ndim > 1:
            raise ParameterError(name, "must be a number or a 1-D array (one value per machine)",
                                 f"array of shape {v.shape}")
        _RULES[rule](name, v)
        arrays[name] = v
    batch = [n for n, v in arrays.items() if v.ndim == 1]
    m = arrays[batch[0]].size if batch else 1
    for name in batch:
        if arrays[name].size != m:
            raise ParameterError(name, f"must have as many values as {batch[0]} ({m})",
                                 f"{arrays[name].size} values")
    return {n: np.broadcast_to(v, (m,)) for n, v in arrays.items()}, m


def evaluate(values: dict, samples: int = SAMPLES, rpm: float = RPM) -> Evaluation:
    """The file's outputs (plus EXTRA_OUTPUTS) for a batch of machines.

    `values` maps parameter names to numbers or equal-length 1-D arrays (one per machine);
    missing parameters take their nominal values. Angle outputs are taken over the sampled cycle
    from psi unwrapped along the turn (starting from the first sample's value in (-180, 180]);
    argmax/argmin give the sampled crank angle in [0, 360) deg.
    """
    if int(samples) != samples or samples < 3:
        raise ParameterError("samples", "must be an integer >= 3", samples)
    if not np.isfinite(rpm) or rpm <= 0:
        raise ParameterError("rpm", "must be a positive number", rpm)
    p, m = _batch(values)
    q = 2.0 * np.pi * np.arange(int(samples)) / samples
    parts = [_chunk(p, slice(lo, lo + CHUNK), q, rpm) for lo in range(0, m, CHUNK)]
    status = np.concatenate([s for s, _ in parts])
    out = {k: np.concatenate([o[k] for _, o in parts]) for k in OUTPUTS + EXTRA_OUTPUTS}
    return Evaluation(out, status, np.where(status == "ok", "", GROUP))


def _chunk(p: dict, rows: slice, q: np.ndarray, rpm: float):
    """Status and outputs of the machines `rows` (a few hundred at a time keeps the
    (machines, samples) arrays in cache)."""
    col = {n: v[rows, None] for n, v in p.items()}
    psi, closure = engine.spatial_rocker(
        engine.driving_angle(q), col["a"], col["b"], col["c"], col["e"], col["f"], col["g"],
        np.radians(col["alpha"]), col["branch_psi"])
    cannot = np.any(closure.miss_mm > 0.0, axis=1)
    with np.errstate(invalid="ignore"):
        worst = np.min(closure.transmission_deg, axis=1)
    dead = ~cannot & (worst < DEAD_POINT_DEG)
    ok = ~cannot & ~dead
    status = np.where(cannot, "cannot_close", np.where(dead, "dead_point", "ok"))

    turned = np.unwrap(np.where(ok[:, None], psi.a, 0.0), axis=1)
    rate = np.abs(np.where(ok[:, None], psi.da, 0.0))
    omega = rpm * 2.0 * np.pi / 60.0
    i_max, i_min = np.argmax(turned, axis=1), np.argmin(turned, axis=1)
    out = {
        "rocker_swing_deg": np.degrees(np.ptp(turned, axis=1)),
        "rocker_max_deg": np.degrees(turned.max(axis=1)),
        "rocker_min_deg": np.degrees(turned.min(axis=1)),
        "crank_at_rocker_max_deg": np.degrees(q[i_max]),
        "crank_at_rocker_min_deg": np.degrees(q[i_min]),
        "rocker_tip_speed_max_m_s": p["c"][rows] * 1e-3 * omega * rate.max(axis=1),
        "transmission_min_deg": worst,
        "rocker_rate_max": rate.max(axis=1),
    }
    return status, {k: np.where(ok, v, np.nan) for k, v in out.items()}
