"""What became of each machine of a needle study, per case (beta fixed, beta adjusted).

Status: `ok` (SumDelta <= limit), `out_of_spec` (SumDelta > limit), or a failure that names
why: `cannot_close` (a dyad misses: the dyad, the angle of its worst position and the gap in mm)
or `dead_point` (a dyad's links come within nd.DEAD_POINT_DEG of collinear: the dyad, the angle
and its smallest transmission angle). A failure is a machine whose SumDelta is NaN; its reason is
read from the exact feasibility functions at the beta of the case (the nominal beta when fixed,
the machine's adjusted beta, or the nominal beta if no beta in the range assembles it). A NaN
with no reason found there is `unexplained` (counted as a failure, never dropped).

So for every case, ok + out_of_spec + failed = n, with failed = cannot_close + dead_point +
unexplained.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd

STATUSES = ("ok", "out_of_spec", "cannot_close", "dead_point", "unexplained")
FAILURES = ("cannot_close", "dead_point", "unexplained")


@np.errstate(invalid="ignore")
def failure_reasons(c) -> dict[str, np.ndarray]:
    """Per machine of columns c: the first reason it cannot run (status, dyad, angle, gap, and
    the smallest transmission angle); status "" where it runs."""
    lo, hi, miss1, phi_fail = nd.rocker_interval(c)
    miss2, t_fail = nd.second_dyad_miss(c, lo, hi)
    g1, phi1, g2, t2 = nd.transmission_extremes(c, lo, hi)
    shape = np.shape(lo)
    miss1, phi_fail = np.broadcast_to(miss1, shape), np.broadcast_to(phi_fail, shape)
    g1, phi1 = np.broadcast_to(g1, shape), np.broadcast_to(phi1, shape)
    miss2 = np.where(np.isnan(miss2), np.inf, miss2)
    g1 = np.where(np.isnan(g1), 0.0, g1)
    g2 = np.where(np.isnan(g2), 0.0, g2)
    status = np.full(shape, "", dtype=object)
    dyad = np.full(shape, "", dtype=object)
    angle = np.full(shape, np.nan)
    gap = np.full(shape, np.nan)
    trans = np.minimum(g1, g2)
    # the first failing condition in assembly order wins
    rules = [
        (miss1 > 0, "cannot_close", "L-M-A", np.degrees(phi_fail) % 360, miss1),
        (miss2 > 0, "cannot_close", "B-C-D", np.degrees(t_fail), miss2),
        (g1 < nd.DEAD_POINT_DEG, "dead_point", "L-M-A", np.degrees(phi1) % 360, 0.0 * g1),
        (g2 < nd.DEAD_POINT_DEG, "dead_point", "B-C-D", np.degrees(t2), 0.0 * g2),
    ]
    for cond, st, dy, ang, g in reversed(rules):
        status = np.where(cond, st, status)
        dyad = np.where(cond, dy, dyad)
        angle = np.where(cond, ang, angle)
        gap = np.where(cond, g, gap)
    return {"status": status.ravel(), "dyad": dyad.ravel(), "angle_deg": angle.ravel(),
            "gap_mm": gap.ravel(), "transmission_deg": trans.ravel()}


def machine_status(nominal, machines: pd.DataFrame, params, limit_um: float) -> pd.DataFrame:
    """Status columns for a needle Monte-Carlo table (deviations in `params`, totals and the
    adjusted beta in total_fixed_um, total_adjusted_um, beta_opt_deg)."""
    dev = {k: machines[k].to_numpy(float) for k in params}
    n = len(machines)
    if not dev:
        dev = {"LF": np.zeros(n)}
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    beta_adj = machines["beta_opt_deg"].to_numpy(float)
    beta_nom = c["beta"][:, 0]
    cases = {"fixed": c,
             "adjusted": nm.with_values(c, beta=np.where(np.isfinite(beta_adj), beta_adj,
                                                         beta_nom))}
    out = {}
    for case, cc in cases.items():
        total = machines[f"total_{case}_um"].to_numpy(float)
        why = failure_reasons(cc)
        failed = np.isnan(total)
        status = np.where(total <= limit_um, "ok", "out_of_spec").astype(object)
        reason = np.where(why["status"] == "", "unexplained", why["status"])
        status = np.where(failed, reason, status)
        out[f"status_{case}"] = status
        out[f"fail_dyad_{case}"] = np.where(failed, why["dyad"], "")
        out[f"fail_angle_deg_{case}"] = np.where(failed, why["angle_deg"], np.nan)
        out[f"fail_gap_mm_{case}"] = np.where(failed, why["gap_mm"], np.nan)
        out[f"fail_transmission_deg_{case}"] = np.where(failed, why["transmission_deg"], np.nan)
    return pd.DataFrame(out, index=machines.index)


def counts(status: pd.Series | np.ndarray) -> dict[str, int]:
    """Machines per status plus `failed` (all failures) and `n`; ok + out_of_spec + failed = n."""
    s = pd.Series(np.asarray(status, dtype=object))
    vc = s.value_counts()
    out = {k: int(vc.get(k, 0)) for k in STATUSES}
    unknown = set(vc.index) - set(STATUSES)
    if unknown:
        raise ValueError(f"unknown status {sorted(unknown)}")
    out["failed"] = sum(out[k] for k in FAILURES)
    out["n"] = int(len(s))
    assert out["ok"] + out["out_of_spec"] + out["failed"] == out["n"]
    return out
