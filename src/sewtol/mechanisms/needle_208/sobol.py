"""Sobol indices of the needle's SumDelta, beta fixed and beta re-optimised per sample (on the
exact optimiser), with the generic machinery of sewtol.studies.sobol (SALib). Machines that
cannot be built follow studies.sobol.POLICY: each one's reason (cannot_close, dead_point,
unexplained) and dyad come from needle_208.status.failure_reasons at the nominal (fixed) beta,
as for a Monte-Carlo machine that no beta in the range assembles.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.evaluate import evaluate
from sewtol.studies.parallel import chunk_bounds, run_chunks
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from distributed import Client

    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.studies.checkpoint import ChunkStore
from sewtol.studies.sobol import CHUNK, SobolResult, case_indices, check_sobol, problem_of, result_of, sample


def _failures(nominal, names, X, bad) -> tuple[np.ndarray, np.ndarray]:
    """(status, dyad) per row: "ok" and "" where bad is False, else why the machine does not
    run at the nominal beta (status.failure_reasons; "unexplained" when no reason is found)."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.status import failure_reasons

    status = np.full(len(X), "ok", dtype=object)
    dyad = np.full(len(X), "", dtype=object)
    if bad.any():
        c, _ = nm.columns(P.with_deviations(nominal, {k: X[bad, i] for i, k in enumerate(names)}))
        why = failure_reasons(c)
        status[bad] = np.where(why["status"] == "", "unexplained", why["status"])
        dyad[bad] = why["dyad"]
    return status, dyad


def _needle_chunk(nominal, names, X, range_deg, strategy=None, limit_um=sb.DEFAULT_LIMIT_UM):
    dev = {k: X[:, i] for i, k in enumerate(names)}
    if strategy is None:
        out = evaluate(nominal, dev, adjust=True, range_deg=range_deg)
        return out.total_fixed_um, out.total_adjusted_um
    from sewtol.mechanisms.needle_208.adjustment import adjust, columns_of

    fixed = evaluate(nominal, dev, adjust=False, range_deg=range_deg).total_fixed_um
    return fixed, adjust(columns_of(nominal, dev), strategy, limit_um, plateaus=False).total_um


def needle_sobol(nominal: Needle208, tolerances: ToleranceSet | str, n: int, seed: int,
                 range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG, n_jobs: int = 1,
                 progress: bool | Callable[[int, int], None] = False,
                 backend: str | None = None, resamples: int = 200,
                 chunk_size: int = CHUNK, store: ChunkStore | None = None,
                 conf_level: float = 0.95, fixed_beta: str = "optimum",
                 limit_um: float = sb.DEFAULT_LIMIT_UM,
                 scheduler: str | Client | None = None,
                 strategy: Strategy | None = None,
                 second_order: bool = False) -> SobolResult:
    """Sobol indices of SumDelta, beta fixed and beta adjusted, at n and n/2 base samples.

    strategy (a needle_208.compensators.Strategy): the adjusted case is SumDelta after the
    strategy's exact joint optimum (needle_208.adjustment.adjust), its case named
    "adjusted_" + strategy.name ("adjusted_beta" for beta alone, as without it); the fixed case
    is unchanged. None: beta re-optimised in range_deg.

    beta fixed means what it means in `montecarlo` (fixed_beta: "optimum", the nominal's beta*
    as `sewtol needle nominal` prints it, or "as_given"). progress: True (bar on stderr) or
    progress(done, total) in chunks; scheduler: run the model on a Dask cluster (address or
    distributed.Client; parallel.run_chunks).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        The inputs: each tolerance is one factor with its distribution (uniform, normal,
        truncated normal).
    n : int
        Base samples, a power of 2 (>= 16); the sample holds n (k + 2) machines for k factors,
        each evaluated in both cases.
    seed : int
        Seeds the scrambled Sobol' sample and the bootstrap (>= 0; 0 is a seed).
    range_deg : tuple of float
        The regulating range for beta, (low, high) in deg.
    n_jobs : int
        Worker processes on this machine (joblib); the indices do not depend on it.
    progress : bool or callable
        True: a bar on stderr; a callable ``progress(done, total)`` is called as chunks finish.
    backend : str or None
        A joblib backend (e.g. ``"dask"`` inside a ``distributed.Client()``); None: joblib's
        default.
    resamples : int
        Bootstrap resamples for the confidence intervals.
    chunk_size : int
        Model runs per chunk.
    store : ChunkStore or None
        A study folder that saves finished chunks and resumes an interrupted study.
    conf_level : float
        The confidence level of the bootstrap intervals, in (0, 1).
    fixed_beta : str
        ``"optimum"`` (the nominal's beta*) or ``"as_given"`` (its ``beta`` parameter).
    limit_um : float
        The SumDelta limit (um) used by the beta search.
    scheduler : str, distributed.Client or None
        A Dask scheduler address or client: the model runs on that cluster.
    strategy : Strategy or None
        The adjusted case: None for beta re-optimised, or a strategy's joint optimum.
    second_order : bool
        True: the design of n (2k + 2) machines per case and the second-order index S2 of
        every pair with its interval (`SobolResult.second_order_frame()`); the S1/ST of that
        design differ from the first-order design's by their sampling error only.

    Returns
    -------
    SobolResult
        S1 and ST with their confidence half-widths per parameter and case
        (``fixed_beta``, ``adjusted_<strategy>``), at n and n/2, and the convergence table
        (with second_order, the S2 pairs and max |dS2|).
    """
    tolerances = needle_set(tolerances)
    from sewtol.mechanisms.needle_208.tables import fixed_beta_of

    check_sobol(nominal, tolerances, n, seed, second_order)
    sb.check_range(range_deg, limit_um)
    nominal = nominal.override(beta=fixed_beta_of(nominal, fixed_beta, range_deg, limit_um))
    problem = problem_of(tolerances)
    X = sample(problem, n, seed, second_order)
    bounds = chunk_bounds(len(X), chunk_size)

    def validate(i, part):
        m = bounds[i][1] - bounds[i][0]
        if not (isinstance(part, tuple) and len(part) == 2
                and all(np.shape(p) == (m,) for p in part)):
            return f"does not hold two outputs of {m} samples"
        return None

    tail = () if strategy is None else (strategy, limit_um)
    parts = run_chunks(_needle_chunk, [(nominal, problem["names"], X[a:b], range_deg, *tail)
                                       for a, b in bounds],
                       n_jobs=n_jobs, progress=progress, desc="Sobol", backend=backend,
                       store=store, validate=validate, scheduler=scheduler)
    y_fixed = np.concatenate([p[0] for p in parts])
    y_adj = np.concatenate([p[1] for p in parts])
    status, dyad = _failures(nominal, problem["names"], X,
                             ~(np.isfinite(y_fixed) & np.isfinite(y_adj)))
    adjusted = "adjusted_beta" if strategy is None else "adjusted_" + strategy.name
    return result_of([case_indices(problem, X, y, n, seed, case, resamples, conf_level,
                                   second_order, np.where(np.isfinite(y), "ok", status), dyad)
                      for case, y in (("fixed_beta", y_fixed), (adjusted, y_adj))],
                     n, seed, tolerances.name, second_order, len(X))
