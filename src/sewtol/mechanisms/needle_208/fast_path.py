"""The needle_208 fast path: the check that a mechanism file is the built-in 208 needle drive, so
that its studies may run on the fused kernels and the exact beta optimiser (sewtol.mechanism.fast_paths)."""

from __future__ import annotations

import numpy as np

from sewtol.mechanism.fast_paths import (
    CHECK_SEED,
    PERTURBED,
    POSITION_TOL_MM,
    SUMDELTA_TOL_UM,
    FastPath,
)


def needle_params(mech, values=None):
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208.model import Needle208

    vals = mech.nominal_values()
    vals.update(values or {})
    return Needle208(**{k: vals[k] for k in P.field_names(Needle208)})


def needle_perturbations(mech) -> dict[str, np.ndarray]:
    """Nominal plus PERTURBED machines: lengths +-0.05 mm, angles +-0.2 deg, frame +-0.05 mm."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208.model import Needle208

    rng = np.random.default_rng(CHECK_SEED)
    nominal = mech.nominal_values()
    out = {}
    for k in P.field_names(Needle208):
        if k.startswith(("branch_", "beta_sense")):
            continue
        step = 0.2 if k in ("beta", "CBE", "guide_angle") else 0.05
        out[k] = nominal[k] + np.concatenate([[0.0], rng.uniform(-step, step, PERTURBED)])
    return out


def needle_positions_residual(mech, values: dict[str, np.ndarray]) -> tuple[float, str]:
    """Largest |file - built-in| (mm) over L, M, B, C, E at the file's samples, and where."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208 import model as nd

    q = mech.angles_rad()
    state = mech.state(values, q)
    m = state.shape[0]
    built = nd.chain_from_crank(P.column(needle_params(mech, values), m), q[None, :])
    worst, where = 0.0, ""
    for name in ("L", "M", "B", "C", "E"):
        a = np.broadcast_to(built[name].p, state.shape)
        b = state.points[name].p
        # where a joint cannot close both models leave NaN: they must agree on where, too
        same_gaps = np.array_equal(np.isnan(a), np.isnan(b))
        both = ~np.isnan(a) & ~np.isnan(b)
        d = float(np.max(np.abs(a - b)[both], initial=0.0)) if same_gaps else np.inf
        if d > worst:
            worst, where = d, name
    return worst, where


def check_needle_208(mech) -> str:
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208.model import Needle208

    missing = [k for k in P.field_names(Needle208) if k not in mech.parameter_names]
    if missing:
        return "parameters missing: " + ", ".join(missing)
    points = [g.name for g in mech.groups]
    lacking = [p for p in ("L", "M", "B", "C", "E") if p not in points]
    if lacking:
        return "points missing: " + ", ".join(lacking)
    try:
        needle_params(mech)
    except ValueError as exc:
        return str(exc)
    values = needle_perturbations(mech)
    worst, where = needle_positions_residual(mech, values)
    if not worst <= POSITION_TOL_MM:
        return f"{where} differs by {worst:.3g} mm > {POSITION_TOL_MM:g} mm"
    return _needle_sumdelta_problem(mech, values)


def _needle_sumdelta_problem(mech, values) -> str:
    """The file's SumDelta (a line_deviation of E, sum_extremes) must be the built-in one: same
    guide, same figure (to SUMDELTA_TOL_UM), since the fast path computes the built-in's."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.model import Needle208

    outs = [o for o in mech.outputs if o.type == "line_deviation" and o.fields["point"] == "E"
            and o.fields["measure"] == "sum_extremes"]
    if not outs:
        return "no SumDelta output (a line_deviation of E with measure sum_extremes)"
    full = {**mech.nominal_values(), **values}
    n = len(next(iter(values.values())))
    batch = Needle208(**{k: np.broadcast_to(np.asarray(full[k], float), (n,))
                         for k in P.field_names(Needle208)})
    exact = nm.deviation_figures(nm.columns(batch)[0]).total_um
    for o in outs:
        ev = mech.evaluate(values, [o.name])
        got = ev.outputs[o.name]
        # machines that cannot run have no SumDelta in either model (the file also blanks its
        # dead points, which the built-in figure still gives): compare the machines that run
        runs = ev.status == "ok"
        diff = np.abs(got - exact)[runs]
        if not np.all(diff <= SUMDELTA_TOL_UM):
            return (f"output {o.name} differs from the built-in SumDelta by "
                    f"{float(np.max(np.where(np.isnan(diff), np.inf, diff))):.3g} um > "
                    f"{SUMDELTA_TOL_UM:g} um")
    return ""




# --- the plug-ins of the mechanism protocol (sewtol.protocol.Plugins) --------------------------
#
# The kernel gives SumDelta exactly (its extremes on the exact rocker interval, the fused numba
# kernel); the generic path takes them on the file's sampled crank angles, so it lies below by
# at most max|d''| (h/2)^2 / 2 at each extreme (Taylor, h the sample step): kernel_bound derives
# that per machine from the exact curve on a FINE grid, plus the 1e-9 mm the loader's check
# allows between the two models' positions.
FINE = 36000
POSITIONS_UM = 1e-6


def _batch(mech, values):
    """The machines `values` (the rest nominal) as parameter columns (n, 1), validated as a
    Needle208 batch (lengths > 0, finite, branch signs). Each column is a contiguous copy, as
    the kernels and numpy's SIMD loops (whose last bits may differ on strided input) take it."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208.model import Needle208

    full = {**mech.nominal_values(), **{k: np.asarray(v, float) for k, v in values.items()}}
    n = max([np.size(v) for v in full.values()] + [1])
    c = {k: np.broadcast_to(np.asarray(full[k], float).reshape(-1, 1), (n, 1)).copy()
         for k in P.field_names(Needle208)}
    Needle208(**{k: v[:, 0] for k, v in c.items()})
    return c, n


def sumdelta_outputs(mech) -> list[str]:
    """The file's SumDelta outputs (a line_deviation of E, sum_extremes): the loader checked
    each equals the built-in SumDelta, so the fast path answers for these."""
    return [o.name for o in mech.outputs if o.type == "line_deviation"
            and o.fields.get("point") == "E" and o.fields.get("measure") == "sum_extremes"]


def needle_kernel(mech, values) -> dict[str, np.ndarray]:
    """SumDelta (um) of machines `values` (parameter -> array; the rest nominal), exact, by the
    fused kernel, for every SumDelta output of the file; NaN where a machine does not run."""
    from sewtol.mechanisms.needle_208.metrics import total_um_kernel

    total = total_um_kernel(_batch(mech, values)[0])
    return {name: total for name in sumdelta_outputs(mech)}


def needle_kernel_bound(mech, values) -> dict[str, np.ndarray]:
    """How far below the exact SumDelta the file's sampled one may lie, per machine (um)."""
    from sewtol.mechanisms.needle_208 import metrics as nm

    c, n = _batch(mech, values)
    phi = np.arange(FINE) * 2 * np.pi / FINE
    d = nm.deviation_curve(c, phi)["d_um"]
    hf, h = 2 * np.pi / FINE, 2 * np.pi / mech.samples
    d2 = np.abs(np.roll(d, -1, axis=1) - 2 * d + np.roll(d, 1, axis=1)) / hf**2
    w = int(np.ceil(h / 2 / hf)) + 1
    rows = np.arange(n)[:, None]
    bound = np.zeros(n)
    for k in (np.nanargmax(d, axis=1), np.nanargmin(d, axis=1)):
        window = (k[:, None] + np.arange(-w, w + 1)[None, :]) % FINE
        bound += np.max(d2[rows, window], axis=1)
    bound = (h / 2) ** 2 / 2 * bound + POSITIONS_UM
    return {name: bound for name in sumdelta_outputs(mech)}


def needle_adjuster(mech, values, boxes: dict, figures: bool = True) -> dict:
    """The exact joint optimum of beta (and the guide shift) per machine: the sliding-window
    solution of mechanisms/needle_208/adjust.py. boxes: parameter -> (low, high), absolute.
    `value` is the kernel's SumDelta at the settings (within PLATEAU_TOL_UM of the minimum);
    `total_um`, `plus_um`, `minus_um` the exact figures there (needle_208.metrics). With
    figures=False (a Monte-Carlo's chunk: it reads the value and the settings) those figures
    are left out (the numpy reference costs twice the optimum) and `as_built` holds the
    kernel's SumDelta of the machines as given (`needle_kernel`), from the same columns and
    rocker intervals: the chunk's fixed case."""
    from sewtol.mechanisms.needle_208 import adjust as ad
    from sewtol.mechanisms.needle_208 import metrics as nm

    c, _ = _batch(mech, values)
    feas = nm.feasibility(c)  # the rocker interval does not depend on beta or the guide
    boxes = {k: tuple(map(float, v)) for k, v in boxes.items()}
    r = ad.optimise(c, boxes, feas=feas)
    out = {"value": r.total_um, "minimum": r.min_total_um, "settings": dict(r.settings),
           "low": dict(r.low), "high": dict(r.high), "status": r.status,
           "at_bound": dict(r.at_bound)}
    if not figures:
        total = nm.total_um_kernel(c, feas)
        return {**out, "as_built": {name: total for name in sumdelta_outputs(mech)}}
    dead = ~np.isfinite(r.settings["beta"])
    # the figures at the settings; a machine no setting runs is figured at the box centres
    figs = nm.deviation_figures(nm.with_values(c, **{
        k: np.where(dead, 0.5 * (boxes[k][0] + boxes[k][1]), v) for k, v in r.settings.items()}))
    return {**out, **{k: np.where(dead, np.nan, getattr(figs, k))
                      for k in ("total_um", "plus_um", "minus_um")}}


def needle_strategy_adjuster(mech, values, compensators, limit_um: float = 10.0,
                             plateaus: bool = True) -> dict:
    """A strategy's joint optimum per machine (needle_208.adjustment.adjust: steps, resolution,
    the guide angle and CD by an outer search): compensators are needle_208.compensators
    objects. Status in the needle's words ("ok", "out of spec" against limit_um, "cannot
    assemble", "dead point"); at_bound: a setting's plateau reaches an end of its range."""
    from sewtol.mechanisms.needle_208.adjustment import adjust
    from sewtol.mechanisms.needle_208.compensators import Strategy

    c, _ = _batch(mech, values)
    a = adjust(c, Strategy("adjusted", tuple(compensators)), limit_um, plateaus=plateaus)
    at_bound = {}
    for comp in compensators:
        eps = 1e-6 * (comp.high - comp.low)
        at_bound[comp.name] = ((a.plateau_low[comp.name] <= comp.low + eps)
                               | (a.plateau_high[comp.name] >= comp.high - eps))
    return {"value": a.total_um, "settings": dict(a.settings), "status": a.status,
            "at_bound": at_bound, "total_um": a.total_um, "plus_um": a.plus_um,
            "minus_um": a.minus_um, "low": dict(a.plateau_low), "high": dict(a.plateau_high),
            "achieved_um": a.achieved_um, "total_before_um": a.total_before_um,
            "at_limit": dict(a.at_limit)}


def needle_measured_adjuster(mech, values, compensators, phi_rad, noise_um,
                             limit_um: float = 10.0, plateaus: bool = True) -> dict:
    """The compensators set from a reading of d at the crank angles phi_rad with errors
    noise_um (machines x angles, um; needle_208.measurement), the true SumDelta at those
    settings; the strategy adjuster's keys plus ``measured_um`` (the SumDelta the fitter read).
    Plateaus are not searched (a reading's optimum is one setting): low = high = the setting."""
    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.measurement import adjust_measured

    c, _ = _batch(mech, values)
    a, measured = adjust_measured(c, Strategy("adjusted", tuple(compensators)), limit_um,
                                  phi_rad, noise_um)
    return {"value": a.total_um, "settings": dict(a.settings), "status": a.status,
            "at_bound": dict(a.at_limit), "total_um": a.total_um, "plus_um": a.plus_um,
            "minus_um": a.minus_um, "low": dict(a.plateau_low), "high": dict(a.plateau_high),
            "achieved_um": a.achieved_um, "total_before_um": a.total_before_um,
            "at_limit": dict(a.at_limit), "measured_um": measured}


def needle_failure_table(mech, values) -> dict[str, np.ndarray]:
    """Per machine at its values (beta as given): the first reason in assembly order it does
    not run (status.failure_reasons: status, group = the dyad, angle_deg, gap_mm,
    transmission_deg; status "unexplained" where none is found)."""
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.status import failure_reasons

    why = failure_reasons(nm.columns(needle_params(mech, values))[0])
    why["status"] = np.where(why["status"] == "", "unexplained", why["status"])
    why["group"] = why.pop("dyad")
    return why


# the source study's names of the generic studies' columns, in the order its tables show them
COLUMNS = {"montecarlo": {
    "SumDelta_um": "total_fixed_um", "beta_setting": "beta_opt_deg",
    "SumDelta_um_adjusted": "total_adjusted_um", "beta_low": "beta_low_deg",
    "beta_high": "beta_high_deg", "beta_at_bound": "beta_at_bound",
    **{f"{k}{case}": f"{v}_{case.strip('_') or 'fixed'}" for case in ("", "_adjusted")
       for k, v in (("status", "status"), ("failed_group", "fail_dyad"),
                    ("fail_angle_deg", "fail_angle_deg"), ("fail_gap_mm", "fail_gap_mm"),
                    ("fail_transmission_deg", "fail_transmission_deg"))},
    "beta_picks": "beta_picks_deg"},
    # the strategies table (sewtol.studies.strategies.COLUMNS; at_limit_* the per-compensator
    # shares): the source's counts cannot_assemble / dead_point and quantiles in um
    "strategies": {
        **{k: k for k in ("strategy", "resolution", "setting_error", "measurement_error", "n",
                          "ok", "out_of_spec")},
        "cannot_close": "cannot_assemble", "dead_point": "dead_point",
        **{k: k for k in ("yield", "yield_ci_low", "yield_ci_high")},
        "p50": "p50_um", "p95": "p95_um", "p99": "p99_um",
        **{k: k for k in ("Cpk", "at_limit_share", "at_limit_*", "at_limit", "achieved_yield",
                          "distinct_settings")}}}


def _plugins():
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208 import adjust as ad
    from sewtol.mechanisms.needle_208.kernels import ahead_of_time
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.protocol import Plugins

    return Plugins(kernel=needle_kernel, kernel_outputs=("SumDelta_um",),
                   kernel_bound=needle_kernel_bound, adjuster=needle_adjuster,
                   adjuster_sets=(frozenset({"beta"}), frozenset({"beta", "guide_shift_um"})),
                   adjusted_output="SumDelta_um", adjuster_tol=ad.PLATEAU_TOL_UM,
                   strategy_adjuster=needle_strategy_adjuster,
                   strategy_parameters=frozenset(P.field_names(Needle208)),
                   measured_adjuster=needle_measured_adjuster,
                   failure_table=needle_failure_table, serial=ahead_of_time,
                   columns=COLUMNS, name="needle_208")


FAST_PATH = FastPath("needle_208", ("L", "M", "B", "C", "E"), check_needle_208, _plugins())
