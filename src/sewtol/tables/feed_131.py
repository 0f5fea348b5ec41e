"""The feed's tables: a `Feed131` as a protocol mechanism (the folder's mechanism.toml with the
machine's values as nominals; its dog outputs, kind feed_dogs, are the closed-form figures) and
the outputs and columns of the feed report over the generic studies (sewtol.studies.scan,
montecarlo, summaries: summary, contributors, screened Sobol)."""

from __future__ import annotations

from functools import cache

import pandas as pd

from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131.model import Feed131
from sewtol.studies import summaries as SU
from sewtol.tolerances import ToleranceSet

OUTPUTS = ("lower_step_mm", "upper_step_mm", "differential_ratio", "mismatch_mm")
SOBOL_OUTPUTS = OUTPUTS[:3]
CONTRIBUTOR_OUTPUTS = ("lower_step_mm", "differential_ratio", "mismatch_mm")


@cache
def _file():
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    return load(mechanism_file("feed_131"))


def as_mechanism(params: Feed131):
    """The feed `params` (scalar fields) as a protocol mechanism: the folder's mechanism.toml
    with the machine's values as its nominals."""
    return _file().override(**{k: float(getattr(params, k)) for k in P.field_names(Feed131)})


def tolerance_sets() -> dict[str, ToleranceSet]:
    """The feed file's tolerance sets ("assumed": the report's; "links")."""
    return dict(_file().tolerance_sets)


def scan(params: Feed131, tolerances: ToleranceSet) -> pd.DataFrame:
    """Each tolerance at its limits, others nominal (sewtol.studies.scan): feed steps, ratio and
    mismatch, and the changes of the steps and the ratio, one row per tolerance and side."""
    from sewtol.studies import scan as S

    f = SU.scan_table(S.scan(as_mechanism(params), tolerances, OUTPUTS, zero_width=True),
                      OUTPUTS).rename(columns={"deviation": "delta_mm"})
    return f[["param", "side", "delta_mm", *OUTPUTS,
              *(f"change_{k}" for k in SOBOL_OUTPUTS)]]


def montecarlo(params: Feed131, tolerances: ToleranceSet, n: int, seed: int, n_jobs: int = 1,
               progress=False, scheduler=None) -> pd.DataFrame:
    """Feed outputs of n machines (sewtol.studies.montecarlo: progress bar or callback, Dask
    cluster): machine, deviations, outputs."""
    from sewtol.studies.montecarlo import montecarlo as mc

    res = mc(as_mechanism(params), tolerances, n, seed, OUTPUTS, n_jobs=n_jobs,
             progress=progress, scheduler=scheduler)
    return res.machines[["machine", *tolerances.active().params, *OUTPUTS]]


def sobol(params: Feed131, tolerances: ToleranceSet, n: int, seed: int, machines: pd.DataFrame,
          which: tuple[str, ...] = SOBOL_OUTPUTS, **options):
    """Sobol indices (SALib) of each feed output over its own important parameters, screened
    by `machines` (summaries.screened_sobol; options: its selection and sobol.sobol's)."""
    return SU.screened_sobol(as_mechanism(params), tolerances, which, n, seed, machines,
                             **options)
