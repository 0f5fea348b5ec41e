"""Adjustment at assembly: a strategy's joint optimum of the needle's SumDelta over its
compensators, per machine, batched, on the exact optimiser of mechanisms/needle_208/adjust.py.

Structure used, innermost first:
- the exact optimum (needle_208.adjust.optimise): beta (absolute, continuous) with the guide
  shift and the guide angle when they are continuous; an exact sliding-window solution, the
  angle an outer search around it (tests/test_adjust.py, tests/test_independent_reference.py).
- without such a beta, the guide shift alone in closed form on the exact band of the path:
  with the band of n.(E - G) over the cycle [m, M] (um, needle_208.metrics.projection_extremes),
  a shift t gives SumDelta(t) = max(0, M - t) + max(0, t - m), so over t in [T0, T1] the minimum
  is max(M - m, M - T1, T0 - m), a plateau [max(m, T0), min(M, T1)] when the band can be centred
  (the setting is the plateau's centre). A discrete shift takes the better of the two allowed
  settings around that centre (SumDelta is convex in t, so that is exact).
- every other compensator (CD, any parameter declared one, a discrete beta or shift, the angle
  without beta): an outer 1-D search around that inner optimum, nested: a grid over the range,
  then golden section on the best grid cell. A discrete compensator is searched over all its
  allowed settings (exact given the inner optimum). CD (continuous, an offset) around the
  exact optimum with the guide angle: both outer searches in one kernel call
  (needle_208.adjust.cd_and_angle), then beta and the shift at the CD and angle it found.

Every reported SumDelta is recomputed at the chosen settings with the exact extremes
(needle_208.metrics.deviation_figures), so it is the machine's true SumDelta at those settings.

Resolution model: the assembler aims at the chosen setting but lands anywhere within +/- r/2
(clipped to the range). `achieved_um` is the worst SumDelta over the 3^k points (each resolved
compensator at -r/2, 0, +r/2, the others at their settings); exact wherever SumDelta is convex
in the settings over that small box (it is piecewise linear and convex in the shift).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import adjust as exact
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd
from sewtol.mechanisms.needle_208.compensators import Compensator, Strategy
from sewtol.optimize import bisect_root, golden_min
from sewtol.protocol import words_of

if TYPE_CHECKING:
    import pandas as pd

PLATEAU_TOL_UM = 1e-3  # settings within this of the optimum form its plateau (centre chosen)
STATUSES = ("ok", "out of spec", "cannot assemble", "dead point")
# grid spacing of the outer search per compensator (default: 12 cells over the range)
OUTER_GRID_STEP = {"beta": 1.0}
MAX_DISCRETE = 5001
DISCRETE_BATCH = 20000  # machines per call when every allowed setting is tried
EXACT_INNER = ("beta", "guide_shift_um", "guide_angle")  # what the exact optimum sets itself


def _grid(comp: Compensator) -> np.ndarray:
    if comp.discrete:
        s = comp.settings()
        if s.size > MAX_DISCRETE:
            raise ParameterError(f"{comp.name}.step", f"gives more than {MAX_DISCRETE} settings",
                                 comp.step)
        return s
    step = OUTER_GRID_STEP.get(comp.name, (comp.high - comp.low) / 12)
    g = max(int(np.ceil((comp.high - comp.low) / step)) + 1, 3)
    return np.linspace(comp.low, comp.high, g)


def _xtol(comp: Compensator) -> float:
    return 5e-6 * (comp.high - comp.low)


def _finite(v):
    return np.where(np.isnan(v), np.inf, v)


def _apply(c: dict, comp: Compensator, setting) -> dict:
    out = dict(c)
    s = np.asarray(setting, float).reshape(-1, 1)
    out[comp.name] = np.broadcast_to(comp.value(c[comp.name], s), c[comp.name].shape).copy()
    return out


@dataclass
class _Inner:
    total: np.ndarray
    settings: dict = field(default_factory=dict)
    plateaus: dict = field(default_factory=dict)


# --- innermost without beta: the guide shift in closed form on the exact band --------------


def shift_optimum(M, m, s0, comp: Compensator | None):
    """SumDelta (um) minimised over the guide shift, the shift setting and its plateau.

    M, m: band of n.(E - G) in um with no shift; s0: the machine's own shift (um). Returns
    (total, setting, plateau_low, plateau_high); the setting is an offset from s0.
    """
    M, m, s0 = (np.asarray(x, float) for x in (M, m, s0))
    if comp is None:
        total = np.maximum(0.0, M - s0) + np.maximum(0.0, s0 - m)
        nan = np.full(total.shape, np.nan)
        return total, nan, nan, nan
    t0, t1 = s0 + comp.low, s0 + comp.high
    p_lo, p_hi = np.maximum(m, t0), np.minimum(M, t1)
    inside = p_lo <= p_hi
    # band out of reach: the nearer end of the range is the only optimum
    end = np.where(t1 < m, t1, t0)
    p_lo, p_hi = np.where(inside, p_lo, end), np.where(inside, p_hi, end)
    centre = 0.5 * (p_lo + p_hi)
    if not comp.discrete:
        total = np.maximum.reduce([M - m, M - t1, t0 - m])
        return total, centre - s0, p_lo - s0, p_hi - s0
    step, kmax = comp.step, comp.settings().size - 1

    def f(t):
        return np.maximum(0.0, M - t) + np.maximum(0.0, t - m)

    kf = np.clip(np.floor((centre - t0) / step), 0, kmax)
    kc = np.minimum(kf + 1, kmax)
    tf, tc = t0 + kf * step, t0 + kc * step
    ff, fc = f(tf), f(tc)
    take_c = (fc < ff) | ((fc == ff) & (np.abs(tc - centre) < np.abs(tf - centre)))
    t = np.where(take_c, tc, tf)
    total = np.where(take_c, fc, ff)
    # the allowed settings inside the band form the discrete plateau when the band is reachable
    k_lo = np.clip(np.ceil((m - t0) / step - 1e-9), 0, kmax)
    k_hi = np.clip(np.floor((M - t0) / step + 1e-9), 0, kmax)
    flat = inside & (k_lo <= k_hi) & (total <= M - m + 1e-12)
    pl = np.where(flat, t0 + k_lo * step, t)
    ph = np.where(flat, t0 + k_hi * step, t)
    return np.where(np.isnan(M), np.nan, total), t - s0, pl - s0, ph - s0


def _shift_leaf(c: dict, shift: Compensator | None, cutoff_um=None) -> _Inner:
    """The guide shift's optimum (or none) on the exact band of the path, beta as in c."""
    feas = nm.feasibility(c)
    s0 = c["guide_shift_um"][:, 0]
    _, n, G = nd.guide_frame(nm.with_values(c, guide_shift_um=np.zeros(s0.size)))
    ext = nm.projection_extremes(c, n, feas.lo, feas.hi)
    g = nd.project(n, G).ravel()
    M = np.where(feas.ok, (ext.fmax - g) * 1e3, np.nan)
    m = np.where(feas.ok, (ext.fmin - g) * 1e3, np.nan)
    total, t, pl, ph = shift_optimum(M, m, s0, shift)
    out = _Inner(total=total)
    if shift is not None:
        out.settings[shift.name] = t
        out.plateaus[shift.name] = (pl, ph)
    return out


def _plateau(fun, x_opt, best, comp: Compensator, xtol=None):
    """[low, high] around x_opt where fun <= best + PLATEAU_TOL_UM (bisection to each side)."""
    xtol = xtol or 1e-5 * (comp.high - comp.low)
    n = np.shape(x_opt)[0]

    def excess(x):
        v = fun(x)
        return np.where(np.isnan(v), np.inf, v) - (best + PLATEAU_TOL_UM)

    ends = []
    for end in (comp.low, comp.high):
        e = np.full(n, float(end))
        inside = excess(e) <= 0
        root = bisect_root(lambda x: np.minimum(excess(x), 1e300), np.where(inside, x_opt, e),
                           x_opt, xtol=xtol)
        ends.append(np.where(inside, e, root))
    return ends[0], ends[1]


# --- outer 1-D searches -------------------------------------------------------------------


def _search(c: dict, outer: list[Compensator], plateaus: bool, leaf, held=(),
            guess=None, found=None) -> _Inner:
    """Nested 1-D searches over `outer` (outermost first) around `leaf` (columns, cutoff ->
    _Inner, the inner optimum, or where the leaf proves it above the cutoff (um, per machine),
    perhaps only a value above it; `held` are the compensators it sets, held at its settings
    when an outer plateau is measured). guess: columns -> a cheap SumDelta per machine that
    orders the innermost grid (the likely best first, so the cutoffs cut early). found: the
    outermost compensator's optimum where another search found it (then only the inner
    optimum there and the plateau)."""
    if not outer:
        return leaf(c)
    comp, rest = outer[0], outer[1:]
    n = next(iter(c.values())).shape[0]

    def sub(cc, plat=False, cutoff_um=None):
        return _search(cc, rest, plat, leaf, held, guess) if rest else leaf(cc, cutoff_um)

    def score(x, cutoff_um=None):
        return _finite(sub(_apply(c, comp, x), cutoff_um=cutoff_um).total)

    grid = _grid(comp)
    res = None
    if found is not None:
        x = found
    elif comp.discrete:
        # every allowed setting of every machine in batches of repeated machines
        vals = np.empty((n, grid.size))
        per = max(1, DISCRETE_BATCH // n)
        for j in range(0, grid.size, per):
            g = grid[j:j + per]
            cc = {k: np.repeat(v, g.size, axis=0) for k, v in c.items()}
            vals[:, j:j + g.size] = _finite(sub(_apply(cc, comp, np.tile(g, n))).total
                                            ).reshape(n, g.size)
        x = grid[np.argmin(vals, axis=1)]
    else:
        # only the grid's best is used (its value, and where it is): every later grid point is
        # scored with the best so far as its cutoff, so a point that cannot beat it may keep
        # a value above the cutoff instead of its minimum (the argmin is the same)
        vals = np.empty((n, grid.size))
        best = np.full(n, np.inf)
        rows = np.arange(n)
        order = np.tile(np.arange(grid.size), (n, 1))
        if guess is not None and not rest:
            order = np.argsort(np.stack([_finite(guess(_apply(c, comp, np.full(n, g))))
                                         for g in grid], axis=1), axis=1, kind="stable")
        for j in order.T:
            vals[rows, j] = score(grid[j], best)
            best = np.minimum(best, vals[rows, j])
        i = np.argmin(vals, axis=1)
        a, b = grid[np.maximum(i - 1, 0)], grid[np.minimum(i + 1, grid.size - 1)]
        # each new point scored with the one it is compared with as its cutoff
        x = golden_min(score, a, b, xtol=_xtol(comp), value=False, cutoff=not rest)[0]
        # never worse than the grid (golden section can stall on an infinite bracket end); the
        # search at x is the one kept unless the grid wins somewhere
        res = sub(_apply(c, comp, x), plateaus)
        better_grid = vals[np.arange(n), i] < _finite(res.total)
        if better_grid.any():
            x = np.where(better_grid, grid[i], x)
            res = None
    if res is None:
        res = sub(_apply(c, comp, x), plateaus)
    if plateaus and not comp.discrete:
        # the range of this setting (the inner ones held) within PLATEAU_TOL_UM of the optimum
        inner_settings = res.settings

        def at(y):
            cc = _apply(c, comp, y)
            for k in (*rest, *held):
                cc = _apply(cc, k, inner_settings[k.name])
            return nm.total_um_kernel(cc)  # deviation_figures' to 3e-11 um, 6x faster

        best = at(x)
        lo_p, hi_p = _plateau(at, x, best, comp)
        mid = 0.5 * (lo_p + hi_p)
        use_mid = at(mid) <= best + PLATEAU_TOL_UM
        res.plateaus[comp.name] = (lo_p, hi_p)
        x = np.where(use_mid & np.isfinite(best), mid, x)
    res.settings[comp.name] = x
    return res


def _exact_boxes(c: dict, comps) -> dict | None:
    """The boxes of needle_208.adjust.optimise (the exact sliding-window optimum) for these
    continuous compensators, or None where it does not apply: beta must be among them and
    absolute, the guide shift the same offset for every machine (its box there is absolute),
    the guide angle and CD offsets (as there), at most one of those two."""
    names = [k.name for k in comps]
    if ("beta" not in names or any(k.discrete for k in comps)
            or not set(names) <= set(exact.COMPENSATORS)
            or sum(n in exact.OUTER for n in names) > 1):
        return None
    boxes = {}
    for k in comps:
        if k.name == "beta":
            if k.mode != "absolute":
                return None
            boxes["beta"] = (k.low, k.high)
        elif k.name == "guide_shift_um":
            s0 = np.unique(c["guide_shift_um"])
            if k.mode == "absolute":
                boxes[k.name] = (k.low, k.high)
            elif s0.size == 1:
                boxes[k.name] = (float(s0[0]) + k.low, float(s0[0]) + k.high)
            else:
                return None
        else:
            if k.mode != "offset":
                return None
            boxes[k.name] = (k.low, k.high)
    return boxes


def _exact(c: dict, comps, boxes: dict, feas=None, cutoff_um=None) -> _Inner:
    """needle_208.adjust.optimise, its settings and plateau ranges in this module's terms
    (feas: the machines' feasibility if known; cutoff_um: as optimise's)."""
    r = exact.optimise(c, boxes, feas=feas, cutoff_um=cutoff_um)
    out = _Inner(total=np.asarray(r.min_total_um, float))
    for k in comps:
        x, lo, hi = (np.asarray(v[k.name], float) for v in (r.settings, r.low, r.high))
        if k.name == "guide_shift_um" and k.mode == "offset":
            s0 = c["guide_shift_um"][:, 0]
            x, lo, hi = x - s0, lo - s0, hi - s0
        out.settings[k.name] = x
        out.plateaus[k.name] = (lo, hi)
    return out


def _joint_optimum(c: dict, strategy: Strategy, plateaus: bool = True) -> _Inner:
    """Settings (offsets or absolute values as each compensator's mode says) of the joint
    optimum of SumDelta over the strategy's box, per machine, and the plateau ranges.

    Where it applies (beta with the guide shift and one of guide angle or CD, continuous), the
    exact sliding-window optimum of needle_208.adjust does it all (tests/test_adjust.py,
    tests/test_independent_reference.py). Otherwise the inner optimum is the exact one over
    the continuous beta, shift and angle where that applies, else the guide shift's closed form,
    and every other compensator is a nested 1-D search around it (a discrete one over all its
    settings; beta, then the angle innermost).
    """
    comps = list(strategy.compensators)
    if not comps:  # the machine as built
        return _Inner(total=None)
    boxes = _exact_boxes(c, comps)
    if boxes is not None:
        return _exact(c, comps, boxes)
    inner = [k for k in comps if k.name in EXACT_INNER and not k.discrete]
    if _exact_boxes(c, inner) is not None:
        # the rocker's interval (all optimise reads of the feasibility) is the same at every
        # setting of every compensator: once for these machines (a discrete search's
        # repeated machines compute their own)
        feas = nm.feasibility(c)

        def leaf(cc, cutoff_um=None, comps=inner):
            same = np.shape(cc["AB"])[0] == np.shape(feas.lo)[0]
            return _exact(cc, comps, _exact_boxes(cc, comps), feas if same else None,
                          cutoff_um)

        def guess(cc):  # the guide angle as built: one window solve per machine
            return leaf(cc, comps=[k for k in inner if k.name != "guide_angle"]).total
    else:
        inner = [k for k in comps if k.name == "guide_shift_um"]

        def leaf(cc, cutoff_um=None):
            return _shift_leaf(cc, inner[0] if inner else None)

        guess = None
    outer = sorted((k for k in comps if k not in inner),
                   key=lambda k: ("beta", "guide_angle").index(k.name) + 1
                   if k.name in ("beta", "guide_angle") else 0)
    found = None
    angle = next((k for k in inner if k.name == "guide_angle"), None)
    if ([k.name for k in outer] == ["CD"] and not outer[0].discrete
            and outer[0].mode == "offset" and outer[0].high > outer[0].low
            and angle is not None and angle.high > angle.low):
        # CD around the guide angle in one kernel call (adjust.cd_and_angle): CD's optimum and
        # the angle's there; the inner optimum at CD's is then beta's and the shift's at that
        # angle
        boxes = {**_exact_boxes(c, inner), "CD": (outer[0].low, outer[0].high)}
        found, at_angle, _ = exact.cd_and_angle(c, boxes, _grid(outer[0]), feas)
        rest = [k for k in inner if k is not angle]

        def leaf(cc, cutoff_um=None):
            r = _exact(_apply(cc, angle, at_angle), rest, _exact_boxes(cc, rest), feas)
            r.settings[angle.name] = at_angle
            r.plateaus[angle.name] = (at_angle, at_angle)
            return r
    return _search(c, outer, plateaus, leaf, inner, guess, found)


# --- the result ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Adjustment:
    """Per machine: SumDelta before (as built, no adjustment) and after, each compensator's
    setting, plateau, at-limit flag, what the assembler achieves, and the status."""

    strategy: Strategy
    limit_um: float
    total_before_um: np.ndarray
    total_um: np.ndarray
    plus_um: np.ndarray
    minus_um: np.ndarray
    achieved_um: np.ndarray
    status: np.ndarray
    settings: dict
    plateau_low: dict
    plateau_high: dict
    at_limit: dict

    @property
    def n(self) -> int:
        return int(self.total_um.size)

    def counts(self) -> dict:
        return {s: int(np.sum(self.status == s)) for s in STATUSES}

    def to_dataframe(self) -> pd.DataFrame:
        import pandas as pd

        f = pd.DataFrame({"total_before_um": self.total_before_um,
                          "total_after_um": self.total_um, "plus_after_um": self.plus_um,
                          "minus_after_um": self.minus_um, "achieved_um": self.achieved_um})
        for comp in self.strategy.compensators:
            u = f"_{comp.unit}" if comp.unit and not comp.name.endswith(comp.unit) else ""
            f[f"{comp.name}_setting{u}"] = self.settings[comp.name]
            f[f"{comp.name}_plateau_low{u}"] = self.plateau_low[comp.name]
            f[f"{comp.name}_plateau_high{u}"] = self.plateau_high[comp.name]
            f[f"{comp.name}_at_limit"] = self.at_limit[comp.name]
        f["status"] = self.status
        return f


def adjust(c: dict[str, np.ndarray], strategy: Strategy, limit_um: float = 10.0,
           plateaus: bool = True) -> Adjustment:
    """The assembler's adjustment of each machine (parameter columns c, shape (n, 1)).

    Every machine gets the strategy's joint optimum: the settings of its compensators, within
    their ranges and steps, that minimise SumDelta with the guide fixed.

    Parameters
    ----------
    c : dict of numpy.ndarray
        The machines as parameter columns of shape (n, 1), by `Needle208` field name: e.g.
        ``c, n = sewtol.mechanisms.needle_208.metrics.columns(machine)`` (mm, deg, um).
    strategy : Strategy
        The compensators the assembler may set; an empty strategy leaves every machine as
        built.
    limit_um : float
        The SumDelta limit (um) that makes a machine ok or out of spec.
    plateaus : bool
        Also find each setting's plateau (the range within 1e-3 um of the optimum).

    Returns
    -------
    Adjustment
        Per machine: SumDelta before (as built) and after (um), Delta+/Delta- after, each
        setting with its plateau and at-limit flag, what the assembler achieves within the
        setting resolution, and the status (``"ok"``, ``"out of spec"``,
        ``"cannot assemble"``, ``"dead point"``).
    """
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    strategy.check_names(list(c))
    before_feas = nm.feasibility(c)
    before = nm.deviation_figures(c, before_feas).total_um
    res = _joint_optimum(c, strategy, plateaus)
    final = c
    for comp in strategy.compensators:
        final = _apply(final, comp, res.settings[comp.name])
    feas = nm.feasibility(final)
    figs = nm.deviation_figures(final, feas)
    dead_everywhere = ~np.isfinite(figs.total_um)
    settings, p_lo, p_hi, at_limit = {}, {}, {}, {}
    for comp in strategy.compensators:
        x = np.where(dead_everywhere, np.nan, res.settings[comp.name])
        settings[comp.name] = x
        pl, ph = res.plateaus.get(comp.name, (x, x))
        p_lo[comp.name] = np.where(dead_everywhere, np.nan, pl)
        p_hi[comp.name] = np.where(dead_everywhere, np.nan, ph)
        if comp.discrete:
            top = comp.settings()[-1]
            eps = 1e-9 * comp.step
        else:
            top, eps = comp.high, 1e-6 * (comp.high - comp.low)
        at_limit[comp.name] = (x <= comp.low + eps) | (x >= top - eps)
    # a machine no setting can run: classify it at its as-built settings
    dead_point = np.where(dead_everywhere, before_feas.dead_point, feas.dead_point)
    status = status_of(figs.total_um, limit_um, dead_point)
    return Adjustment(strategy, float(limit_um), before, figs.total_um, figs.plus_um,
                      figs.minus_um, _achieved(c, strategy, settings, figs.total_um), status,
                      settings, p_lo, p_hi, at_limit)


WORDS = ("ok", "out of spec", "dead point", "cannot assemble")  # a status's codes 0-3


def status_of(total_um, limit_um: float, dead_point) -> np.ndarray:
    """Per machine: ok / out of spec (SumDelta against limit_um), else dead point / cannot
    assemble."""
    return words_of(WORDS, np.where(np.isfinite(total_um), np.where(total_um <= limit_um, 0, 1),
                                    np.where(dead_point, 2, 3)))


def _achieved(c, strategy: Strategy, settings: dict, total) -> np.ndarray:
    resolved = [k for k in strategy.compensators if k.resolution > 0]
    if not resolved:
        return total
    worst = np.array(total, float)
    top = {k.name: (k.settings()[-1] if k.discrete else k.high) for k in resolved}
    for offs in np.array(np.meshgrid(*[[-0.5, 0.0, 0.5]] * len(resolved))).reshape(
            len(resolved), -1).T:
        cc = c
        for comp in strategy.compensators:
            x = settings[comp.name]
            if comp.resolution > 0:
                j = resolved.index(comp)
                x = np.clip(x + offs[j] * comp.resolution, comp.low, top[comp.name])
            cc = _apply(cc, comp, x)
        v = nm.deviation_figures(cc).total_um
        worst = np.fmax(worst, np.where(np.isnan(v), np.inf, v))
    return np.where(np.isfinite(total), worst, np.nan)


def columns_of(nominal, deviations: dict) -> dict:
    """Parameter columns (n, 1) of the machines nominal + deviations."""
    m = len(next(iter(deviations.values())))
    c, _ = nm.columns(P.with_deviations(nominal, deviations))
    return {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
