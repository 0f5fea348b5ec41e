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


FAST_PATH = FastPath("needle_208", ("L", "M", "B", "C", "E"), check_needle_208)
