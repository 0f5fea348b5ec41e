"""Why a needle machine does not run: the plug-in (fast_path.needle_failure_table) by which
every study names each machine's status, per case (beta fixed, beta adjusted).

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

from sewtol.mechanisms.needle_208 import model as nd


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
