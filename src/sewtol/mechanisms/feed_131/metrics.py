"""Working figures of the feed dogs, batched over machines.

Lower dog: it works while its tooth is above the plate (y > H). Upper dog: while its tooth is
below the plate plus material thickness (y < H + t). The working stroke runs from entry (the
tooth reaches the working side) to exit. Feed step T = x(entry) - x(exit): positive when the
tooth moves towards -x while it works, which is forward feed with the note's frame (the lower
tooth path then runs counter-clockwise); negative for reverse. Rise: for the lower dog the
height above the plate, for the upper dog the depth below plate + material (how far it presses
in). Crossings and the extreme rise are polished by Newton steps on the analytic velocities.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, replace

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanism.clearance import journals_off_centre
from sewtol.mechanisms.feed_131 import model as fd

N_GRID = 720


@dataclass(frozen=True)
class DogFigures:
    feed_step_mm: np.ndarray
    max_rise_mm: np.ndarray
    max_rise_phi_deg: np.ndarray
    entry_phi_deg: np.ndarray
    exit_phi_deg: np.ndarray
    vertical_travel_mm: np.ndarray
    ok: np.ndarray  # one working stroke per turn and every dyad closes

    def to_dict(self, i: int = 0) -> dict:
        return {k: float(np.ravel(getattr(self, k))[i]) for k in
                ("feed_step_mm", "max_rise_mm", "max_rise_phi_deg", "entry_phi_deg",
                 "exit_phi_deg", "vertical_travel_mm")}


def _tooth(c, phi, key):
    """The tooth, and per point how far the chain is from running: the largest dyad gap (mm),
    or inf at a dead point (a dyad within DEAD_POINT_DEG of collinear)."""
    out = fd.chains(c, phi)
    miss = np.zeros(np.shape(out[key].p))
    for m in out["closure"].values():
        miss = np.maximum(miss, m)
    for g in out["transmission"].values():
        miss = np.where(g < fd.DEAD_POINT_DEG, np.inf, miss)
    return out[key], miss


def _newton(c, key, phi, level=None, iters=6):
    """Newton steps from phi on the tooth's y = level (a crossing) or, without a level, on
    dy/dphi = 0 (an extreme); returns phi and the tooth's motion there."""
    for _ in range(iters):
        q, _ = _tooth(c, phi, key)
        phi = phi - ((q.p.imag - level) / q.dp.imag if level is not None
                     else q.dp.imag / q.ddp.imag)
    return phi, _tooth(c, phi, key)[0]


def polish_extremes(c, key, t, iters=6):
    """Newton steps on dy/dphi = 0 from grid extremes t; returns (phi, y) there."""
    t, q = _newton(c, key, t, iters=iters)
    return t, q.p.imag


def dog_figures(c: dict, which: str, n_grid: int = N_GRID, side: str | None = None) -> DogFigures:
    """Figures of the 'lower' or 'upper' dog for machines in c (columns of shape (n, 1)).

    side: the working side, "above" or "below" the level; default the dog's own (lower above,
    upper below). The other side reads the figures of the return stroke (used to test how the
    source read its plots, feed.readoff_residuals).
    """
    if side not in (None, "above", "below"):
        raise ParameterError("side", "must be 'above' or 'below'", side)
    key = {"lower": "Q1", "upper": "Q2"}[which]
    # np.broadcast takes at most 64 arrays; the machine count is the longest first axis
    n = max((np.shape(v)[0] for v in c.values() if np.ndim(v) > 0), default=1)
    phi = np.linspace(0.0, 2 * np.pi, n_grid, endpoint=False).reshape(1, -1)
    q, miss = _tooth(c, phi, key)
    y = np.broadcast_to(q.p.imag, (n, n_grid))
    level = np.broadcast_to(
        np.asarray(c["plate_mm"], float) + (np.asarray(c["material_mm"], float)
                                            if which == "upper" else 0.0), (n, 1))
    side = side or ("above" if which == "lower" else "below")
    sign = 1.0 if side == "above" else -1.0
    depth = sign * (y - level)  # > 0 on the working side
    work = depth > 0
    nxt = np.roll(work, -1, axis=1)
    entries = ~work & nxt
    exits = work & ~nxt
    ok = (entries.sum(1) == 1) & (exits.sum(1) == 1) & np.all(np.broadcast_to(miss, (n, n_grid)) == 0,
                                                               axis=1)
    h = 2 * np.pi / n_grid
    i_in = np.argmax(entries, axis=1)
    i_out = np.argmax(exits, axis=1)
    phi_in, q_in = _newton(c, key, (i_in[:, None] + 0.5) * h, level)
    phi_out, q_out = _newton(c, key, (i_out[:, None] + 0.5) * h, level)
    # extreme rise on the working side and the travel, polished by Newton on y' = 0
    t, y_work = polish_extremes(c, key, np.argmax(depth, axis=1)[:, None] * h)
    _, y_other = polish_extremes(c, key, np.argmin(depth, axis=1)[:, None] * h)
    rise = np.maximum(sign * (y_work - level), depth.max(axis=1, keepdims=True))
    travel = np.maximum(np.abs(y_work - y_other).ravel(), y.max(axis=1) - y.min(axis=1))
    nan = np.where(ok, 1.0, np.nan)

    def deg(a):
        return np.mod(np.degrees(a.ravel()), 360.0) * nan

    return DogFigures(
        feed_step_mm=(q_in.p.real - q_out.p.real).ravel() * nan,
        max_rise_mm=rise.ravel() * nan,
        max_rise_phi_deg=deg(t),
        entry_phi_deg=deg(phi_in),
        exit_phi_deg=deg(phi_out),
        vertical_travel_mm=travel * nan,
        ok=ok,
    )


@dataclass(frozen=True)
class PairFigures:
    lower: DogFigures
    upper: DogFigures
    differential_ratio: np.ndarray
    mismatch_mm: np.ndarray  # largest |relative horizontal travel| while both grip
    overlap_deg: np.ndarray


def pair_figures(c: dict, n_grid: int = N_GRID, lo: DogFigures | None = None,
                 up: DogFigures | None = None, shift: dict | None = None) -> PairFigures:
    """Both dogs' figures (`lo`, `up`: already computed ones) and how they grip together.
    `shift`: tooth -> callable(phi) giving its move by the journals (`JournalShift`), added to
    the closed form's path (the dogs' entries in `lo`, `up` already moved)."""
    lo = dog_figures(c, "lower", n_grid) if lo is None else lo
    up = dog_figures(c, "upper", n_grid) if up is None else up
    # from the later entry, both dogs grip until the first exit
    start = np.radians(np.where(
        np.mod(up.entry_phi_deg - lo.entry_phi_deg, 360) < 180, up.entry_phi_deg,
        lo.entry_phi_deg))
    span = np.linspace(0, 2 * np.pi, n_grid, endpoint=False).reshape(1, -1)
    phi = np.nan_to_num(start).reshape(-1, 1) + span
    out = fd.chains(c, phi)
    q1, q2 = out["Q1"].p, out["Q2"].p
    if shift:
        q1, q2 = q1 + shift["Q1"](phi), q2 + shift["Q2"](phi)
    x1, y1 = q1.real, q1.imag
    x2, y2 = q2.real, q2.imag
    level = np.asarray(c["plate_mm"], float).reshape(-1, 1) if np.ndim(c["plate_mm"]) else \
        c["plate_mm"]
    both = (y1 > level) & (y2 < level + np.asarray(c["material_mm"], float))
    both[:, 0] = True  # the start is the later entry, on the crossing itself
    grip = np.cumprod(both, axis=1).astype(bool)
    rel = (x2 - x2[:, :1]) - (x1 - x1[:, :1])
    mismatch = np.where(grip, np.abs(rel), 0.0).max(axis=1)
    overlap = grip.sum(axis=1) * 360.0 / n_grid
    ok = lo.ok & up.ok
    return PairFigures(lo, up, np.where(ok, up.feed_step_mm / lo.feed_step_mm, np.nan),
                       np.where(ok, mismatch, np.nan), np.where(ok, overlap, np.nan))


# --- the "feed_dogs" output kind of mechanism files (type = "custom", feed_131/mechanism.toml) --
# The working figures come from the closed form above on the machines' parameter columns (the
# file's groups are the same chains); the file's own status still marks machines that cannot
# run. A step needs one dog, the ratio both, the mismatch the grip pass as well: the figures of
# the last state evaluated are kept (a weak reference: the state itself is not held), so the
# outputs of one block cost one pass per dog.
MEASURES = ("lower_step_mm", "upper_step_mm", "differential_ratio", "mismatch_mm")
_last: list = [lambda: None, {}]


# Joint clearances (sewtol.mechanism.clearance): the closed form does not see a journal off its
# centre, the file's groups do. Where a state's journals are off centre, the figures are found
# on the closed form's path moved by the tooth's displacement delta(phi) = the groups' point -
# the closed form's (periodic linear interpolation between the state's angles; delta is a smooth
# function of a few um): the crossings of the level solve y(phi) + delta_y(phi) = L.
TEETH = {"lower": "Q1", "upper": "Q2"}


class JournalShift:
    """delta(phi) of a tooth for the machines of a state: callable on angles (m, j) (rad)."""

    def __init__(self, state, c, key):
        q = np.asarray(state.q_rad, float)
        closed = fd.chains(c, q.reshape(1, -1))[key].p
        self.q, self.delta = q, np.broadcast_to(state.points[key].p - closed, state.shape)

    def __call__(self, phi):
        phi = np.broadcast_to(np.asarray(phi, float), (self.delta.shape[0], np.shape(phi)[-1]))
        out = np.full(phi.shape, np.nan, complex)
        for i in range(phi.shape[0]):
            ok = np.isfinite(phi[i])
            out[i, ok] = np.interp(phi[i, ok], self.q, self.delta[i], period=2 * np.pi)
        return out


def _moved(c, fig: DogFigures, which: str, shift: JournalShift, iters: int = 6) -> DogFigures:
    """A dog's figures with its step and crossings moved by the journals: Newton steps on
    y(phi) + delta_y(phi) = level from the closed form's crossing (the tooth's slope y' of the
    closed form: delta's own is of the order of the clearances)."""
    key, moved = TEETH[which], {}
    level = np.asarray(c["plate_mm"], float) + (np.asarray(c["material_mm"], float)
                                                if which == "upper" else 0.0)
    level = np.reshape(level, (-1, 1)) if np.ndim(level) else level
    for name in ("entry", "exit"):
        phi = np.radians(getattr(fig, f"{name}_phi_deg")).reshape(-1, 1)
        for _ in range(iters):
            q, _ = _tooth(c, np.nan_to_num(phi), key)
            phi = phi - (q.p.imag + shift(phi).imag - level) / q.dp.imag
        q, _ = _tooth(c, np.nan_to_num(phi), key)
        moved[name] = ((q.p.real + shift(phi).real).ravel(),
                       np.mod(np.degrees(phi.ravel()), 360.0))
    return replace(fig, feed_step_mm=moved["entry"][0] - moved["exit"][0],
                   entry_phi_deg=moved["entry"][1], exit_phi_deg=moved["exit"][1])


def _figures_of(state, which: str):
    if _last[0]() is not state:
        _last[:] = [weakref.ref(state), {}]
    memo = _last[1]
    if which not in memo:
        c = {"dog_bar_program": np.zeros((state.shape[0], 1)), **state.values}
        off = journals_off_centre(state)
        if which == "pair":
            shift = {k: JournalShift(state, c, k) for k in TEETH.values()} if off else None
            memo[which] = pair_figures(c, lo=_figures_of(state, "lower"),
                                       up=_figures_of(state, "upper"), shift=shift)
        else:
            fig = dog_figures(c, which)
            if off:
                fig = _moved(c, fig, which, JournalShift(state, c, TEETH[which]))
            memo[which] = fig
    return memo[which]


def feed_dogs_output(state, measure: str = "lower_step_mm") -> np.ndarray:
    """The registry's form, fn(state, measure) -> array (m,): a dog's feed step, the
    differential ratio or the mismatch while both grip (NaN where a dog does not work)."""
    if measure in ("lower_step_mm", "upper_step_mm"):
        return _figures_of(state, measure.split("_")[0]).feed_step_mm
    if measure == "differential_ratio":
        lo, up = _figures_of(state, "lower"), _figures_of(state, "upper")
        return np.where(lo.ok & up.ok, up.feed_step_mm / lo.feed_step_mm, np.nan)
    return _figures_of(state, "pair").mismatch_mm


def _register() -> None:
    from sewtol.mechanism.outputs import register_output

    register_output("feed_dogs", feed_dogs_output,
                    fields={"measure": ("choice", "lower_step_mm", MEASURES)})


_register()
