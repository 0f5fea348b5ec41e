"""The feed's tables of the generic studies: a `Feed131` as a protocol mechanism (the folder's
mechanism.toml with the machine's values as nominals; its dog outputs are the closed-form
figures, kind feed_dogs) and the scan, Monte-Carlo (the one sampler), contributors and Sobol
indices (rows that cannot run counted: studies.sobol.POLICY) of sewtol.studies in the feed
report's columns.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131.model import Feed131
from sewtol.protocol import machines
from sewtol.studies.montecarlo import contributors, sample_machines, with_remainder
from sewtol.tolerances import Tolerance, ToleranceSet

OUTPUTS = ("lower_step_mm", "upper_step_mm", "differential_ratio", "mismatch_mm")
SOBOL_OUTPUTS = OUTPUTS[:3]


@cache
def _file():
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    return load(mechanism_file("feed_131"))


def as_mechanism(params: Feed131):
    """The feed `params` (scalar fields) as a protocol mechanism: the folder's mechanism.toml
    with the machine's values as its nominals."""
    return _file().override(**{k: float(getattr(params, k)) for k in P.field_names(Feed131)})


def default_tolerances(params: Feed131 | None = None, link_mm: float = 0.05,
                       pivot_mm: float = 0.05) -> ToleranceSet:
    """An assumed set (the source gives no feed tolerances): every link length +/- link_mm and
    every frame-pivot coordinate +/- pivot_mm, uniform."""
    names = list(Feed131.LENGTHS)
    pivots = [f for f in P.field_names(Feed131) if f[-1] in "xy" and f[:-1] in
              ("O2", "O3", "O4", "O5", "O6", "O7", "O8", "X", "U")]
    items = tuple(Tolerance(n, -link_mm, link_mm) for n in names) + \
        tuple(Tolerance(n, -pivot_mm, pivot_mm) for n in pivots)
    return ToleranceSet("feed_assumed", items,
                        f"assumed: links +/-{link_mm} mm, frame pivots +/-{pivot_mm} mm, uniform")


def scan(params: Feed131, tolerances: ToleranceSet) -> pd.DataFrame:
    """Each tolerance at its limits, others nominal (sewtol.studies.scan): feed steps, ratio and
    mismatch, and the changes of the steps and the ratio, one row per tolerance and side."""
    from sewtol.studies import scan as S

    r = S.scan(as_mechanism(params), tolerances, OUTPUTS, zero_width=True)
    by = {k: f.reset_index(drop=True) for k, f in r.rows.groupby("output", sort=False)}
    frame = pd.DataFrame({"param": r.params, "side": r.sides, "delta_mm": r.deviations,
                          **{k: by[k]["value"] for k in OUTPUTS}})
    for k in SOBOL_OUTPUTS:
        frame[f"change_{k}"] = by[k]["change"]
    return frame


def _outputs(record, deviations: dict, mech, names) -> dict:
    return mech.evaluate(machines(mech, deviations), names).outputs


def montecarlo(params: Feed131, tolerances: ToleranceSet, n: int, seed: int, n_jobs: int = 1,
               progress=False, scheduler=None) -> pd.DataFrame:
    """Feed outputs of n machines (sample_machines: progress bar or callback, Dask cluster)."""
    mech = as_mechanism(params)
    return sample_machines(_outputs, mech.parameter_record(), tolerances, n, seed, n_jobs,
                           progress, desc="feed Monte-Carlo", scheduler=scheduler, mech=mech,
                           names=list(OUTPUTS))


def montecarlo_summary(machines: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for k in OUTPUTS:
        x = machines[k]
        ok = x.dropna()
        rows.append({"output": k, "n": len(x), "failed": int(x.isna().sum()),
                     "mean": ok.mean(), "std": ok.std(ddof=1), "p1": ok.quantile(0.01),
                     "p99": ok.quantile(0.99), "min": ok.min(), "max": ok.max()})
    return pd.DataFrame(rows)


def contributor_table(machines: pd.DataFrame, tolerances: ToleranceSet, top: int = 10):
    frames = []
    for k in ("lower_step_mm", "differential_ratio", "mismatch_mm"):
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


def _sobol_chunk(mech, names, X, output):
    ev = mech.evaluate(machines(mech, {k: X[:, i] for i, k in enumerate(names)}), [output])
    return ev.outputs[output], ev.status, ev.failed_group


def sobol(params: Feed131, tolerances: ToleranceSet, n: int, seed: int, machines: pd.DataFrame,
          which: tuple[str, ...] = SOBOL_OUTPUTS, n_jobs: int = 1, progress=False,
          scheduler=None, chunk_size: int = 512, resamples: int = 200, **select):
    """Sobol indices (SALib) of each feed output over its own important parameters (chosen
    from `machines`, a Monte-Carlo of the same set; `select` goes to important_parameters),
    at n and n / 2 base samples (the convergence table). Chunks run like every study
    (n_jobs, progress, scheduler); rows that cannot run are counted (studies.sobol.POLICY)."""
    from sewtol.studies.parallel import chunk_bounds, run_chunks
    from sewtol.studies.sobol import case_indices, check_independent, problem_of, result_of, sample

    check_independent(tolerances)
    mech = as_mechanism(params)
    cases, chosen = [], {}
    for output in which:
        if output not in OUTPUTS:
            raise ParameterError("output", f"must be one of {', '.join(OUTPUTS)}", output)
        names = important_parameters(machines, tolerances, output, **select)
        chosen[output] = names
        problem = problem_of(ToleranceSet(tolerances.name, tuple(
            t for t in tolerances.active().items if t.param in names), tolerances.description))
        X = sample(problem, n, seed)
        parts = run_chunks(_sobol_chunk, [(mech, problem["names"], X[a:b], output)
                                          for a, b in chunk_bounds(len(X), chunk_size)],
                           n_jobs=n_jobs, progress=progress, desc=f"feed Sobol {output}",
                           scheduler=scheduler)
        y, status, group = (np.concatenate(p) for p in zip(*parts, strict=True))
        c = case_indices(problem, X, y, n, seed, output, resamples, status=status, group=group)
        c.convergence.insert(1, "params", len(names))
        cases.append(c)
    return result_of(cases, n, seed, tolerances.name), chosen
