"""Joint clearances in studies: the clearance Jacobian (`jacobian`, central differences of the
real model), the first-order worst case W(phi) = sum_j c_j |J_j(phi)| (`worst_case`), Ting's
bound for a four-bar (`ting_bound`), random journals in or on their circles (`random_offsets`,
through the real model) and the guide pair as the criterion of a zero-mobility drive
(`guide_criterion`). Assumptions: rigid links, small clearances, no impact dynamics, offsets
held over the turn in the frame's axes. See docs/clearances.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.fits import iso_fit
from sewtol.mechanism.clearance import offset_names, polar_names
from sewtol.mechanism.model import resolved
from sewtol.mechanism.outputs import OUTPUT_TYPES

H_MM = 1e-4  # the finite-difference step: 1/25 of the smallest radial clearance of a fine fit
SIGNAL_TYPES = ("line_deviation", "coordinate", "angle")
DEG = np.pi / 180.0


def revolute(mech) -> tuple:
    """The mechanism's revolute pairs with a clearance (refused when it has none)."""
    pairs = tuple(c for c in getattr(mech, "clearances", ()) if c.pair == "revolute")
    if not pairs:
        raise ParameterError("clearances", "the mechanism file declares no revolute "
                                           "[[clearances]]", getattr(mech, "name", mech))
    return pairs


def signal(mech, state, output: str) -> np.ndarray:
    """The output's signal over the sampled angles, shape (m, samples): the signed distance d
    (um) of a line_deviation's point from its line, a coordinate's x or y (mm), an angle's
    direction (deg, unwrapped)."""
    o = mech.output(output)
    if o.type not in SIGNAL_TYPES:
        raise ParameterError("output", "must be an output of type "
                             + ", ".join(SIGNAL_TYPES) + " (a signal over the turn)",
                             f"{output} ({o.type})")
    f = resolved(o.fields, OUTPUT_TYPES[o.type].fields, state.points, state.angles, state.values)
    if o.type == "line_deviation":
        a = f["angle_deg"] * DEG
        n = np.cos(a) - 1j * np.sin(a)
        g = f["x"] + 1j * f["y"] + n * (f["shift_um"] * 1e-3)
        return 1e3 * (np.conjugate(n) * (f["point"].p - g)).real
    if o.type == "coordinate":
        p = f["point"]
        return np.broadcast_to(p.x if f["axis"] == "x" else p.y, state.shape)
    base = f["angle"] if f.get("angle") is not None else f["direction"]
    return np.degrees(np.unwrap(np.broadcast_to(base.a, state.shape), axis=-1))


def _signal(mech, values, output):
    state = mech.state(values)
    status, _ = mech.status_of(state)
    s = np.array(signal(mech, state, output), float)
    s[status != "ok"] = np.nan
    return s, status


def jacobian(mech, values: dict | None, output: str, h_mm: float = H_MM) -> dict:
    """joint -> J_j, complex (m, samples): ds/ddx_j + i ds/ddy_j (signal unit per mm) at each
    machine of `values` and angle, by central differences of step h_mm."""
    pairs = revolute(mech)
    values = {k: np.atleast_1d(np.asarray(v, float)) for k, v in (values or {}).items()}
    m = max([v.size for v in values.values()], default=1)
    values = {k: np.broadcast_to(v, (m,)) for k, v in values.items()}
    names = [n for c in pairs for n in offset_names(c.joint)]
    # one evaluation of 2 * len(names) * m machines: every +h and -h side by side
    big = {k: np.tile(v, 2 * len(names)) for k, v in values.items()}
    for k, name in enumerate(names):
        col = np.array(big.get(name, np.zeros(2 * len(names) * m)), float)
        col[2 * k * m:(2 * k + 1) * m] += h_mm
        col[(2 * k + 1) * m:(2 * k + 2) * m] -= h_mm
        big[name] = col
    s, _ = _signal(mech, big, output)
    s = s.reshape(len(names), 2, m, -1)
    d = (s[:, 0] - s[:, 1]) / (2.0 * h_mm)
    return {c.joint: d[2 * i] + 1j * d[2 * i + 1] for i, c in enumerate(pairs)}


def radii(mech, which: str = "max") -> dict[str, float]:
    """joint -> radial clearance (mm) of each revolute pair: its largest ("max") or smallest
    ("min")."""
    if which not in ("min", "max"):
        raise ParameterError("clearance", "must be min or max", which)
    return {c.joint: (c.radial_max_mm if which == "max" else c.radial_min_mm)
            for c in revolute(mech)}


@dataclass(frozen=True)
class ClearanceWorstCase:
    """The first-order worst case of an output's signal under the pin clearances, per machine
    and angle: W = sum_j c_j |J_j| (`total`, signal unit), each pair's share c_j |J_j|
    (`by_pair`), and the offsets that reach +W (`argmax_mm`: joint -> complex r_j)."""

    output: str
    unit: str
    q_deg: np.ndarray
    total: np.ndarray
    by_pair: dict[str, np.ndarray]
    radius_mm: dict[str, float]
    argmax_mm: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def inert(self) -> tuple[str, ...]:
        """The pairs whose offset moves the signal at no machine and angle (exactly 0): a
        point the model draws but no group builds on (the spatial groups take lengths)."""
        return tuple(j for j, v in self.by_pair.items() if not np.any(np.nan_to_num(v)))

    def to_dataframe(self) -> pd.DataFrame:
        """One row per (machine, angle): W and each pair's c_j |J_j|."""
        m, k = self.total.shape
        f = pd.DataFrame({"machine": np.repeat(np.arange(m), k),
                          "q_deg": np.tile(self.q_deg, m),
                          f"W_{self.unit}": self.total.reshape(-1)})
        for j, v in self.by_pair.items():
            f[f"{j}_{self.unit}"] = v.reshape(-1)
        return f

    def shares(self) -> pd.DataFrame:
        """Each pair's share of W at the angle where W is largest, per machine (mean)."""
        k = np.nanargmax(np.nan_to_num(self.total, nan=-1.0), axis=-1)
        rows = np.arange(self.total.shape[0])
        tot = self.total[rows, k]
        return pd.DataFrame({"pair": list(self.by_pair),
                             "radial_mm": [self.radius_mm[j] for j in self.by_pair],
                             f"at_max_{self.unit}": [float(np.nanmean(v[rows, k]))
                                                     for v in self.by_pair.values()],
                             "share": [float(np.nanmean(v[rows, k] / tot))
                                       for v in self.by_pair.values()]})


def worst_case(mech, values: dict | None, output: str, clearance: str = "max",
               h_mm: float = H_MM) -> ClearanceWorstCase:
    """The worst case of `output`'s signal under the file's pin clearances (the radial clearance
    of each pair: its "max" or "min"), first order, per machine of `values` and angle."""
    c = radii(mech, clearance)
    jac = jacobian(mech, values, output, h_mm)
    by = {j: c[j] * np.abs(J) for j, J in jac.items()}
    # J_j . r_j = Re(conj(J_j) r_j) is largest at r_j = c_j J_j / |J_j| (as dx + i dy)
    arg = {j: c[j] * J / np.where(np.abs(J) > 0, np.abs(J), 1.0) for j, J in jac.items()}
    total = sum(by.values())
    return ClearanceWorstCase(output, mech.output(output).unit, np.degrees(mech.angles_rad()),
                              total, by, c, arg)


def random_offsets(mech, n: int, rng: np.random.Generator, *, rim: bool = False,
                   clearance: str = "max") -> dict[str, np.ndarray]:
    """Pair parameters of n machines: each journal uniform in its clearance circle (area-uniform),
    or on its rim (rim=True), of the pair's radial clearance ("max", "min", or "drawn": uniform
    between them per machine)."""
    if not isinstance(rng, np.random.Generator):
        raise ParameterError("rng", "must be a numpy Generator", type(rng).__name__)
    if clearance not in ("min", "max", "drawn"):
        raise ParameterError("clearance", "must be min, max or drawn", clearance)
    out = {}
    for c in revolute(mech):
        if clearance == "drawn":
            radius = rng.uniform(c.radial_min_mm, c.radial_max_mm, n)
        else:
            radius = np.full(n, c.radial_max_mm if clearance == "max" else c.radial_min_mm)
        t = rng.uniform(0.0, 2.0 * np.pi, n)
        rho = radius if rim else radius * np.sqrt(rng.uniform(0.0, 1.0, n))
        dx, dy = offset_names(c.joint)
        out[dx], out[dy] = rho * np.cos(t), rho * np.sin(t)
    return out


# --- clearances as variables of every study ---------------------------------------------------

VARIABLE_MODES = ("disc", "rim")


def clearance_variables(mech, tolerances, mode: str = "disc"):
    """The mechanism and tolerance set with each revolute pair's journal as two further
    variables beside the link tolerances, drawn by every study of the one stack: the offset
    r = sqrt(r2) (cos phi, sin phi) (`sewtol.mechanism.clearance.polar_names`), phi uniform in
    [0, 360) deg and r2 uniform in [0, c^2] (``disc``: uniform over the disc) or r2 = c^2
    (``rim``), c the pair's largest radial clearance. Returns (a copy of the file with r2 and
    phi as parameters and no fast path, the set ``NAME+clearances``); refused: a file without
    revolute clearances, a set that already names them, an unknown mode (docs/clearances.md)."""
    import dataclasses

    from sewtol.mechanism.spec import Parameter
    from sewtol.protocol import tolerance_set
    from sewtol.tolerances import Tolerance, ToleranceSet

    if mode not in VARIABLE_MODES:
        raise ParameterError("clearances", f"must be one of {', '.join(VARIABLE_MODES)}", mode)
    pairs = revolute(mech)
    ts = tolerance_set(mech, tolerances)
    params, items = list(mech.parameters), list(ts.items)
    for c in pairs:
        r2, phi = polar_names(c.joint)
        hi = c.radial_max_mm ** 2
        nominal = hi if mode == "rim" else 0.0
        params += [Parameter(r2, nominal, "mm2", "finite",
                             f"square of the journal's offset in pair {c.joint}"),
                   Parameter(phi, 0.0, "deg", "finite",
                             f"direction of the journal's offset in pair {c.joint}")]
        if mode == "disc":
            items.append(Tolerance(r2, 0.0, hi, "uniform"))
        items.append(Tolerance(phi, 0.0, 360.0, "uniform"))
    names = {p.name for p in mech.parameters}
    clash = sorted(names & {p.name for p in params[len(mech.parameters):]})
    if clash:
        raise ParameterError("parameters", "already name a journal's polar offset", clash)
    header = dataclasses.replace(mech.header, fast_path=None)
    varied = dataclasses.replace(mech, parameters=tuple(params), header=header)
    return varied, ToleranceSet(f"{ts.name}+clearances", tuple(items),
                                (ts.description + "; " if ts.description else "")
                                + f"journals {mode}", dependence=ts.dependence,
                                relations=ts.relations, selective=ts.selective)


@dataclass(frozen=True)
class SobolShare:
    """The Sobol indices of one output with the journals as variables (`clearance_variables`)
    beside the link tolerances: ``indices`` per input (source ``link`` or ``pin``; a pin's
    ``pair``), ``by_pair`` each pair's first-order and total index (r2 and phi together: their
    closed index S1_r2 + S1_phi is a lower bound of the pair's first-order share, the sum of
    their totals an upper bound of its total), ``sources`` the sums over the links and over the
    pins (a source's share of the variance lies between the sum of its S1 and the sum of its
    ST)."""

    mechanism: str
    tolerances: str
    output: str
    mode: str
    n: int
    seed: int
    indices: pd.DataFrame
    by_pair: pd.DataFrame
    sources: pd.DataFrame

    def to_dataframe(self) -> pd.DataFrame:
        return self.indices


def sobol_share(mech, tolerances, output: str, n: int, seed: int, *, mode: str = "disc",
                **options) -> SobolShare:
    """The pins against the links by Sobol indices on `output` as evaluated (no adjustment):
    `sewtol.studies.sobol.sobol` on `clearance_variables` (n base samples, seeded; `options`
    go to it). See `SobolShare`."""
    from sewtol.studies.sobol import sobol

    varied, ts = clearance_variables(mech, tolerances, mode)
    res = sobol(varied, ts, output, n, seed, fast=False, **options)
    f = res.to_dataframe()
    f = f[f["case"] == f["case"].iloc[0]].copy()
    pair = {name: c.joint for c in revolute(mech) for name in polar_names(c.joint)}
    f.insert(0, "source", ["pin" if p in pair else "link" for p in f["param"]])
    f.insert(1, "pair", [pair.get(p, "") for p in f["param"]])
    pins = f[f["source"] == "pin"]
    by_pair = (pins.groupby("pair", sort=False)[["S1", "ST"]].sum().reset_index())
    sources = f.groupby("source", sort=False)[["S1", "ST"]].sum().reset_index()
    return SobolShare(mech.name, ts.name, output, mode, int(res.n), int(seed),
                      f.reset_index(drop=True), by_pair, sources)


# --- loaded mode: the contact direction follows the joint force ------------------------------


@dataclass(frozen=True)
class LoadedClearance:
    """The loaded mode (docs/clearances.md): each journal on its rim, r_j = c_j u_j, along the
    force u_j it presses on its bearing with (`kinetostatics.joint_forces`), per machine and
    angle; ``total`` = sum_j c_j J_j . u_j (first order; ``by_pair`` each term). A pair whose
    force is below 1e-9 of the largest stays centred. ``crossings_deg``: joint -> per machine,
    the crank angles where the force turns by more than 90 deg between two samples, interpolated
    where its component along its former direction passes zero."""

    output: str
    unit: str
    q_deg: np.ndarray
    rpm: float
    radius_mm: dict
    force_N: dict
    offsets_mm: dict
    total: np.ndarray
    by_pair: dict
    crossings_deg: dict

    def to_dataframe(self) -> pd.DataFrame:
        """One row per (machine, angle): the signal's move and each pair's force and term."""
        m, k = self.total.shape
        f = pd.DataFrame({"machine": np.repeat(np.arange(m), k), "q_deg": np.tile(self.q_deg, m),
                          f"loaded_{self.unit}": self.total.reshape(-1)})
        for j, v in self.by_pair.items():
            f[f"{j}_force_N"] = np.abs(self.force_N[j]).reshape(-1)
            f[f"{j}_force_deg"] = np.degrees(np.angle(self.force_N[j])).reshape(-1)
            f[f"{j}_{self.unit}"] = v.reshape(-1)
        return f

    def crossings(self) -> pd.DataFrame:
        """One row per crossing: pair, machine, crank angle (deg)."""
        rows = [{"pair": j, "machine": i, "q_deg": float(q)}
                for j, per in self.crossings_deg.items() for i, qs in enumerate(per) for q in qs]
        return pd.DataFrame(rows, columns=["pair", "machine", "q_deg"])


def _crossings(force: np.ndarray, q_deg: np.ndarray) -> list[tuple[float, ...]]:
    """Per machine, the angles where the force's direction reverses between two samples (the
    sampled turn closes on itself)."""
    nxt = np.roll(force, -1, axis=-1)
    a = np.abs(force)
    u = force / np.where(a > 0, a, 1.0)
    s0, s1 = a, (np.conjugate(u) * nxt).real  # the force's component along u, here and next
    step = 360.0 / q_deg.size
    out = []
    for i in range(force.shape[0]):
        k = np.flatnonzero((s1[i] < 0) & np.isfinite(s1[i]))
        t = s0[i, k] / (s0[i, k] - s1[i, k])
        out.append(tuple(float(v) for v in np.round((q_deg[k] + t * step) % 360.0, 6)))
    return out


def loaded(mech, values: dict | None, output: str, loads, rpm: float | None = None,
           clearance: str = "max", h_mm: float = H_MM) -> LoadedClearance:
    """The loaded mode on `output` for the machines of `values` (their journals centred to
    find the forces): see `LoadedClearance`. `loads`: PointLoad objects
    (`sewtol.mechanism.kinetostatics`); `rpm`: the crank speed (default the file's);
    `clearance`: each pair's "max" or "min" radial clearance."""
    from sewtol.mechanism.kinetostatics import joint_forces

    c = radii(mech, clearance)
    jf = joint_forces(mech, values, loads, rpm, h_mm)
    jac = jacobian(mech, {k: v for k, v in (values or {}).items()
                          if k in mech.parameter_names}, output, h_mm)
    scale = max((float(np.nanmax(np.abs(f), initial=0.0)) for f in jf.force_N.values()),
                default=0.0)
    offsets, by = {}, {}
    for j, f in jf.force_N.items():
        a = np.abs(f)
        loaded_ = a > 1e-9 * scale
        r = np.where(loaded_, c[j] * f / np.where(loaded_, a, 1.0), 0.0)
        offsets[j] = r
        by[j] = (np.conjugate(jac[j]) * r).real  # J_j . r_j
    total = sum(by.values())
    q_deg = np.degrees(mech.angles_rad())
    crossings = {j: _crossings(np.where(np.abs(f) > 1e-9 * scale, f, 0.0), q_deg)
                 for j, f in jf.force_N.items()}
    return LoadedClearance(output, mech.output(output).unit, q_deg, jf.rpm, c, jf.force_N,
                           offsets, total, by, crossings)


def fit_gap_um(fit: str, diameter_mm: float) -> tuple[float, float]:
    """The diametral clearance range (um) of a clearance fit (refused otherwise)."""
    f = iso_fit(fit, diameter_mm)
    if f.kind != "clearance":
        raise ParameterError("fit", f"must be a clearance fit for a guide that slides (this is "
                                    f"{f.kind})", fit)
    return f.clearance_min_um, f.clearance_max_um


# --- the guide pair as the criterion ---------------------------------------------------------

# hole-basis clearance fits a needle-bar guide may take, tightest first at 8 mm
GUIDE_FITS = ("H6/h5", "H6/g5", "H7/h6", "H7/g6", "H7/f7", "H8/f7", "H8/e8", "H9/d9",
              "H11/c11")


def machines_of(mech, tolerances, n: int, seed: int) -> dict[str, np.ndarray]:
    """n machines (absolute parameter values) drawn from a tolerance set, as the Monte-Carlo
    draws them (same seed, same machines)."""
    from sewtol.protocol import machines, tolerance_set
    from sewtol.studies.montecarlo import check_seed, draw_deviations

    check_seed(seed)
    ts = tolerance_set(mech, tolerances)
    return machines(mech, draw_deviations(ts, n, seed))


def adjusted_machines(mech, values: dict, adjust, output: str):
    """The machines with their compensators set, the adjusted output and status per machine:
    the mechanism's plug-in adjuster where the journals sit at their centres (it knows the
    link parameters only), else the generic adjuster, which sees the pair parameters."""
    from sewtol.studies.adjusting import adjusted

    pairs = {p.name for p in getattr(mech, "pair_parameters", ())}
    ideal = not any(np.any(np.asarray(values[k]) != 0) for k in pairs & set(values))

    m = len(next(iter(values.values())))
    if not adjust:
        ev = mech.evaluate(values, [output])
        return dict(values), ev.outputs[output], ev.status
    a = adjusted(mech, values, list(adjust), output, fast=ideal)
    out = dict(values)
    for param, setting in a.settings.items():
        out[param] = np.broadcast_to(np.asarray(setting, float), (m,))
    from sewtol.studies.montecarlo import WORDS  # a plug-in's words, as the Monte-Carlo reads them

    status = np.array([WORDS.get(w, w) for w in a.status], object)
    return out, np.asarray(a.value, float), status


@dataclass(frozen=True)
class GuideCriterion:
    """The guide pair as the criterion of a drive whose point E slides in a guide (the 208
    needle): per machine (after adjustment) the guide clearance it needs to run without binding
    and the needle's lateral play at the stitch, and per guide fit the machines that run and
    whose play stays within the limit. See `guide_criterion`."""

    mechanism: str
    tolerances: str
    strategy: str
    n: int
    seed: int
    guide_diameter_mm: float
    play_limit_um: float
    target_yield: float
    machines: pd.DataFrame
    fits: pd.DataFrame
    pins: pd.DataFrame

    def to_dataframe(self) -> pd.DataFrame:
        return self.machines

    def fit_reaching(self, column: str = "yield") -> tuple[str | None, str | None]:
        """(tightest, loosest) fit whose `column` (``yield``, or ``runs_share``) reaches the
        target yield; None where no fit does."""
        ok = self.fits[self.fits[column] >= self.target_yield]
        if ok.empty:
            return None, None
        return str(ok["fit"].iloc[0]), str(ok["fit"].iloc[-1])


def guide_criterion(mech, tolerances, n: int, seed: int, *, output: str | None = None,
                    adjust=("beta",), guide_diameter_mm: float = 8.0,
                    fits=GUIDE_FITS, play_limit_um: float = 20.0,
                    target_yield: float = 0.95) -> GuideCriterion:
    """The guide pair as the criterion (a line_deviation output: its point E slides on a rod
    along the line), on n machines drawn from `tolerances` (seeded; compensators `adjust` set
    per machine on `output`, ``()`` for none). Per machine: the guide gap it needs to run
    without binding with the pins at their tightest (``needed_gap_um``) and the lateral play at
    the stitch with each fit's largest gap and the pins at their largest; per fit, tightest
    first, the machines that run and keep the play within `play_limit_um` (failed machines
    count against the yield). The method: docs/clearances.md, "The guide pair as the criterion"."""
    pairs = revolute(mech)
    if output is None:
        output = next((o.name for o in mech.outputs if o.type == "line_deviation"), None)
    o = mech.output(output) if output is not None else None
    if o is None or o.type != "line_deviation":
        raise ParameterError("output", "must be a line_deviation output (the point in its guide)",
                             output)
    if not (isinstance(play_limit_um, int | float) and play_limit_um > 0):
        raise ParameterError("play_limit_um", "must be a positive number (um)", play_limit_um)
    if not 0 < target_yield < 1:
        raise ParameterError("target_yield", "must lie in (0, 1)", target_yield)
    gaps = {f: fit_gap_um(f, guide_diameter_mm) for f in fits}
    ts_name = tolerances if isinstance(tolerances, str) else tolerances.name
    values = machines_of(mech, tolerances, n, seed)
    values, adj_value, status = adjusted_machines(mech, values, adjust, output)
    state = mech.state(values)
    st, _ = mech.status_of(state)
    status = np.where(status == "ok", st, status)
    ok = status == "ok"
    d = signal(mech, state, output)
    f = resolved(o.fields, OUTPUT_TYPES[o.type].fields, state.points, state.angles, state.values)
    a = f["angle_deg"] * DEG
    along = (np.conjugate(np.sin(a) + 1j * np.cos(a)) * f["point"].p).real  # up the guide
    k = np.argmin(np.nan_to_num(along, nan=np.inf), axis=-1)
    rows = np.arange(len(k))
    jac = jacobian(mech, values, output)
    w_min = sum(c.radial_min_mm * np.abs(jac[c.joint]) for c in pairs)
    w_max = sum(c.radial_max_mm * np.abs(jac[c.joint]) for c in pairs)
    needed = 2.0 * np.maximum(0.0, np.max(np.abs(d) - w_min, axis=-1))
    needed_ideal = 2.0 * np.max(np.abs(d), axis=-1)
    d_s, w_s = d[rows, k], w_max[rows, k]
    frame = pd.DataFrame({
        "machine": rows, "status": status,
        f"{output}_adjusted" if adjust else output: np.where(ok, adj_value, np.nan),
        **{f"{mech.compensators[c].parameter}_setting": values[mech.compensators[c].parameter]
           for c in adjust or ()},
        "needed_gap_ideal_pins_um": np.where(ok, needed_ideal, np.nan),
        "needed_gap_um": np.where(ok, needed, np.nan),
        "stitch_deg": np.degrees(mech.angles_rad())[k],
        "d_stitch_um": np.where(ok, d_s, np.nan),
        "pin_reach_stitch_um": np.where(ok, w_s, np.nan),
        "pin_reach_min_um": np.where(ok, np.min(w_min, axis=-1), np.nan)})
    rows_f = []
    for fit, (g_lo, g_hi) in gaps.items():
        runs = ok & (needed <= g_lo)
        play = np.maximum(0.0, np.minimum(d_s + w_s, g_hi / 2) - np.maximum(d_s - w_s, -g_hi / 2))
        frame[f"play_{fit}_um"] = np.where(ok, play, np.nan)
        good = runs & (play <= play_limit_um)
        rows_f.append({"fit": fit, "gap_min_um": g_lo, "gap_max_um": g_hi,
                       "runs": int(runs.sum()), "binds": int((ok & ~runs).sum()),
                       "failed": int((~ok).sum()), "play_ok": int((ok & (play <= play_limit_um)).sum()),
                       "play_median_um": float(np.nanmedian(np.where(ok, play, np.nan))),
                       "runs_share": float(runs.mean()), "good": int(good.sum()),
                       "yield": float(good.mean())})
    fits_frame = pd.DataFrame(rows_f).sort_values("gap_max_um", kind="stable",
                                                  ignore_index=True)
    pins = pd.DataFrame({"pair": [c.joint for c in pairs],
                         "fit": [c.fit or "" for c in pairs],
                         "radial_min_um": [1e3 * c.radial_min_mm for c in pairs],
                         "radial_max_um": [1e3 * c.radial_max_mm for c in pairs],
                         "reach_max_at_stitch_um": [
                             float(np.nanmedian(np.where(ok, c.radial_max_mm
                                                         * np.abs(jac[c.joint][rows, k]), np.nan)))
                             for c in pairs]})
    strategy = ",".join(adjust) if adjust else "none"
    return GuideCriterion(mech.name, ts_name, strategy, int(n), int(seed),
                          float(guide_diameter_mm), float(play_limit_um), float(target_yield),
                          frame, fits_frame, pins)


# --- their share of the error ----------------------------------------------------------------

PIN_STREAM = 1  # the pins' random stream: SeedSequence(seed, spawn_key=(PIN_STREAM,))


def pin_rng(seed: int) -> np.random.Generator:
    """The generator of the journals' positions of a study seeded `seed` (a stream apart from
    the link deviations', which the tolerance law draws from the seed itself)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(PIN_STREAM,)))


@dataclass(frozen=True)
class ClearanceShare:
    """The pin clearances against the link tolerances, on one output after adjustment.

    ``cases``: one row per case (``links``: the tolerance set's machines, ideal pins; ``pins``:
    nominal links, each journal random in its circle; ``both``), with the failed machines, the
    mean, standard deviation and variance of the adjusted output, the yield within the spec,
    and the variance share of each case against ``both`` (what is left is their interaction).
    ``worst``: at the nominal machine (compensators at nominal), the first-order worst case of
    the output's signal per angle from the link tolerances (sum t_i |ds/dx_i|, t_i the
    half-width) and from the pins (sum c_j |J_j|, c_j the largest radial clearance), at the
    angle where their sum is largest."""

    mechanism: str
    tolerances: str
    strategy: str
    output: str
    n: int
    seed: int
    limit: float | None
    pins: str
    cases: pd.DataFrame
    worst: pd.DataFrame

    def to_dataframe(self) -> pd.DataFrame:
        return self.cases


def clearance_share(mech, tolerances, n: int, seed: int, *, output: str | None = None,
                    adjust=("beta",), pins: str = "drawn", rim: bool = False,
                    limit: float | None = None) -> ClearanceShare:
    """The share of `output`'s scatter (after `adjust`) from the pin clearances
    (random journals: `random_offsets` with ``clearance=pins`` and `rim`) against the link
    tolerances of `tolerances`, on n machines drawn with `seed`; the yield against `limit`
    (default the file's spec of the output). See `ClearanceShare`."""
    from sewtol.protocol import tolerance_set

    pairs = revolute(mech)
    if output is None:
        output = mech.specs[0].output if mech.specs else mech.output_names[0]
    mech.output(output)
    spec = mech.spec_of(output)
    upper = limit if limit is not None else (spec.upper if spec is not None else None)
    ts = tolerance_set(mech, tolerances)
    links = machines_of(mech, ts, n, seed)
    offsets = random_offsets(mech, n, pin_rng(seed), rim=rim, clearance=pins)
    nominal = {k: np.full(n, v) for k, v in mech.nominal_values().items() if k in links}
    cases = {"links": links, "pins": {**nominal, **offsets}, "both": {**links, **offsets}}
    rows, var = [], {}
    for case, values in cases.items():
        _, y, status = adjusted_machines(mech, values, adjust, output)
        ok = (status == "ok") & np.isfinite(y)
        var[case] = float(np.var(y[ok], ddof=1)) if ok.sum() > 1 else float("nan")
        good = ok & (y <= upper) if upper is not None else ok
        rows.append({"case": case, "n": int(n), "failed": int((~ok).sum()),
                     "mean": float(np.mean(y[ok])), "std": float(np.std(y[ok], ddof=1)),
                     "variance": var[case],
                     "within_limit": int(good.sum()), "yield": float(good.mean())})
    frame = pd.DataFrame(rows)
    frame["variance_share"] = frame["variance"] / var["both"]
    worst = _worst_share(mech, ts, output, pairs)
    strategy = ",".join(adjust) if adjust else "none"
    return ClearanceShare(mech.name, ts.name, strategy, output, int(n), int(seed), upper,
                          ("rim" if rim else "disc") + f", radius {pins}", frame, worst)


def _worst_share(mech, ts, output, pairs) -> pd.DataFrame:
    """Link tolerances against pins, first order, on the output's signal at the nominal machine
    (`ClearanceShare.worst`)."""
    try:
        state = mech.state()
        signal(mech, state, output)
    except ParameterError:
        return pd.DataFrame()  # the output has no signal over the turn (a speed, a minimum)
    nom = mech.nominal_values()
    items = ts.active().items
    h = {t.param: max(1e-9, 1e-4 * max(abs(nom[t.param]), 1.0)) for t in items}
    rows = []
    for t in items:
        plus, _ = _signal(mech, {t.param: [nom[t.param] + h[t.param]]}, output)
        minus, _ = _signal(mech, {t.param: [nom[t.param] - h[t.param]]}, output)
        slope = (plus[0] - minus[0]) / (2 * h[t.param])
        rows.append((t.param, (t.upper - t.lower) / 2 * np.abs(slope)))
    jac = jacobian(mech, None, output)
    pin_rows = [(c.joint, c.radial_max_mm * np.abs(jac[c.joint][0])) for c in pairs]
    link_w = sum(w for _, w in rows)
    pin_w = sum(w for _, w in pin_rows)
    k = int(np.nanargmax(link_w + pin_w))
    unit = mech.output(output).unit
    out = [{"source": "link", "name": p, f"worst_{unit}": float(w[k])} for p, w in rows]
    out += [{"source": "pin", "name": j, f"worst_{unit}": float(w[k])} for j, w in pin_rows]
    out += [{"source": "links", "name": "sum", f"worst_{unit}": float(link_w[k])},
            {"source": "pins", "name": "sum", f"worst_{unit}": float(pin_w[k])}]
    f = pd.DataFrame(out)
    f["share"] = f[f"worst_{unit}"] / float(link_w[k] + pin_w[k])
    f.attrs["q_deg"] = float(np.degrees(mech.angles_rad()[k]))
    return f
