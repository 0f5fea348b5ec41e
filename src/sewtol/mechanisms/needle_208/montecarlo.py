"""Monte-Carlo tolerance analysis of the needle drive over N machines.

Each machine draws its deviations from the tolerance set; SumDelta is computed with beta fixed at
the nominal machine's beta* and with beta re-optimised on the machine (the assembly adjustment).
Machines that cannot assemble are counted as failed and count against both yields; each case
has its own count (a machine may fail at the nominal beta and assemble at its adjusted beta), and
every summary satisfies ok + out_of_spec + failed = n (mechanisms/needle_208/status.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy import stats

from sewtol.errors import ParameterError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import status as ns
from sewtol.mechanisms.needle_208.evaluate import evaluate
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from distributed import Client

    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.studies.checkpoint import ChunkStore
from sewtol.studies.montecarlo import (
    CHUNK,
    check_sampling,
    contributors,
    quantiles,
    record,
    sample_machines,
    with_remainder,
)


def _needle_model(nominal, dev, range_deg):
    out = evaluate(nominal, dev, adjust=True, range_deg=range_deg)
    return {"total_fixed_um": out.total_fixed_um, "beta_opt_deg": out.beta_opt_deg,
            "total_adjusted_um": out.total_adjusted_um,
            "beta_low_deg": out.beta_low_deg, "beta_high_deg": out.beta_high_deg,
            "beta_at_bound": np.asarray(out.beta_at_bound, float)}


@dataclass(frozen=True)
class MonteCarloResult:
    """The machines of a needle Monte-Carlo and what they give (see `montecarlo`).

    Two cases: ``fixed`` (every machine at the fixed beta) and ``adjusted`` (beta re-optimised
    per machine). ``summary_frame()`` has per case the counts (``ok + out_of_spec + failed =
    n``), the yield with its Clopper-Pearson interval, SumDelta quantiles and capability;
    ``yield_of(case)``, ``yield_ci(case)``, ``counts(case)``, ``quantiles(case)`` and
    ``capability(case)`` give them one by one; ``machines`` has every machine's deviations
    (mm), outputs (um, deg) and status.
    """

    machines: pd.DataFrame  # deviations (mm) and outputs per machine
    params: tuple[str, ...]
    tolerances: str
    seed: int
    limit_um: float
    nominal_beta_deg: float  # the beta of the fixed case (see `montecarlo`'s fixed_beta)
    range_deg: tuple[float, float]
    fixed_beta: str = "optimum"

    @property
    def n(self) -> int:
        """The number of machines drawn."""
        return len(self.machines)

    @property
    def failed(self) -> int:
        """Machines that cannot run at the nominal beta (the fixed case; see `counts`)."""
        return self.counts("fixed")["failed"]

    @staticmethod
    def case_of(case: str) -> str:
        """'fixed' or 'adjusted'; the output names 'fixed_beta' and 'adjusted_beta' work too."""
        c = case[: -len("_beta")] if isinstance(case, str) and case.endswith("_beta") else case
        if c not in ("fixed", "adjusted"):
            raise ParameterError("case", "must be fixed, adjusted, fixed_beta or adjusted_beta",
                                 case)
        return c

    def status(self, case: str) -> np.ndarray:
        """Per machine: ok, out_of_spec, cannot_close, dead_point or unexplained."""
        case = self.case_of(case)
        col = f"status_{case}"
        if col in self.machines:
            return self.machines[col].to_numpy(object)
        total = self.machines[f"total_{case}_um"].to_numpy(float)
        return np.where(np.isnan(total), "unexplained",
                        np.where(total <= self.limit_um, "ok", "out_of_spec")).astype(object)

    def counts(self, case: str) -> dict[str, int]:
        """ok, out_of_spec, failed (= cannot_close + dead_point + unexplained) and n of a case."""
        return ns.counts(self.status(case))

    def passed(self, case: str) -> np.ndarray:
        """Per machine: True where SumDelta <= limit_um (a failed machine never passes)."""
        case = self.case_of(case)
        return (self.machines[f"total_{case}_um"] <= self.limit_um).to_numpy()

    def yield_of(self, case: str) -> float:
        """The share of machines that pass in a case (``"fixed"`` or ``"adjusted"``)."""
        return float(self.passed(case).mean())

    def yield_ci(self, case: str = "adjusted", level: float = 0.95) -> tuple[float, float]:
        """Clopper-Pearson interval of the yield."""
        case = self.case_of(case)
        k = int(self.passed(case).sum())
        ci = stats.binomtest(k, self.n).proportion_ci(confidence_level=level, method="exact")
        return float(ci.low), float(ci.high)

    def quantiles(self, case: str) -> dict:
        """p50, p95 and p99 of SumDelta (um); failed machines rank as infinitely bad, so they
        are not hidden by the quantiles (studies.montecarlo.quantiles)."""
        return quantiles(self.machines[f"total_{self.case_of(case)}_um"])

    def beta_range(self) -> tuple[float, float]:
        """The smallest and largest per-machine beta* (deg) among machines that assemble."""
        b = self.machines["beta_opt_deg"].dropna()
        return (float(b.min()), float(b.max())) if len(b) else (float("nan"), float("nan"))

    def capability(self, case: str) -> dict:
        """Cpu = (USL - mean) / 3 sigma, and the percentile form (USL - p50) / (p99.865 - p50)."""
        case = self.case_of(case)
        x = self.machines[f"total_{case}_um"].dropna().to_numpy()
        if x.size < 2:  # (almost) every machine failed: no scatter to speak of
            return {"Cpu": float("nan"), "Cpu_percentile": float("nan")}
        mean, sd = float(np.mean(x)), float(np.std(x, ddof=1))
        p50, p99865 = np.quantile(x, [0.5, 0.99865])
        return {"Cpu": (self.limit_um - mean) / (3 * sd) if sd > 0 else float("inf"),
                "Cpu_percentile": float((self.limit_um - p50) / (p99865 - p50))
                if p99865 > p50 else float("inf")}

    def pareto(self, case: str = "adjusted", bins: int = 20) -> pd.DataFrame:
        """Contributors to SumDelta's scatter (see `contributors`), with the explained sum and
        the interaction remainder as the last two rows (`with_remainder`)."""
        case = self.case_of(case)
        return with_remainder(contributors(self.machines, self.params, f"total_{case}_um", bins))

    def beta_at_bound(self, pinned: bool = False) -> int:
        """Machines whose adjusted beta*'s plateau (SumDelta within 1e-3 um of its minimum)
        reaches a bound of the searched range; pinned=True: only those whose plateau is narrower
        than PINNED_PLATEAU_DEG, where SumDelta still falls at the bound and the optimum likely
        lies outside the range (a wide plateau is flat: beta hardly matters there)."""
        col = self.machines.get("beta_at_bound")
        if col is None:
            return 0
        at = col.to_numpy(float) == 1.0
        if pinned:
            width = (self.machines["beta_high_deg"] - self.machines["beta_low_deg"]).to_numpy()
            at &= width < PINNED_PLATEAU_DEG
        return int(at.sum())

    def to_dict(self) -> dict:
        """The JSON of ``sewtol needle montecarlo``, the shape every Monte-Carlo shares
        (studies.montecarlo.record: counts, yields, labelled intervals and quantiles of both
        cases); extra: capability, beta* picks and their at-bound counts, the fixed case's
        beta and the searched range."""
        from sewtol.mechanism.spec import Spec

        cases = {"fixed_beta": "fixed", "adjusted_beta": "adjusted"}
        return record(
            mechanism="needle_208", n=self.n, seed=self.seed, tolerances=self.tolerances,
            output="SumDelta_um", unit="um", spec=Spec("SumDelta_um", self.limit_um),
            counts={k: self.counts(c) for k, c in cases.items()},
            quantiles={k: self.quantiles(c) for k, c in cases.items()},
            extra={"capability": {"definition": CAPABILITY_DEFINITION,
                                  **{k: self.capability(c) for k, c in cases.items()}},
                   "beta_picks_deg": list(self.beta_range()),
                   "beta_at_bound": self.beta_at_bound(),
                   "beta_pinned_at_bound": self.beta_at_bound(pinned=True),
                   "limit_um": self.limit_um,
                   "nominal_beta_deg": self.nominal_beta_deg,
                   "fixed_beta": self.fixed_beta,
                   "fixed_beta_means": FIXED_BETA_MEANS[self.fixed_beta],
                   "beta_search_range_deg": list(self.range_deg)})

    def summary_frame(self) -> pd.DataFrame:
        """One row per case: counts (ok + out_of_spec + failed = n), yield and interval, quantiles, Cpu."""
        rows = []
        for case in ("fixed", "adjusted"):
            q = self.quantiles(case)
            lo, hi = self.yield_ci(case)
            cap = self.capability(case)
            k = self.counts(case)
            rows.append({"case": f"{case}_beta", "n": self.n, "ok": k["ok"],
                         "out_of_spec": k["out_of_spec"], "failed": k["failed"],
                         "cannot_close": k["cannot_close"], "dead_point": k["dead_point"],
                         "yield": self.yield_of(case), "yield_ci_low": lo, "yield_ci_high": hi,
                         "p50_um": q["p50"], "p95_um": q["p95"], "p99_um": q["p99"],
                         "Cpu": cap["Cpu"], "Cpu_percentile": cap["Cpu_percentile"],
                         "beta_at_bound": self.beta_at_bound() if case == "adjusted" else 0,
                         "beta_pinned_at_bound": self.beta_at_bound(True)
                         if case == "adjusted" else 0})
        return pd.DataFrame(rows)


FIXED_BETA = ("optimum", "as_given")
FIXED_BETA_MEANS = {
    "optimum": "every machine keeps the nominal machine's beta* in the searched range (as "
               "`sewtol needle nominal` prints it for the same parameters)",
    "as_given": "every machine keeps the nominal's own beta parameter"}
# an adjusted optimum whose plateau reaches a bound and is narrower than this is pinned there
PINNED_PLATEAU_DEG = 0.1
CAPABILITY_DEFINITION = {
    "Cpu": "one-sided (limit_um - mean) / (3 sd) of SumDelta over the machines that run "
           "(failed machines are in counts, not in Cpu)",
    "Cpu_percentile": "(limit_um - p50) / (p99.865 - p50) over the machines that run"}


def fixed_beta_of(nominal, fixed_beta: str, range_deg, limit_um) -> float:
    """The beta every machine keeps in the fixed case.

    "optimum": the nominal machine's beta* in range_deg, exactly what `sewtol needle nominal`
    prints for the same parameters (so a study of a shifted guide is fixed at that guide's beta*,
    as an assembler would set it); "as_given": the nominal's own beta parameter.
    """
    if fixed_beta == "as_given":
        return float(nominal.beta)
    if fixed_beta != "optimum":
        raise ParameterError("fixed_beta", f"must be one of {', '.join(FIXED_BETA)}", fixed_beta)
    from sewtol.mechanisms.needle_208.single import nominal_figures

    return float(nominal_figures(nominal, tuple(range_deg), limit_um).beta_opt_deg)


def montecarlo(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
               limit_um: float = 10.0, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
               n_jobs: int = 1, progress: bool | Callable[[int, int], None] = False,
               backend: str | None = None, chunk_size: int = CHUNK,
               store: ChunkStore | None = None, fixed_beta: str = "optimum",
               scheduler: str | Client | None = None) -> MonteCarloResult:
    """N machines in chunks of chunk_size, chunk i drawing from child i of the seed.

    The fixed case keeps every machine at the nominal machine's beta* (fixed_beta="optimum",
    the default) or at the nominal's own beta parameter (fixed_beta="as_given"); the adjusted case
    re-optimises beta per machine in range_deg. With a ChunkStore (studies.checkpoint) finished
    chunks are saved as they arrive and an interrupted study resumes without recomputing them.
    progress: True (bar on stderr) or a callable progress(done, total) in chunks; scheduler: run
    on a Dask cluster (address or distributed.Client), same machines as a local run.

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters); machines deviate from it.
    tolerances : ToleranceSet or str
        What each machine's parameters draw from (deviations in mm, deg or um).
    n : int
        The number of machines (>= 1).
    seed : int
        The seed (>= 0; 0 is a seed). Chunk i draws from child i of
        ``numpy.random.default_rng(seed)`` (``spawn``).
    limit_um : float
        The SumDelta limit (um) a machine must keep to count as ok; default 10.
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg; default (10, 35).
    n_jobs : int
        Worker processes on this machine (joblib); the tables do not depend on it.
    progress : bool or callable
        True: a bar on stderr; a callable ``progress(done, total)`` is called as chunks finish.
    backend : str or None
        A joblib backend (e.g. ``"dask"`` inside a ``distributed.Client()``); None: joblib's
        default.
    chunk_size : int
        Machines per chunk; part of the study's identity (another chunk size draws other
        machines).
    store : ChunkStore or None
        A study folder (``studies.checkpoint.ChunkStore``) that saves finished chunks and
        resumes an interrupted study.
    fixed_beta : str
        ``"optimum"``: the fixed case is the nominal machine's beta*; ``"as_given"``: the
        nominal's own ``beta`` parameter.
    scheduler : str, distributed.Client or None
        A Dask scheduler address or client: the chunks run on that cluster.

    Returns
    -------
    MonteCarloResult
        Every machine with its deviations, SumDelta (um) in both cases, beta* (deg) and status;
        yields, counts, quantiles and capability per case.

    Raises
    ------
    ParameterError
        For a bad n, seed, limit, range or tolerance set (before anything runs).

    Examples
    --------
    >>> import sewtol
    >>> res = sewtol.montecarlo(sewtol.Needle208.nominal(), sewtol.tolerance_set("base"),
    ...                         n=200, seed=2026)
    >>> c = res.counts("adjusted")
    >>> c["ok"] + c["out_of_spec"] + c["failed"] == 200
    True
    """
    tolerances = needle_set(tolerances)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    sb.check_range(range_deg, limit_um)
    params = tuple(tolerances.active().params)
    check_sampling(nominal, tolerances, n, seed, chunk_size, columns=len(params) + 14)
    nominal = nominal.override(beta=fixed_beta_of(nominal, fixed_beta, range_deg, limit_um))
    machines = sample_machines(_needle_model, nominal, tolerances, n, seed, n_jobs, progress,
                               backend, chunk_size, store=store, scheduler=scheduler,
                               range_deg=range_deg)
    status = ns.machine_status(nominal, machines, params, float(limit_um))
    machines = pd.concat([machines, status], axis=1)
    return MonteCarloResult(machines, params, tolerances.name,
                            int(seed), float(limit_um), float(nominal.beta),
                            tuple(map(float, range_deg)), fixed_beta)
