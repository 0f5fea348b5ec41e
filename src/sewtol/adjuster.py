"""Adjustment at assembly for any mechanism file: 1 to 3 compensators set jointly per machine.

A fitter sets the file's compensators on each machine, inside their box, to serve one output
(an `Objective`: ``minimise`` it, bring it to a ``target`` T, or ``centre`` it in [L, U]).
`adjust` searches a grid over the box, refines it by branch and bound on the cells (a cell's
possible drop: SAFETY times the largest change to its neighbours), tries the box's faces, then
moves each setting along its plateau to the point nearest the machine's own setting. The
search, the meaning of "global" and its certificate (`grid_step`, `gap_bound`,
`local_change`): docs/mechanism_files.md, "Adjustment at assembly"; `brute_force` is the
reference it is tested against.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError

if TYPE_CHECKING:
    import pandas as pd

OBJECTIVES = ("minimise", "target", "centre")
MAX_COMPENSATORS = 3
# grid points per continuous compensator, by the number of compensators searched jointly
GRID = {1: 25, 2: 13, 3: 7}
# branch and bound: at most SPLITS cells of a machine are cut per round, MAX_ROUNDS rounds; a
# cell is not cut below a half-width of MIN_STEP of the box
SPLITS, MAX_ROUNDS, MIN_STEP = 8, 1000, 1e-7
# a cell's drop along an axis: SAFETY times the largest change to its neighbours there (0.5
# would be exact for slopes no steeper than those measured; with 1, 5 of 500 needle machines
# stopped up to 0.019 um above the brute force: docs/mechanism_files.md)
SAFETY = 2.0
# an outer third of a cut cell keeps INHERIT times its parent's slope towards that side, so a V
# against a steep wall at the parent's face is not lost (needle machines 900 and 1388 of the
# benchmark's draw); 0.03 costs 1.8 times the evaluations (0.1: 2.2 times)
INHERIT = 0.03
# a cell is cut while its bound lies more than TOL[unit] (default TOL_OTHER) below the best
# value: 1e-4 um, in mm 1e-7 mm (the same), deg 1e-6 deg
TOL, TOL_OTHER = {"um": 1e-4, "mm": 1e-7, "deg": 1e-6}, 1e-6
# settings within PLATEAU_TOL (output unit) of the optimum form its plateau; PROBE: the first
# step along an axis (fraction of the box) that tells a plateau from a strict optimum
PLATEAU_TOL, PROBE, BISECTIONS = 1e-6, 1e-3, 30


@dataclass(frozen=True)
class Objective:
    """What the adjustment asks of the output: ``Objective()`` minimises it,
    ``Objective("target", target=60.0)`` brings it to 60, ``Objective("centre", low=L,
    high=U)`` centres it in [L, U] (the output's unit)."""

    kind: str = "minimise"
    target: float | None = None
    low: float | None = None
    high: float | None = None

    def __post_init__(self):
        if self.kind not in OBJECTIVES:
            raise ParameterError("objective", f"must be one of {', '.join(OBJECTIVES)}",
                                 self.kind)
        want = {"minimise": (), "target": ("target",), "centre": ("low", "high")}[self.kind]
        for f in ("target", "low", "high"):
            v = getattr(self, f)
            if f in want and not (isinstance(v, (int, float)) and np.isfinite(v)):
                raise ParameterError(f"objective.{f}", f"must be a finite number for "
                                     f"{self.kind}", v)
            if f not in want and v is not None:
                raise ParameterError(f"objective.{f}", f"is not used by {self.kind}", v)
        if self.kind == "centre" and not self.low < self.high:
            raise ParameterError("objective.high", "must be above low", (self.low, self.high))

    @classmethod
    def parse(cls, spec) -> Objective:
        """An Objective from itself, None, "minimise", "target=T" or "centre=L,U"."""
        if isinstance(spec, Objective):
            return spec
        if spec is None:
            return cls()
        kind, _, numbers = str(spec).partition("=")
        try:
            v = [float(t) for t in numbers.split(",")] if numbers else []
        except ValueError:
            raise ParameterError("objective", "must be minimise, target=T or centre=L,U",
                                 spec) from None
        if kind == "target" and len(v) == 1:
            return cls("target", target=v[0])
        if kind == "centre" and len(v) == 2:
            return cls("centre", low=v[0], high=v[1])
        if kind == "minimise" and not v:
            return cls()
        raise ParameterError("objective", "must be minimise, target=T or centre=L,U", spec)

    def loss(self, y):
        """The quantity minimised (output unit): y, |y - T| or the negative margin
        max(L - y, y - U)."""
        y = np.asarray(y, float)
        if self.kind == "target":
            return np.abs(y - self.target)
        if self.kind == "centre":
            return np.maximum(self.low - y, y - self.high)
        return y

    @property
    def floor(self) -> float:
        """The smallest loss there can be: -inf, 0 (on target), -(U - L)/2 (centred)."""
        if self.kind == "target":
            return 0.0
        if self.kind == "centre":
            return -(self.high - self.low) / 2.0
        return -np.inf

    def __str__(self) -> str:
        if self.kind == "target":
            return f"target={self.target:g}"
        if self.kind == "centre":
            return f"centre={self.low:g},{self.high:g}"
        return "minimise"


def compensators_of(mech, adjust) -> tuple:
    """The file's compensators named by `adjust`: a name, a comma list ("beta,guide_shift") or
    a list of names; 1 to MAX_COMPENSATORS of them, each setting its own parameter."""
    names = [s.strip() for s in adjust.split(",")] if isinstance(adjust, str) else list(adjust)
    known = ", ".join(mech.compensators) or "it has none"
    if not 1 <= len(names) <= MAX_COMPENSATORS or len(set(names)) != len(names):
        raise ParameterError("adjust", f"must name 1 to {MAX_COMPENSATORS} different "
                             f"compensators of the file ({known})", adjust)
    for n in names:
        if n not in mech.compensators:
            raise ParameterError("adjust", f"must name a compensator of the file ({known})", n)
    comps = tuple(mech.compensators[n] for n in names)
    if len({c.parameter for c in comps}) != len(comps):
        raise ParameterError("adjust", "must name compensators of different parameters", adjust)
    return comps


@dataclass(frozen=True)
class Adjustment:
    """Per machine: the output at the chosen settings (`value`), the objective's loss there,
    each compensator's setting (its unit), the extent of its plateau (low == high == setting
    when the optimum is strict along it), at-bound flags, the status and failed group at the
    settings ("ok" and "" when it runs; a machine no setting of the box runs keeps its own
    setting and that status), and the certificate: `grid_step` (per compensator), `gap_bound`
    and `local_change` (objective's unit; see the module doc). `evaluations`: machine
    evaluations made, over all machines."""

    output: str
    objective: Objective
    names: tuple[str, ...]
    parameters: tuple[str, ...]
    value: np.ndarray
    loss: np.ndarray
    settings: dict[str, np.ndarray]
    plateau_low: dict[str, np.ndarray]
    plateau_high: dict[str, np.ndarray]
    at_bound: dict[str, np.ndarray]
    status: np.ndarray
    failed_group: np.ndarray
    grid_step: dict[str, float]
    gap_bound: np.ndarray
    local_change: np.ndarray
    evaluations: int

    def to_dataframe(self) -> pd.DataFrame:
        import pandas as pd

        cols = {self.output: self.value, "loss": self.loss, "status": self.status,
                "failed_group": self.failed_group}
        for n, p in zip(self.names, self.parameters, strict=True):
            cols.update({f"{p}_setting": self.settings[n], f"{p}_plateau_low":
                         self.plateau_low[n], f"{p}_plateau_high": self.plateau_high[n],
                         f"{p}_at_bound": self.at_bound[n]})
        cols.update({"gap_bound": self.gap_bound, "local_change": self.local_change})
        return pd.DataFrame(cols)


class _Problem:
    """The objective of m machines as a function of (rows, settings): loss, +inf where the
    machine cannot run at those settings."""

    def __init__(self, mech, values, output, comps, objective, compiled=False):
        cols, self.m = mech.columns(values)
        self.mech, self.output, self.comps, self.objective = mech, output, comps, objective
        # the search's evaluations through the file's compiled kernel where it covers the
        # output (sewtol.mechanism.compiled; equal to mech.evaluate to rounding), else numpy
        self.model = None
        if compiled:
            from sewtol.mechanism.compiled import compiled as compile_model

            self.model = compile_model(mech, [output])
        self.base = {k: np.asarray(v, float)[:, 0] for k, v in cols.items()}
        self.low = np.array([c.low for c in comps])
        self.high = np.array([c.high for c in comps])
        self.evaluations = 0

    def values(self, rows, X):
        vals = {k: v[rows] for k, v in self.base.items()}
        for i, c in enumerate(self.comps):
            own = vals[c.parameter]
            vals[c.parameter] = X[:, i] if c.mode == "absolute" else own + X[:, i]
        return vals

    def evaluate(self, rows, X):
        self.evaluations += len(rows)
        return self.mech.evaluate(self.values(rows, X), [self.output])

    def __call__(self, rows, X):
        if not len(rows):
            return np.zeros(0)
        if self.model is not None:
            self.evaluations += len(rows)
            ev = self.model.evaluate(self.values(rows, X))
        else:
            ev = self.evaluate(rows, X)
        loss = self.objective.loss(ev.outputs[self.output])
        return np.where(np.isnan(loss), np.inf, loss)

    def home(self):
        """Each machine's own setting (m, d): the as-built value, or 0 for an offset."""
        return np.stack([self.base[c.parameter] if c.mode == "absolute"
                         else np.zeros(self.m) for c in self.comps], axis=1)


def adjust(mech, values: dict | None, output: str, compensators,
           objective: Objective | str | None = None,
           plateau_tol: float = PLATEAU_TOL, tol: float | None = None,
           compiled: bool = True) -> Adjustment:
    """Set 1 to 3 compensators jointly on each machine for one output (see the module doc).

    Parameters
    ----------
    mech : FileMechanism
        The mechanism file.
    values : dict or None
        The machines: parameter name -> array of m absolute values (the rest nominal).
    output : str
        The output served (its unit is the objective's).
    compensators : str or list of str
        Compensator names of the file: "beta", "beta,guide_shift" or ["beta", "guide_shift"].
    objective : Objective, str or None
        "minimise" (default), "target=T", "centre=L,U" or an Objective.
    plateau_tol : float
        Settings within this much (output unit) of the optimum form a plateau.
    tol : float or None
        The search stops when no cell's bound lies more than this (output unit) below the best
        value; None: TOL of the output's unit (TOL_OTHER for other units).
    compiled : bool
        Search on the file's compiled kernel where it covers the output (equal to
        `FileMechanism.evaluate` to rounding); False: on `FileMechanism.evaluate` itself. The
        answer (value, status) at the settings found comes from `FileMechanism.evaluate`
        either way.

    Returns
    -------
    Adjustment
    """
    unit = mech.output(output).unit
    comps = compensators_of(mech, compensators)
    objective = Objective.parse(objective)
    tol = TOL.get(unit, TOL_OTHER) if tol is None else tol
    if not (np.isfinite(plateau_tol) and plateau_tol >= 0):
        raise ParameterError("plateau_tol", "must be a number >= 0", plateau_tol)
    f = _Problem(mech, values, output, comps, objective, compiled)
    m, d = f.m, len(comps)
    # a continuous compensator: the centres of GRID[d] cells of its box
    axes = [c.settings() if c.step is not None
            else c.low + (c.high - c.low) * (np.arange(GRID[d]) + 0.5) / GRID[d] for c in comps]
    steps = np.array([(c.high - c.low) / GRID[d] if c.step is None else 0.0 for c in comps])
    P = np.array(list(itertools.product(*axes)))
    shape = tuple(len(ax) for ax in axes)
    Y = f(np.repeat(np.arange(m), len(P)), np.tile(P, (m, 1))).reshape(m, len(P))
    x, fx, gap, local = _search(f, Y, P, shape, steps / 2.0, tol)
    # cell centres never reach the box's faces: each continuous setting tried at both faces
    for i in np.flatnonzero(steps > 0):
        for face in (f.low[i], f.high[i]):
            C = x.copy()
            C[:, i] = face
            fc = f(np.arange(m), C)
            better = fc < fx
            x[better], fx[better] = C[better], fc[better]
    runs = np.isfinite(fx)
    x, lo, hi = _plateaus(f, x, fx, runs, axes, plateau_tol)
    x = np.where(runs[:, None], x, f.home())
    lo, hi = np.where(runs[:, None], lo, np.nan), np.where(runs[:, None], hi, np.nan)
    ev = f.evaluate(np.arange(m), x)
    y = ev.outputs[output]
    width = f.high - f.low
    at = runs[:, None] & ((x - f.low <= 1e-9 * width) | (f.high - x <= 1e-9 * width))
    names = tuple(c.name for c in comps)

    def per(a):
        return {n: a[:, i] for i, n in enumerate(names)}

    return Adjustment(output, objective, names, tuple(c.parameter for c in comps), y,
                      objective.loss(y), per(x), per(lo), per(hi), per(at), ev.status,
                      ev.failed_group, {c.name: float(s) for c, s in zip(comps, steps,
                                                                            strict=True)},
                      np.where(runs, gap, np.nan), np.where(runs, local, np.nan),
                      f.evaluations)


def _search(f, Y, P, shape, half, tol):
    """Branch and bound on cells (see the module doc): a cell (centre, half-widths, value, slope
    towards each side per axis) whose bound (its value minus its summed drops) lies below its
    machine's best value by more than tol is cut in 3 along the continuous axis of its largest
    drop, up to SPLITS cells per machine per round, until no cell qualifies or every axis of it
    is down to MIN_STEP of the box. Returns per machine the best centre and value, the
    certificate's gap bound and the best cell's summed drop."""
    m, g = Y.shape
    d = P.shape[1]
    G = Y.reshape(m, *shape)
    # the slope (output per unit setting) from each cell to its grid neighbour below (SL) and
    # above (SR) along each axis; a cell's drop along an axis is SAFETY x its half-width x 2 x
    # the larger of the two: SAFETY x the larger change to a neighbour on the first grid
    slope = np.zeros((2, m, g, d))
    for i in np.flatnonzero(half > 0):
        pad = [(0, 0)] * G.ndim
        pad[i + 1] = (1, 1)
        Pd = np.pad(G, pad, constant_values=np.nan)
        n = G.shape[i + 1]
        for side, lo in enumerate((0, 2)):
            with np.errstate(invalid="ignore"):  # inf - inf next to failing settings
                dif = np.abs(np.take(Pd, range(lo, n + lo), axis=i + 1) - G)
            slope[side, :, :, i] = np.where(np.isfinite(dif), dif, 0.0).reshape(m, g) / (
                2.0 * half[i])
    mach = np.repeat(np.arange(m), g)
    X = np.tile(P, (m, 1))
    H = np.tile(half, (m * g, 1))
    F = Y.ravel()
    SL, SR = slope[0].reshape(m * g, d), slope[1].reshape(m * g, d)
    # every cell has an id, its place in the order cells are made; a cell that does not
    # qualify now never will (its bound is fixed until it is cut, the best value only falls),
    # so it leaves the active arrays for `done`: each round then costs the live cells only, and
    # the active arrays keep the ids' order, so ties fall as they would over all cells
    ids, made = np.arange(m * g), m * g
    done = []
    best = np.full(m, np.inf)
    np.minimum.at(best, mach, F)

    def drops(H, SL, SR):
        return SAFETY * 2.0 * H * np.maximum(SL, SR)

    smallest = MIN_STEP * (f.high - f.low)
    for _ in range(MAX_ROUNDS if np.any(half > 0) else 0):
        D = drops(H, SL, SR)
        lb = np.maximum(F - D.sum(axis=1), f.objective.floor)
        cuttable = np.where(H > smallest, D, -1.0)
        want = np.isfinite(F) & (lb < best[mach] - tol) & (cuttable.max(axis=1) >= 0)
        sel = np.flatnonzero(want)
        if not sel.size:
            break
        # machine by machine, lowest bound first (on a tie, at the floor: lowest value)
        sel = sel[np.lexsort((F[sel], lb[sel], mach[sel]))]
        sel = sel[np.arange(sel.size) - np.searchsorted(mach[sel], mach[sel]) < SPLITS]
        k = sel.size
        ax = np.argmax(cuttable[sel], axis=1)
        r = np.arange(k)
        Hc = H[sel].copy()
        Hc[r, ax] /= 3.0
        Xs = [X[sel].copy() for _ in range(3)]
        Xs[0][r, ax] -= 2.0 * Hc[r, ax]
        Xs[2][r, ax] += 2.0 * Hc[r, ax]
        Fs = f(np.tile(mach[sel], 2), np.concatenate([Xs[0], Xs[2]])).reshape(2, k)
        trio = np.stack([Fs[0], F[sel], Fs[1]], axis=1)
        dif = np.abs(np.diff(trio, axis=1))
        inner = np.where(np.isfinite(dif), dif, 0.0).max(axis=1) / (2.0 * Hc[r, ax])
        # the middle third: the slopes inside the trio both ways; an outer third keeps the
        # parent's slope towards its outer side (the neighbour beyond the parent: a minimum
        # against a steep wall at the parent's face lies in that third) and the trio's inward
        SLs, SRs = [SL[sel].copy() for _ in range(3)], [SR[sel].copy() for _ in range(3)]
        SLs[1][r, ax] = SRs[1][r, ax] = inner
        SRs[0][r, ax] = SLs[2][r, ax] = inner
        SLs[0][r, ax] = np.maximum(inner, INHERIT * SL[sel][r, ax])
        SRs[2][r, ax] = np.maximum(inner, INHERIT * SR[sel][r, ax])
        F[sel], H[sel], SL[sel], SR[sel] = trio[:, 1], Hc, SLs[1], SRs[1]
        new_mach = np.concatenate([mach[sel], mach[sel]])
        new_F = np.concatenate([trio[:, 0], trio[:, 2]])
        np.minimum.at(best, new_mach, new_F)
        done.append((ids[~want], mach[~want], X[~want], H[~want], F[~want], SL[~want],
                     SR[~want]))
        ids = np.concatenate([ids[want], made + np.arange(2 * k)])
        made += 2 * k
        mach = np.concatenate([mach[want], new_mach])
        X = np.concatenate([X[want], Xs[0], Xs[2]])
        H = np.concatenate([H[want], Hc, Hc])
        F = np.concatenate([F[want], new_F])
        SL = np.concatenate([SL[want], SLs[0], SLs[2]])
        SR = np.concatenate([SR[want], SRs[0], SRs[2]])
    # every cell again, in the order they were made
    parts = done + [(ids, mach, X, H, F, SL, SR)]
    ids, mach, X, H, F, SL, SR = (np.concatenate([c[i] for c in parts]) for i in range(7))
    order = np.argsort(ids, kind="stable")
    mach, X, H, F, SL, SR = mach[order], X[order], H[order], F[order], SL[order], SR[order]
    D = drops(H, SL, SR)
    order = np.lexsort((F, mach))
    first = order[np.searchsorted(mach[order], np.arange(m))]
    fx = F[first]
    low_bound = np.full(m, np.inf)
    np.minimum.at(low_bound, mach, np.where(np.isfinite(F), np.maximum(
        F - D.sum(axis=1), f.objective.floor), np.inf))
    with np.errstate(invalid="ignore"):  # a machine no setting runs: inf - inf
        gap = np.maximum(0.0, fx - low_bound)
    return X[first], fx, gap, D[first].sum(axis=1)


def _plateaus(f, x, fx, runs, axes, tol):
    """Each compensator in turn: the extent of the settings along its axis within tol of the
    optimum, and the setting moved to the point of it nearest the machine's own setting."""
    m, d = x.shape
    x = x.copy()
    lo, hi = x.copy(), x.copy()
    home = f.home()
    rows = np.flatnonzero(runs)
    for i, c in enumerate(f.comps):
        if not rows.size:
            break
        if c.step is not None:  # every setting along the axis
            s = axes[i]
            C = np.repeat(x[rows], s.size, axis=0)
            C[:, i] = np.tile(s, rows.size)
            fl = f(np.repeat(rows, s.size), C).reshape(rows.size, s.size)
            flat = fl <= fx[rows, None] + tol
            lo[rows, i] = np.where(flat, s, np.inf).min(axis=1)
            hi[rows, i] = np.where(flat, s, -np.inf).max(axis=1)
            near = np.argmin(np.where(flat, np.abs(s - home[rows, i, None]), np.inf), axis=1)
            x[rows, i] = s[near]
            continue
        w = c.high - c.low
        for side, end in ((-1, c.low), (1, c.high)):
            a = x[rows, i].copy()  # within tol
            probe = np.clip(a + side * PROBE * w, c.low, c.high)
            C = x[rows].copy()
            C[:, i] = probe
            flat = (f(rows, C) <= fx[rows] + tol) & (probe != a)
            r = rows[flat]
            a, b = probe[flat], np.full(r.size, float(end))
            C = x[r].copy()
            C[:, i] = b
            reach = f(r, C) <= fx[r] + tol
            a[reach] = b[reach]
            bis = np.flatnonzero(~reach)
            for _ in range(BISECTIONS):
                mid = 0.5 * (a[bis] + b[bis])
                C = x[r[bis]].copy()
                C[:, i] = mid
                inside = f(r[bis], C) <= fx[r[bis]] + tol
                a[bis] = np.where(inside, mid, a[bis])
                b[bis] = np.where(inside, b[bis], mid)
            (lo if side < 0 else hi)[r, i] = a
        x[rows, i] = np.clip(home[rows, i], lo[rows, i], hi[rows, i])
    return x, lo, hi


def brute_force(mech, values: dict | None, output: str, compensators,
                objective: Objective | str | None = None, points: int = 101, zoom: int = 21,
                zooms: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The reference `adjust` is tested against: the loss minimised over a dense grid of
    `points` settings per compensator (every setting of a stepped one), then `zooms` times a
    grid of `zoom` points per continuous compensator over +-1 step of the previous grid around
    its best point. Returns the loss (m,) and the settings (m, d); no refinement but grids."""
    comps = compensators_of(mech, compensators)
    f = _Problem(mech, values, output, comps, Objective.parse(objective))
    m = f.m
    axes = [c.settings() if c.step is not None else np.linspace(c.low, c.high, points)
            for c in comps]
    steps = np.array([0.0 if c.step is not None else ax[1] - ax[0]
                      for c, ax in zip(comps, axes, strict=True)])
    P = np.array(list(itertools.product(*axes)))
    Y = f(np.repeat(np.arange(m), len(P)), np.tile(P, (m, 1))).reshape(m, len(P))
    k = np.argmin(Y, axis=1)
    x, fx = P[k], Y[np.arange(m), k]
    u = np.linspace(-1.0, 1.0, zoom)
    for _ in range(zooms):
        off = np.array(list(itertools.product(*[u if s > 0 else [0.0] for s in steps])))
        C = np.clip(np.repeat(x, len(off), axis=0) + np.tile(off * steps, (m, 1)), f.low, f.high)
        Yc = f(np.repeat(np.arange(m), len(off)), C).reshape(m, len(off))
        j = np.argmin(Yc, axis=1)
        better = Yc[np.arange(m), j] < fx
        x = np.where(better[:, None], C.reshape(m, len(off), -1)[np.arange(m), j], x)
        fx = np.minimum(fx, Yc[np.arange(m), j])
        steps = steps * 2.0 / (zoom - 1)
    return fx, x
