"""The per-parameter scan, and the largest single deviations, of any mechanism (the protocol):
`scan` sets each toleranced parameter at each limit (all 2k machines one batch; with
compensators the adjusted output and its settings); `largest_tolerances` finds per parameter
and side the largest |deviation| keeping one output within an upper limit (a geometric grid,
then bisection). Nothing here names a mechanism.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.optimize import bisect_root
from sewtol.protocol import NO_PLUGINS, machines, plugins
from sewtol.studies.adjusting import Adjusted, adjusted, evaluated
from sewtol.tolerances import ToleranceSet


def checked(mech, tolerances: ToleranceSet) -> ToleranceSet:
    """The set's tolerances of non-zero width, checked against the mechanism's parameters."""
    tol = tolerances.active()
    if not tol.items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(mech.parameter_record())
    return tol


@dataclass(frozen=True)
class ScanResult:
    """The scan's rows (`to_dataframe`: param, side, deviation, output, nominal, value, change,
    status, failed_group; rows OUTPUT_adjusted add the setting) and what they came from: the
    machines (param, side, deviation per row, `values` the batch) and the adjusted results of
    the rows and of the nominal machine (None without compensators)."""

    mechanism: str
    tolerances: str
    rows: pd.DataFrame
    params: list = field(default_factory=list)
    sides: list = field(default_factory=list)
    deviations: list = field(default_factory=list)
    values: dict = field(default_factory=dict)
    adjusted: Adjusted | None = None
    adjusted_nominal: Adjusted | None = None

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "tolerances": self.tolerances,
                "rows": self.rows.to_dict("records")}


def scan(mech, tolerances: ToleranceSet, outputs=None, adjust=None,
         adjusted_output: str | None = None, *, zero_width: bool = False, fast: bool = True,
         **options) -> ScanResult:
    """Each tolerance at its upper and lower limit (see the module docstring).

    outputs: the outputs evaluated (None: all; () none, only the adjusted case). adjust: the
    compensators (as `adjusting.adjusted` takes them), adjusted_output the output they minimise
    (default the first of `outputs`). zero_width: also scan tolerances of zero width. fast:
    use the mechanism's plug-ins (its kernel for the outputs it gives, its adjusters); options
    go to its strategy adjuster.
    """
    tol = checked(mech, tolerances)
    if zero_width:
        tol = tolerances
    names = mech.output_names if outputs is None else list(outputs)
    params, sides, deltas, dev = tol.limit_variants()
    values = machines(mech, dev)
    rows = []
    if names:
        from sewtol.studies.generic import nominal

        base = dict(nominal(mech).rows.set_index("output")["value"])
        ev = mech.evaluate(values, names)
        outs = dict(ev.outputs)
        pl = plugins(mech) if fast else NO_PLUGINS
        own = [k for k in names if pl.kernel is not None and k in pl.kernel_outputs]
        if own:  # the plug-in kernel's outputs (the mechanism's evaluation names the failures)
            got, got0 = pl.kernel(mech, values), pl.kernel(mech, {})
            outs.update({k: got[k] for k in own})
            base.update({k: float(got0[k][0]) for k in own})
    adj = adj0 = None
    if adjust is not None:
        target = adjusted_output or names[0]
        adj = adjusted(mech, values, adjust, target, fast=fast, **options)
        adj0 = adjusted(mech, None, adjust, target, fast=fast, **options)
    for i, (p, s, d) in enumerate(zip(params, sides, deltas, strict=True)):
        for name in names:
            v = float(outs[name][i])
            rows.append({"param": p, "side": s, "deviation": d, "output": name,
                         "nominal": float(base[name]), "value": v,
                         "change": v - float(base[name]), "status": ev.status[i],
                         "failed_group": ev.failed_group[i]})
        if adj is not None:
            v, v0 = float(adj.value[i]), float(adj0.value[0])
            row = {"param": p, "side": s, "deviation": d, "output": f"{target}_adjusted",
                   "nominal": v0, "value": v, "change": v - v0, "status": adj.status[i],
                   "failed_group": adj.extras.get("failed_group", [""] * len(params))[i]}
            rows.append(row | {f"setting{'' if k == 0 else f'_{name}'}": float(x[i])
                               for k, (name, x) in enumerate(adj.settings.items())})
    return ScanResult(mech.name, tolerances.name, pd.DataFrame(rows), params, sides, deltas,
                      values, adj, adj0)


def largest_tolerances(mech, params: list[str], output: str, limit: float, adjust=None,
                       max_dev: float = 1.0, xtol: float = 1e-5, figure: str | None = None,
                       *, fast: bool = True) -> pd.DataFrame:
    """Per parameter and side, the largest |deviation| <= max_dev with `output` <= limit.

    With `adjust` (compensators) the output is the adjusted one: its `value`, or the plug-in's
    extra figure named `figure`. `reaches_max` marks sides where even max_dev keeps the limit.
    Returns rows param, side (upper/lower), largest_deviation (signed), reaches_max.
    """
    jobs = [(p, s) for p in params for s in (1.0, -1.0)]
    jm = len(jobs)
    nominal = mech.nominal_values()
    for p in params:
        if p not in nominal:
            raise ParameterError("params", "must name parameters of the mechanism ("
                                 + ", ".join(nominal) + ")", p)
    grid = np.geomspace(1e-3, max_dev, 25)

    def out(deltas):
        """The output of machine k = job k % jm at |deviation| deltas[k]."""
        deltas = np.asarray(deltas, float)
        job = np.arange(deltas.size) % jm
        values = {p: np.full(deltas.size, nominal[p]) for p in params}
        for j, (p, s) in enumerate(jobs):
            rows = job == j
            values[p][rows] = values[p][rows] + s * deltas[rows]
        if adjust is None:
            return evaluated(mech, values, output, fast=fast)
        a = adjusted(mech, values, adjust, output, fast=fast)
        return a.value if figure is None else a.extras[figure]

    # grid: every job at every grid value in one batch
    tot = out(np.repeat(grid, jm)).reshape(grid.size, jm)
    exceed = ~(tot <= limit)
    first = np.where(exceed.any(axis=0), exceed.argmax(axis=0), -1)
    lo = np.where(first > 0, grid[np.maximum(first - 1, 0)], 0.0)
    hi = np.where(first >= 0, grid[np.maximum(first, 0)], max_dev)
    edge = bisect_root(lambda d: out(d) - limit, lo, hi, xtol=xtol)
    edge = np.where(first >= 0, edge, max_dev)
    return pd.DataFrame({
        "param": [p for p, _ in jobs], "side": ["upper" if s > 0 else "lower" for _, s in jobs],
        "largest_deviation": [s * e for (_, s), e in zip(jobs, edge, strict=True)],
        "reaches_max": first < 0,
    })
