"""The exact joint optimum of the needle's compensators per machine.

Compensators and their boxes (low, high): `beta` (deg), `guide_shift_um` (um, the setting of
the guide's lateral shift; it replaces the machine's own value) and `guide_angle` (deg, the
guide turned about its point N1; the box is around the machine's own angle: own + low .. own +
high). The minimum is the global one in the box:

- beta slides a window of fixed width along one coupler curve d(psi): mechanisms/needle_208/kernels/window.py
  (numba) and `_reference_beta` here (numpy) solve that sliding-window problem exactly;
- the guide shift t turns SumDelta into max(F - G, F - T1, T0 - G), so it is solved inside the
  same search, and t's optimal range at beta* is [max(G, T0), min(F, T1)];
- the guide angle and CD change d(psi) itself; each is an outer search (a grid over its box,
  then golden section around each machine's three best local minima of the
  grid) around the exact inner optimum, every machine's whole search in one kernel call
  (kernels/window.py: outer_batch): checked against a dense grid in the tests, not proven
  global. One outer compensator at a time.

Where the optimum is a plateau (SumDelta within `tol_um` of the minimum over an interval) the
range is reported and its centre is the setting.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd

if TYPE_CHECKING:
    import pandas as pd

COMPENSATORS = ("beta", "guide_shift_um", "guide_angle", "CD")
DEFAULT_BOXES = {"beta": (10.0, 35.0), "guide_shift_um": (-100.0, 100.0),
                 "guide_angle": (-0.1, 0.1), "CD": (-0.3, 0.3)}
# compensators that change d(psi) itself: an outer search around the exact inner optimum; their
# box and setting are relative to the machine's own value (deg, mm)
OUTER = ("guide_angle", "CD")
OUTER_GRID = {"guide_angle": 21, "CD": 61}  # default grid points of the outer search
STATUS = ("ok", "cannot assemble", "dead point")
OUTER_SEARCHES = ("fused", "loop")
_KERNEL_COLUMN = {"guide_angle": 13, "CD": 3}  # kernels.FIELDS
PLATEAU_TOL_UM = 1e-3


@dataclass(frozen=True)
class AdjustResult:
    """Per machine: the optimum SumDelta (um) and Delta+/Delta- at the chosen settings, each
    compensator's setting (the centre of its plateau range), the range, at-bound flags and a
    status ("ok", "cannot assemble", "dead point"; the figures are NaN unless ok).

    `min_total_um` is the minimum itself; `total_um` is SumDelta at the reported settings (the
    plateau centre), within `tol_um` of it.
    """

    total_um: np.ndarray
    plus_um: np.ndarray
    minus_um: np.ndarray
    min_total_um: np.ndarray
    settings: dict[str, np.ndarray]
    low: dict[str, np.ndarray]
    high: dict[str, np.ndarray]
    at_bound: dict[str, np.ndarray]
    status: np.ndarray
    boxes: dict[str, tuple[float, float]]
    tol_um: float

    def to_dataframe(self) -> pd.DataFrame:
        import pandas as pd

        cols = {"status": self.status, "total_um": self.total_um, "plus_um": self.plus_um,
                "minus_um": self.minus_um, "min_total_um": self.min_total_um}
        for k in self.settings:
            cols[k] = self.settings[k]
            cols[f"{k}_low"] = self.low[k]
            cols[f"{k}_high"] = self.high[k]
            cols[f"{k}_at_bound"] = self.at_bound[k]
        return pd.DataFrame(cols)


def check_boxes(active: dict) -> dict[str, tuple[float, float]]:
    boxes = {}
    for name, box in active.items():
        if name not in COMPENSATORS:
            raise ParameterError(name, "unknown compensator; valid names are "
                                 + ", ".join(COMPENSATORS), name)
        if box is None:
            box = DEFAULT_BOXES[name]
        try:
            lo, hi = (float(v) for v in box)
        except (TypeError, ValueError):
            raise ParameterError(name, "box must be (low, high)", box) from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise ParameterError(name, "box must be finite with low <= high", box)
        if name == "beta" and not lo < hi:
            raise ParameterError(name, "box must have low < high", box)
        boxes[name] = (lo, hi)
    if "beta" not in boxes:
        raise ParameterError("compensators", "must include beta (the per-machine adjustment)",
                             sorted(active))
    return boxes


def _rocker(c, feas=None):
    """Rocker interval (rad) where L-M-A runs (NaN elsewhere) and its status code."""
    f = feas if feas is not None else nm.feasibility(c)
    miss_ok = f.miss_LMA_mm == 0
    lma_ok = miss_ok & (f.transmission_LMA_deg >= nd.DEAD_POINT_DEG)
    r_lo = np.where(lma_ok, f.lo, np.nan)
    r_hi = np.where(lma_ok, f.hi, np.nan)
    code = np.where(lma_ok, 0, np.where(miss_ok, 2, 1))
    return r_lo, r_hi, code


def optimise(c: dict[str, np.ndarray], active: dict[str, tuple[float, float] | None],
             engine: str = "numba", h_deg: float = 2.0, tol_um: float = PLATEAU_TOL_UM,
             angle_grid: int | None = None, feas: nm.Feasibility | None = None,
             outer_search: str = "fused", cutoff_um: np.ndarray | None = None) -> AdjustResult:
    """Joint optimum of the active compensators for machines given as parameter columns
    (c from needle_208.metrics.columns, each (n, 1)); `active` maps compensator names to their
    (low, high) box (None: DEFAULT_BOXES). feas: needle_208.metrics.feasibility(c) if known (the
    rocker interval does not depend on any compensator).

    The minimum is global in the box for beta and the guide shift (an exact sliding-window
    solution); the guide angle or CD, at most one of them, is an outer search around it.

    Parameters
    ----------
    c : dict of numpy.ndarray
        The machines as parameter columns of shape (n, 1), by `Needle208` field name: e.g.
        ``c, n = sewtol.mechanisms.needle_208.metrics.columns(machine)`` (mm, deg, um).
    active : dict
        Compensator name (``"beta"``, ``"guide_shift_um"``, ``"guide_angle"``, ``"CD"``) to
        its box ``(low, high)``, or None for the default box: beta 10 ... 35 deg (absolute),
        the shift -100 ... 100 um (absolute), the angle +/-0.1 deg and CD +/-0.3 mm (relative
        to the machine's own value).
    engine : str
        ``"numba"`` (the kernel) or ``"numpy"`` (the reference implementation).
    h_deg : float
        The node spacing of the kernel's Hermite surrogate of d along the rocker (deg); 2 deg
        keeps its error near 4e-4 um.
    tol_um : float
        Settings within this much (um) of the minimum form the plateau reported.
    angle_grid : int or None
        Grid points of the outer search (None: 21 for the guide angle, 61 for CD).
    feas : Feasibility or None
        ``needle_208.metrics.feasibility(c)`` if already known.
    outer_search : str
        How the guide angle's or CD's outer search runs with the numba engine: ``"fused"``
        (every machine's whole search in one kernel call, window.outer_batch, each local
        minimum of the grid refined by the golden section of before: the same numbers) or
        ``"loop"`` (the batched Python loop over trial values it was written as,
        kept as the reference; the numpy engine always uses it). tests/test_adjust.py holds
        them to each other.
    cutoff_um : numpy.ndarray or None
        Per machine (the guide angle's fused search): where the grid proves no angle reaches
        it, the grid's best angle (min_total_um then above it, not the minimum).

    Returns
    -------
    AdjustResult
        Per machine: the minimum SumDelta (um), SumDelta, Delta+ and Delta- at the settings,
        each compensator's setting (its plateau's centre), plateau range and at-bound flag,
        and the status (``"ok"``, ``"cannot assemble"``, ``"dead point"``).

    Raises
    ------
    ParameterError
        For an unknown compensator, a bad box, an unknown engine, or both outer compensators.
    """
    if engine not in ("numba", "numpy"):
        raise ParameterError("engine", "must be 'numba' or 'numpy'", engine)
    if outer_search not in OUTER_SEARCHES:
        raise ParameterError("outer_search", f"must be one of {', '.join(OUTER_SEARCHES)}",
                             outer_search)
    boxes = check_boxes(active)
    r_lo, r_hi, code = _rocker(c, feas)
    outer = [k for k in OUTER if k in boxes]
    if len(outer) > 1:
        raise ParameterError("compensators", "at most one of guide_angle, CD at a time",
                             sorted(boxes))
    if outer:
        if engine == "numba" and outer_search != "loop":
            return _with_outer_fused(outer[0], c, boxes, r_lo, r_hi, code, engine, h_deg,
                                     tol_um, angle_grid, cutoff_um)
        return _with_outer(outer[0], c, boxes, r_lo, r_hi, code, engine, h_deg, tol_um,
                           angle_grid)
    out = _inner(c, boxes, r_lo, r_hi, engine, h_deg, tol_um)
    return _result(out, boxes, code, tol_um)


def _inner(c, boxes, r_lo, r_hi, engine, h_deg, tol_um):
    blo, bhi = boxes["beta"]
    shift = "guide_shift_um" in boxes
    slo, shi = boxes.get("guide_shift_um", (0.0, 0.0))
    if engine == "numpy":
        return _reference(c, r_lo, r_hi, blo, bhi, slo, shi, shift, tol_um)
    from sewtol.mechanisms.needle_208 import kernels

    return kernels.optimise_batch(kernels.pack(c), np.ascontiguousarray(r_lo, float),
                                  np.ascontiguousarray(r_hi, float), blo, bhi, slo, shi, shift,
                                  h_deg, tol_um)


def _result(out, boxes, code, tol_um, outer=None) -> AdjustResult:
    status_code = np.where(code > 0, code, out[:, 9]).astype(int)
    ok = status_code == 0
    nan = np.full(len(out), np.nan)

    def col(j):
        return np.where(ok, out[:, j], nan)

    settings = {"beta": col(0)}
    low = {"beta": col(4)}
    high = {"beta": col(5)}
    if "guide_shift_um" in boxes:
        settings["guide_shift_um"], low["guide_shift_um"], high["guide_shift_um"] = (
            col(6), col(7), col(8))
    if outer is not None:
        name, vals = outer
        settings[name], low[name], high[name] = (np.where(ok, v, nan) for v in vals)
    at_bound = {}
    for k, (blo, bhi) in boxes.items():
        eps = 1e-9 * max(1.0, abs(blo), abs(bhi))
        at_bound[k] = ok & ((low[k] <= blo + eps) | (high[k] >= bhi - eps))
    return AdjustResult(total_um=col(1), plus_um=col(2), minus_um=col(3), min_total_um=col(11),
                        settings=settings, low=low, high=high, at_bound=at_bound,
                        status=np.array(STATUS, dtype=object)[status_code], boxes=boxes,
                        tol_um=float(tol_um))


# --- the guide angle or CD: an outer search around the exact inner optimum ---------------------

def cd_and_angle(c: dict[str, np.ndarray], active: dict, cd_grid, feas=None,
                 angle_grid: int = 21, h_deg: float = 2.0, tol_um: float = PLATEAU_TOL_UM):
    """CD's and the guide angle's offsets (mm, deg) at the joint optimum of beta, the guide shift
    (if active), the guide angle and CD, and that least SumDelta (um), per machine (CD, angle,
    SumDelta): kernels.window.cd_angle_batch (CD on cd_grid, then golden section; at each CD
    the angle on angle_grid points, its local minima refined by kink searches). `active` as
    optimise's, with both guide_angle and CD."""
    from sewtol.mechanisms.needle_208 import kernels as KB

    boxes = check_boxes(active)
    r_lo, r_hi, _ = _rocker(c, feas)
    blo, bhi = boxes["beta"]
    slo, shi = boxes.get("guide_shift_um", (0.0, 0.0))
    alo, ahi = boxes["guide_angle"]
    cd_grid = np.asarray(cd_grid, float)
    out = KB.cd_angle_batch(KB.pack(c), np.ascontiguousarray(r_lo, float).reshape(-1),
                            np.ascontiguousarray(r_hi, float).reshape(-1), blo, bhi, slo, shi,
                            "guide_shift_um" in boxes, cd_grid, alo, ahi, int(angle_grid), h_deg,
                            tol_um, 5e-6 * (cd_grid[-1] - cd_grid[0]), 1e-6 * (ahi - alo))
    return out[:, 0], out[:, 2], out[:, 1]


def _with_outer_fused(name, c, boxes, r_lo, r_hi, code, engine, h_deg, tol_um, angle_grid,
                      cutoff_um=None):
    """_with_outer's search with every machine's grid and refinements in one numba call
    (kernels.window.outer_batch: golden sections as _with_outer), then the
    full inner optimum at the setting found."""
    from sewtol.mechanisms.needle_208 import kernels as KB

    alo, ahi = boxes[name]
    if ahi == alo:
        return _with_outer(name, c, boxes, r_lo, r_hi, code, engine, h_deg, tol_um, angle_grid)
    inner_boxes = {k: v for k, v in boxes.items() if k != name}
    own = np.broadcast_to(np.asarray(c[name], float).reshape(-1), r_lo.shape).copy()
    n_grid = int(angle_grid) if angle_grid else OUTER_GRID[name]
    grid = np.linspace(alo, ahi, max(n_grid, 3))
    cc = dict(c)
    cc[name] = own.reshape(-1, 1)
    blo, bhi = inner_boxes["beta"]
    shift = "guide_shift_um" in inner_boxes
    slo, shi = inner_boxes.get("guide_shift_um", (0.0, 0.0))
    lo = np.ascontiguousarray(r_lo, float).reshape(-1)
    hi = np.ascontiguousarray(r_hi, float).reshape(-1)
    best_rel = KB.outer_batch(KB.pack(cc), _KERNEL_COLUMN[name], lo, hi, blo, bhi, slo, shi,
                              shift, grid, h_deg, tol_um, 3,
                              None if cutoff_um is None else np.asarray(cutoff_um, float))
    cc[name] = (own + best_rel).reshape(-1, 1)
    out = _inner(cc, inner_boxes, r_lo, r_hi, engine, h_deg, tol_um)
    return _result(out, boxes, code, tol_um, (name, (best_rel, best_rel, best_rel)))


def _with_outer(name, c, boxes, r_lo, r_hi, code, engine, h_deg, tol_um, angle_grid):
    """Outer search over `name` (relative to each machine's own value): a grid over the box,
    then golden section around the best grid point of each machine."""
    alo, ahi = boxes[name]
    inner_boxes = {k: v for k, v in boxes.items() if k != name}
    own = np.broadcast_to(np.asarray(c[name], float).reshape(-1), r_lo.shape).copy()
    n = own.size

    def run(rel):
        cc = dict(c)
        cc[name] = (own + rel).reshape(-1, 1)
        return _inner(cc, inner_boxes, r_lo, r_hi, engine, h_deg, tol_um)

    def minimum_at(rel, rows):
        """The inner minimum (column 11) at `rel` of the machines `rows` (a mask), NaN for
        the others: every machine's optimum is its own, so a subset gives the same numbers,
        and the golden sections below skip the machines whose result they discard."""
        if rows.all():
            return run(rel)[:, 11]
        got = np.full(n, np.nan)
        if rows.any():
            cc = {k: (v[rows] if np.shape(v)[:1] == (n,) else v) for k, v in c.items()}
            cc[name] = (own[rows] + rel[rows]).reshape(-1, 1)
            got[rows] = _inner(cc, inner_boxes, r_lo[rows], r_hi[rows], engine, h_deg,
                               tol_um)[:, 11]
        return got

    if ahi == alo:
        out = run(np.full(n, alo))
        return _result(out, boxes, code, tol_um, (name, (np.full(n, alo),) * 3))
    n_grid = int(angle_grid) if angle_grid else OUTER_GRID[name]
    grid = np.linspace(alo, ahi, max(n_grid, 3))
    vals = np.stack([run(np.full(n, g))[:, 11] for g in grid], axis=1)
    vals = np.where(np.isnan(vals), np.inf, vals)
    # golden section around each of the best three local minima of the grid
    left_n = np.concatenate([np.full((n, 1), np.inf), vals[:, :-1]], axis=1)
    right_n = np.concatenate([vals[:, 1:], np.full((n, 1), np.inf)], axis=1)
    score = np.where((vals <= left_n) & (vals <= right_n), vals, np.inf)
    rows = np.arange(n)
    i0 = np.argmin(vals, axis=1)
    best_rel = grid[i0]
    best_val = vals[rows, i0]
    invphi = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(3):
        i = np.argmin(score, axis=1)
        has = np.isfinite(score[rows, i])
        score[rows, i] = np.inf
        if not has.any():
            break
        a = grid[np.maximum(i - 1, 0)]
        b = grid[np.minimum(i + 1, grid.size - 1)]
        x1 = b - invphi * (b - a)
        x2 = a + invphi * (b - a)
        # a machine without an i-th local minimum is carried along (its bracket narrows as
        # every other's, so the loop ends when it did) but never evaluated: its result is
        # discarded below (better = has & ...)
        f1 = minimum_at(x1, has)
        f2 = minimum_at(x2, has)
        for _ in range(40):
            if np.all(b - a < 1e-9):
                break
            left = ~(f1 >= f2)  # NaN counts as worse
            b = np.where(left, x2, b)
            a = np.where(left, a, x1)
            nx1 = np.where(left, b - invphi * (b - a), x2)
            nx2 = np.where(left, x1, a + invphi * (b - a))
            nf1 = np.where(left, np.nan, f2)
            nf2 = np.where(left, f1, np.nan)
            x1, x2 = nx1, nx2
            fresh = minimum_at(np.where(left, x1, x2), has)
            f1 = np.where(left, fresh, nf1)
            f2 = np.where(left, nf2, fresh)
        for xx, ff in ((x1, f1), (x2, f2)):
            better = has & (ff < best_val)  # never worse than the grid itself
            best_val = np.where(better, ff, best_val)
            best_rel = np.where(better, xx, best_rel)
    out = run(best_rel)
    return _result(out, boxes, code, tol_um, (name, (best_rel, best_rel, best_rel)))


# --- the numpy reference: exact local extrema of d(psi), a fine window grid, golden polish -----

def _d_of_psi(c, psi):
    """d (mm, guide shift removed), d', d'' at psi (n, k) through the engine (beta = 0)."""
    from sewtol import engine

    cz = nm.with_values(c, beta=np.zeros(len(psi)))
    E = nd.chain_from_rocker(cz, engine.driving_angle(psi))["E"]
    cz = nm.with_values(cz, guide_shift_um=np.zeros(len(psi)))
    _, n, G = nd.guide_frame(cz)
    return nd.project(n, E.p - G), nd.project(n, E.dp), nd.project(n, E.ddp)


def _reference(c, r_lo, r_hi, blo, bhi, slo, shi, shift, tol_um, n_psi=1441, n_u=1001):
    """numpy reference (slow, independent of the kernel's surrogate): the local extrema of the
    true d over the reachable psi range, located by bisection on d'; F(u), G(u) exactly as the ends and
    the extrema inside the window; SumDelta on a grid of n_u windows; golden section around
    every grid descent. Windows that pass a dead point are scored infinite (feasibility as
    needle_208.metrics.feasibility, evaluated for each window)."""
    n = r_lo.size
    out = np.full((n, 12), np.nan)
    s = np.asarray(c["beta_sense"], float).reshape(-1)
    s = np.broadcast_to(s, (n,))
    deg = np.pi / 180
    lo = r_lo.reshape(-1)
    w = (r_hi - r_lo).reshape(-1)
    u0 = lo + np.minimum(s * blo, s * bhi) * deg
    u1 = lo + np.maximum(s * blo, s * bhi) * deg
    good = np.isfinite(lo)
    gshift = np.broadcast_to(np.asarray(c["guide_shift_um"], float).reshape(-1), (n,)) * 1e-3
    T0 = np.where(shift, slo * 1e-3, gshift)
    T1 = np.where(shift, shi * 1e-3, gshift)
    u0g, u1g, wg = (np.where(good, v, 0.0) for v in (u0, u1, w))
    psi = u0g[:, None] + (u1g + wg - u0g)[:, None] * np.linspace(0, 1, n_psi)[None, :]
    f, f1, f2 = _d_of_psi(c, psi)
    # every local extremum: a sign change of d' between nodes (0.05 deg apart over the ~72-deg
    # reachable range), located by bisection on the exact d'
    sc = np.sign(f1[:, :-1]) != np.sign(f1[:, 1:])
    ii, jj = np.nonzero(sc & np.isfinite(f1[:, :-1]) & np.isfinite(f1[:, 1:]))
    a = psi[ii, jj]
    b = psi[ii, jj + 1]
    t = 0.5 * (a + b)
    for _ in range(60):  # bisection on d' (robust), then the value
        _, g1, _ = _d_of_psi({k: np.asarray(v)[ii] if np.ndim(v) and np.shape(v)[0] == n
                              else v for k, v in c.items()}, t[:, None])
        g1 = g1[:, 0]
        same = np.sign(g1) == np.sign(f1[ii, jj])
        a = np.where(same, t, a)
        b = np.where(same, b, t)
        t = 0.5 * (a + b)
    sub = {k: np.asarray(v)[ii] if np.ndim(v) and np.shape(v)[0] == n else v
           for k, v in c.items()}
    ext_v = _d_of_psi(sub, t[:, None])[0][:, 0] if ii.size else np.zeros(0)
    counts = np.bincount(ii, minlength=n)
    kmax = max(int(counts.max()) if n else 0, 1)
    ext_t = np.full((n, kmax), np.nan)
    ext_f = np.full((n, kmax), np.nan)
    slot = np.arange(ii.size) - np.concatenate([[0], np.cumsum(counts)[:-1]])[ii]
    ext_t[ii, slot] = t
    ext_f[ii, slot] = ext_v
    # feasible windows: every psi of the window passes the dead-point test
    from sewtol.mechanisms.needle_208.kernels import window as KW

    def S(u):
        """SumDelta (mm), F, G for windows starting at u (n, k); inf where infeasible."""
        fa, _, _ = _d_of_psi(c, u)
        fb, _, _ = _d_of_psi(c, u + wg[:, None])
        inside = (ext_t[:, None, :] > u[..., None]) & (ext_t[:, None, :] < (u + wg[:, None])[..., None])
        emax = np.where(inside, ext_f[:, None, :], -np.inf).max(axis=-1)
        emin = np.where(inside, ext_f[:, None, :], np.inf).min(axis=-1)
        F = np.maximum(np.maximum(fa, fb), emax)
        G = np.minimum(np.minimum(fa, fb), emin)
        val = np.maximum(F - G, np.maximum(F - T1[:, None], T0[:, None] - G))
        feas = _window_feasible(c, u, wg)
        return np.where(feas & np.isfinite(val), val, np.inf), F, G

    ug = u0g[:, None] + (u1g - u0g)[:, None] * np.linspace(0, 1, n_u)[None, :]
    sg, _, _ = S(ug)
    du = (u1g - u0g) / (n_u - 1)
    best = sg.min(axis=1)
    ubest = ug[np.arange(n), sg.argmin(axis=1)]
    # golden section around every grid descent (all of them, in rounds of one per machine)
    left = np.concatenate([np.full((n, 1), np.inf), sg[:, :-1]], axis=1)
    right = np.concatenate([sg[:, 1:], np.full((n, 1), np.inf)], axis=1)
    desc = (sg <= left) & (sg <= right) & ((sg < left) | (sg < right)) & np.isfinite(sg)
    invphi = (np.sqrt(5.0) - 1.0) / 2.0
    while desc.any():
        j = np.argmax(desc, axis=1)
        has = desc[np.arange(n), j]
        desc[np.arange(n), j] = False
        a = np.clip(ug[np.arange(n), j] - du, u0g, u1g)[:, None]
        b = np.clip(ug[np.arange(n), j] + du, u0g, u1g)[:, None]
        x1 = b - invphi * (b - a)
        x2 = a + invphi * (b - a)
        g1 = S(x1)[0]
        g2 = S(x2)[0]
        for _ in range(45):
            lft = g1 < g2
            b = np.where(lft, x2, b)
            a = np.where(lft, a, x1)
            nx1 = np.where(lft, b - invphi * (b - a), x2)
            nx2 = np.where(lft, x1, a + invphi * (b - a))
            ng1 = np.where(lft, 0.0, g2)
            ng2 = np.where(lft, g1, 0.0)
            x1, x2 = nx1, nx2
            fresh = S(np.where(lft, x1, x2))[0]
            g1 = np.where(lft, fresh, ng1)
            g2 = np.where(lft, ng2, fresh)
        for xx, gg in ((x1, g1), (x2, g2)):
            better = has & (gg[:, 0] < best)
            best = np.where(better, gg[:, 0], best)
            ubest = np.where(better, xx[:, 0], ubest)
    # the plateau around the optimum: the nearest grid window above the level on each side,
    # then bisection between it and the next window inwards (or the optimum itself)
    level = best + tol_um * 1e-3
    above = sg > level[:, None]
    rows = np.arange(n)
    idx = np.arange(n_u)[None, :]
    lims = []
    for side in (-1, 1):
        if side < 0:
            cand = np.where(above & (ug < ubest[:, None]), idx, -1).max(axis=1)
            has = cand >= 0
            nxt = np.minimum(cand + 1, n_u - 1)
            inner = np.where(has & (ug[rows, nxt] < ubest), ug[rows, nxt], ubest)
            edge = u0g
        else:
            cand = np.where(above & (ug > ubest[:, None]), idx, n_u).min(axis=1)
            has = cand < n_u
            nxt = np.maximum(cand - 1, 0)
            inner = np.where(has & (ug[rows, nxt] > ubest), ug[rows, nxt], ubest)
            edge = u1g
        outer = np.where(has, ug[rows, np.clip(cand, 0, n_u - 1)], edge)
        for _ in range(50):
            mid = 0.5 * (inner + outer)
            up = S(mid[:, None])[0][:, 0] > level
            outer = np.where(up, mid, outer)
            inner = np.where(up, inner, mid)
        lims.append(np.where(has, inner, edge))
    uc = 0.5 * (lims[0] + lims[1])
    sc, F, G = S(uc[:, None])
    F, G = F[:, 0], G[:, 0]
    tl = np.maximum(G, T0)
    th = np.minimum(F, T1)
    outside = tl > th
    near = np.where(G > T1, T1, T0)
    tl = np.where(outside, near, tl)
    th = np.where(outside, near, th)
    tc = 0.5 * (tl + th)
    plus = np.maximum(F - tc, 0) * 1e3
    minus = np.maximum(tc - G, 0) * 1e3
    ba = (lims[0] - lo) / (s * deg)
    bb = (lims[1] - lo) / (s * deg)
    ok = good & np.isfinite(best)
    out[:, 0] = (uc - lo) / (s * deg)
    out[:, 1] = plus + minus
    out[:, 2] = plus
    out[:, 3] = minus
    out[:, 4] = np.minimum(ba, bb)
    out[:, 5] = np.maximum(ba, bb)
    out[:, 6] = tc * 1e3
    out[:, 7] = tl * 1e3
    out[:, 8] = th * 1e3
    out[:, 10] = 0.0
    out[:, 11] = best * 1e3
    out[~ok, :] = np.nan
    # status of machines with no feasible window: closes somewhere (dead point) or nowhere
    st = np.zeros(n)
    bad = good & ~np.isfinite(best)
    if bad.any():
        KBP = __import__("sewtol.mechanisms.needle_208.kernels", fromlist=["pack"]).pack(c)
        for i in np.nonzero(bad)[0]:
            seg = np.empty((12, 2))
            k = KW.feasible_segments(KBP[i], u0[i], u1[i] + w[i], 0.0, seg)
            closes = any(seg[r, 1] - seg[r, 0] >= w[i] for r in range(k))
            st[i] = 2 if closes else 1
    out[:, 9] = np.where(good, st, 1)
    return out


def _window_feasible(c, u, w):
    """True where the window [u, u + w] keeps B-C-D closed and >= 1 deg from a dead point:
    |D - B| is extreme at the window ends or where B points at or away from D (the same
    closed form as mechanisms.needle_208.transmission_extremes)."""
    v = (c["Dx"] - c["Ax"]) + 1j * (c["Dy"] - c["Ay"])
    v = np.broadcast_to(np.asarray(v).reshape(-1, 1), (u.shape[0], 1))
    g = np.angle(v)
    AB = np.broadcast_to(np.asarray(c["AB"], float).reshape(-1, 1), (u.shape[0], 1))
    BC = np.broadcast_to(np.asarray(c["BC"], float).reshape(-1, 1), (u.shape[0], 1))
    CD = np.broadcast_to(np.asarray(c["CD"], float).reshape(-1, 1), (u.shape[0], 1))
    hi = u + w[:, None]
    ok = np.ones(u.shape, bool)
    cands = [u, hi]
    for off in (0.0, np.pi):
        tt = u + np.mod(g + off - u, 2 * np.pi)
        cands.append(np.where(tt <= hi, tt, u))
    for t in cands:
        dist = np.abs(v - AB * np.exp(1j * t))
        cos_g = (BC * BC + CD * CD - dist * dist) / (2 * BC * CD)
        closes = np.abs(cos_g) <= 1.0
        gam = np.degrees(np.arccos(np.clip(cos_g, -1, 1)))
        ok &= closes & (np.minimum(gam, 180 - gam) >= nd.DEAD_POINT_DEG)
    return ok
