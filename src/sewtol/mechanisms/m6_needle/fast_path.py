"""The m6_needle fast path: the needle travel exactly, as the protocol's kernel plug-in.

The file's travel takes J's extremes on the sampled crank angles; the model has them in closed
form (`extremes`, `travel_mm`) for a slotted-lever rocker (crank shorter than pivot_mm -
|slot_offset_mm|) whose rod reaches the guide over the whole swing; any other machine keeps the
file's own evaluation, so both paths agree on which machines run. The bound (`kernel_bound`):
the sampled extreme falls short by at most max|s''| (h/2)^2 / 2 (h the sample step; s'' exact,
on a FINE grid over 1.5 samples either side) plus POSITION_TOL_MM at each end (this folder's
README.md).
"""

from __future__ import annotations

import numpy as np

from sewtol.mechanism.fast_paths import CHECK_SEED, PERTURBED, POSITION_TOL_MM, FastPath

FINE = 301
POINTS = ("A", "B", "J")


def travel_outputs(mech) -> list[str]:
    """The file's travel outputs: J's coordinate along a direction, its range over the turn."""
    return [o.name for o in mech.outputs if o.type == "coordinate"
            and o.fields.get("point") == "J" and o.fields.get("axis") == "along"
            and o.fields.get("measure") == "range"]


def _columns(mech, values) -> tuple[dict, int]:
    """The model's columns (n, 1) of machines `values` (the rest nominal): the file's parameters,
    the model's defaults for the rest (phase and sense do not move J's extremes)."""
    import dataclasses

    from sewtol.mechanisms.m6_needle.model import M6Needle

    cols, n = mech.columns(values)
    return {f.name: np.broadcast_to(np.asarray(cols.get(f.name, f.default), float), (n, 1))
            for f in dataclasses.fields(M6Needle)}, n


def _sin_range(lo, hi):
    """Smallest and largest sin over the intervals [lo, hi] (rad)."""
    def holds(peak):  # the interval holds peak + 2 pi k for some k
        return np.ceil((lo - peak) / (2 * np.pi)) <= np.floor((hi - peak) / (2 * np.pi))

    ends = np.stack([np.sin(lo), np.sin(hi)])
    return (np.where(holds(-np.pi / 2), -1.0, ends.min(axis=0)),
            np.where(holds(np.pi / 2), 1.0, ends.max(axis=0)))


def runs_exactly(c: dict, lo, hi) -> np.ndarray:
    """Machines the closed form covers: a rocker (crank < pivot_mm - |slot_offset_mm|: the block
    never leaves the slot) whose rod reaches the guide at every lever angle of the swing [lo, hi]
    (the pin B's distance from the guide line, O2's plus arm sin(f + arm - guide), at most rod)."""
    deg = np.pi / 180.0
    g = np.exp(1j * c["guide_deg"] * deg)
    o2 = c["pivot_mm"] * np.exp(1j * c["pivot_deg"] * deg)
    base = (np.conjugate(g) * (o2 - (c["guide_x_mm"] + 1j * c["guide_y_mm"]))).imag
    turn = (c["arm_deg"] - c["guide_deg"]) * deg
    s_lo, s_hi = _sin_range(lo + turn, hi + turn)
    across = np.maximum(np.abs(base + c["arm_mm"] * s_lo), np.abs(base + c["arm_mm"] * s_hi))
    rocker = c["crank_mm"] < c["pivot_mm"] - np.abs(c["slot_offset_mm"])
    with np.errstate(invalid="ignore"):
        return (rocker & (across <= c["rod_mm"]))[:, 0]


def travel_kernel(mech, values) -> dict[str, np.ndarray]:
    """The exact travel (mm) of machines `values` (parameter -> array; the rest nominal) for
    every travel output of the file; the file's own evaluation where the closed form does not
    cover a machine (NaN where it does not run)."""
    from sewtol.mechanisms.m6_needle import model as m6

    c, n = _columns(mech, values)
    with np.errstate(invalid="ignore"):
        lo, hi = m6.lever_extremes(c)
        j_lo, j_hi = m6.extremes(c)
        travel = np.abs(j_hi - j_lo)[:, 0]
    names = travel_outputs(mech)
    out = {k: travel.copy() for k in names}
    other = ~runs_exactly(c, lo, hi)
    if other.any():
        rest = {k: np.broadcast_to(np.asarray(v, float), (n,))[other]
                for k, v in (values or {}).items()}
        ev = mech.evaluate(rest, names)
        for k in names:
            out[k][other] = ev.outputs[k]
    return out


def travel_kernel_bound(mech, values) -> dict[str, np.ndarray]:
    """How far below the exact travel the file's sampled one may lie, per machine (mm)."""
    from sewtol.mechanisms.m6_needle import model as m6

    c, n = _columns(mech, values)
    h = 2 * np.pi / mech.samples
    u = np.conjugate(np.exp(1j * c["guide_deg"] * np.pi / 180.0))
    with np.errstate(invalid="ignore"):
        ok = runs_exactly(c, *m6.lever_extremes(c))
        q = mech.angles_rad()
        s = np.where(ok[:, None], (m6.chain(c, q)["J"].p * u).real, 0.0)
        bound = np.zeros(n)
        # the sample nearest an extreme is the sampled extreme or its neighbour: search
        # |s''| within 1.5 steps of it, on a FINE grid
        for k in (np.argmax(s, axis=1), np.argmin(s, axis=1)):
            near = q[k][:, None] + np.linspace(-1.5 * h, 1.5 * h, FINE)[None, :]
            s2 = np.abs((m6.chain(c, near)["J"].ddp * u).real)
            bound += np.where(ok, np.max(s2, axis=1), 0.0)
    bound = np.where(ok, (h / 2) ** 2 / 2 * bound + 2 * POSITION_TOL_MM, 0.0)
    return {k: bound for k in travel_outputs(mech)}


def check_m6_needle(mech) -> str:
    """"" when the file is the model's chain: its parameters, the points A, B, J equal to the
    model's (POSITION_TOL_MM) on the nominal and PERTURBED machines, and its travel outputs run
    along the guide (angle_deg = guide_deg there)."""
    from sewtol.mechanisms.m6_needle import model as m6

    names = ("crank_mm", "pivot_mm", "pivot_deg", "slot_offset_mm", "arm_deg", "arm_mm",
             "rod_mm", "guide_x_mm", "guide_y_mm", "guide_deg", "rod_branch")
    missing = [k for k in names if k not in mech.parameter_names]
    if missing:
        return "parameters missing: " + ", ".join(missing)
    lacking = [p for p in POINTS if p not in [g.name for g in mech.groups]]
    if lacking:
        return "points missing: " + ", ".join(lacking)
    if not travel_outputs(mech):
        return "no travel output (a coordinate of J, axis along, measure range)"
    rng = np.random.default_rng(CHECK_SEED)
    nominal = mech.nominal_values()
    values = {k: nominal[k] + np.concatenate([[0.0], rng.uniform(-0.05, 0.05, PERTURBED)])
              for k in names if k != "rod_branch"}
    state = mech.state(values)
    built = m6.chain(_columns(mech, values)[0], mech.angles_rad()[None, :])
    for p in POINTS:
        d = np.abs(built[p].p - state.points[p].p)
        if not np.nanmax(d) <= POSITION_TOL_MM:
            return f"{p} differs by {np.nanmax(d):.3g} mm > {POSITION_TOL_MM:g} mm"
    cols, _ = mech.columns(values)
    for o in (o for o in mech.outputs if o.name in travel_outputs(mech)):
        a = o.fields.get("angle_deg", 0.0)
        if not np.allclose(a(cols) if callable(a) else a, cols["guide_deg"], rtol=0, atol=1e-12):
            return f"output {o.name} is not along the guide (angle_deg is not guide_deg)"
    return ""


def _plugins():
    from sewtol.protocol import Plugins

    return Plugins(kernel=travel_kernel, kernel_outputs=("travel_mm",),
                   kernel_bound=travel_kernel_bound, name="m6_needle")


FAST_PATH = FastPath("m6_needle", POINTS, check_m6_needle, _plugins())
