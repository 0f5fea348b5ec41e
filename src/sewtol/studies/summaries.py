"""Tables of several outputs at once, for any mechanism (the protocol): a scan one row per
tolerance and side (`scan_table`), a Monte-Carlo's summary per output at chosen quantile
levels (`output_summary`), each output's contributors (`contributor_table`: bias-corrected
eta^2, `montecarlo.contributors`), the screening of the tolerances that matter to an output
(`important_parameters`) and Sobol indices of several outputs, each over its own screened
tolerances (`screened_sobol`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.studies.montecarlo import contributors, with_remainder
from sewtol.studies.sobol import CaseIndices, SobolResult, result_of, sobol
from sewtol.tolerances import ToleranceSet

if TYPE_CHECKING:
    import pandas as pd


def scan_table(result, outputs) -> pd.DataFrame:
    """The rows of a ScanResult as one row per tolerance and side: param, side, deviation,
    then per output its value (column OUTPUT) and its change from nominal (change_OUTPUT)."""
    import pandas as pd

    by = {k: f.reset_index(drop=True) for k, f in result.rows.groupby("output", sort=False)}
    frame = pd.DataFrame({"param": result.params, "side": result.sides,
                          "deviation": result.deviations})
    for k in outputs:
        frame[k] = by[k]["value"]
        frame[f"change_{k}"] = by[k]["change"]
    return frame


def quantile_column(level: float) -> str:
    """The column of a quantile level: p1 for 0.01, p0.135 for 0.00135."""
    return f"p{100.0 * level:.10g}"


def output_summary(machines: pd.DataFrame, outputs, levels=(0.01, 0.99), ok=None,
                   nominal: dict | None = None) -> pd.DataFrame:
    """Per output: n, failed (machines without a value, or outside the mask `ok`), then over the
    others mean, std (ddof 1), the quantiles at `levels` (linear interpolation; columns
    `quantile_column`), min and max (NaN where none is left); with `nominal` (output -> value)
    its value after the output's name."""
    import pandas as pd

    for q in levels:
        if not 0.0 <= q <= 1.0:
            raise ParameterError("levels", "must be quantile levels in [0, 1]", q)
    keep = np.ones(len(machines), bool) if ok is None else np.asarray(ok, bool)
    rows = []
    for k in outputs:
        x = machines[k]
        used = x[keep].dropna()
        row = {"output": k, **({} if nominal is None else {"nominal": nominal[k]}),
               "n": len(x), "failed": len(x) - len(used), "mean": used.mean(),
               "std": used.std(ddof=1)}
        row.update({quantile_column(q): used.quantile(q) for q in levels})
        rows.append(row | {"min": used.min(), "max": used.max()})
    return pd.DataFrame(rows)


def contributor_table(machines: pd.DataFrame, tolerances: ToleranceSet, outputs,
                      top: int = 10) -> pd.DataFrame:
    """Each output's `top` contributors, then the explained sum and the interaction remainder,
    one block of rows per output (column `output` first)."""
    import pandas as pd

    frames = []
    for k in outputs:
        f = with_remainder(contributors(machines, tolerances.active().params, k), top)
        f.insert(0, "output", k)
        frames.append(f)
    return pd.concat(frames, ignore_index=True)


def important_parameters(machines: pd.DataFrame, tolerances: ToleranceSet, output: str,
                         share: float = 0.9, min_params: int = 4,
                         max_params: int = 12) -> list[str]:
    """The tolerances that matter to `output`, from a Monte-Carlo's bias-corrected eta^2
    (`contributors`): in falling order until they hold `share` of the summed first-order
    effects, at least min_params and at most max_params."""
    f = contributors(machines, tolerances.active().params, output)
    k = int(np.searchsorted(f["cumulative_pct"].to_numpy(), 100.0 * share) + 1)
    return f["param"].tolist()[:min(max(k, min_params), max_params, len(f))]


def screened_sobol(mech, tolerances: ToleranceSet, outputs, n: int, seed: int,
                   machines: pd.DataFrame, *, share: float = 0.9, min_params: int = 4,
                   max_params: int = 12, **options) -> tuple[SobolResult, dict]:
    """Sobol indices of each output over its own important parameters (chosen from
    `machines`, a Monte-Carlo of the same set: `important_parameters`), one case per output on
    the design of its parameters (the set's order), at n and n / 2 base samples. options go to
    `sobol.sobol` (n_jobs, progress, scheduler, chunk_size, resamples, fast, ...). Returns
    the joined result (its convergence adds the number of parameters) and output ->
    parameters."""
    names, cases, chosen = set(mech.output_names), [], {}
    for output in outputs:
        if output not in names:
            raise ParameterError("output", f"must be one of {', '.join(mech.output_names)}",
                                 output)
        chosen[output] = important_parameters(machines, tolerances, output, share, min_params,
                                              max_params)
        sub = ToleranceSet(tolerances.name, tuple(t for t in tolerances.active().items
                                                  if t.param in chosen[output]),
                           tolerances.description)
        r = sobol(mech, sub, output, n, seed, **options)
        r.convergence.insert(1, "params", len(chosen[output]))
        cases.append(CaseIndices(output, r.indices, r.convergence, r.second_order, r.outcomes,
                                 r.feasibility, r.complete[output], r.failed[output]))
    # model runs: each case has its own D (n (D + 2) runs each), so none is given for all
    return result_of(cases, n, seed, tolerances.name, options.get("second_order", False)), chosen
