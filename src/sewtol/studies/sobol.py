"""Sobol global sensitivity with SALib: first and total order with bootstrap intervals.

`sobol_indices` takes any vectorised model of an (N, D) matrix (the needle's SumDelta:
sewtol.mechanisms.needle_208.sobol; any file's output: sewtol.studies.generic.sobol). The Sobol'
sample of 2N base points starts with the sample of N base points, so one model run gives the
indices at N and 2N, and their difference shows whether they have converged.

second_order=True (SALib's calc_second_order) runs the design of N (2D + 2) rows instead of
N (D + 2) and adds the second-order indices S2_ij of every pair with their bootstrap intervals:
the share of Var(Y) that only the pair i, j together explains (ST_i - S1_i is the sum of every
interaction that involves i, so a large ST - S1 with S2 shows which partner it is).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from SALib.analyze import sobol as sobol_analyze
from SALib.sample import sobol as sobol_sample

from sewtol.errors import ParameterError
from sewtol.tolerances import ToleranceSet

if TYPE_CHECKING:

    pass

CHUNK = 1000


def problem_of(tolerances: ToleranceSet) -> dict:
    names, bounds, dists = [], [], []
    for t in tolerances.active().items:
        d, b = t.salib_dist()
        names.append(t.param)
        bounds.append(b)
        dists.append(d)
    return {"num_vars": len(names), "names": names, "bounds": bounds, "dists": dists}


# the convergence check compares the indices at N and N/2; below 8 base samples SALib's
# estimators and their bootstrap intervals are noise, so smaller N is refused, not printed
MIN_N = 16


def check_power_of_two(n):
    if isinstance(n, bool) or int(n) != n or n < MIN_N or (int(n) & (int(n) - 1)) != 0:
        raise ParameterError("n", f"must be a power of two >= {MIN_N} (Sobol' sequence balance; "
                             "the convergence check uses N/2)", n)


def rows_per_sample(d: int, second_order: bool = False) -> int:
    """Model runs per base sample: D + 2 (first and total order) or 2D + 2 (with S2)."""
    return 2 * d + 2 if second_order else d + 2


def check_sobol(nominal, tolerances: ToleranceSet, n, seed, second_order: bool = False) -> None:
    """Every input of a Sobol study that can be checked before it runs (nothing is written)."""
    from sewtol.studies.montecarlo import check_memory, check_seed

    check_power_of_two(n)
    check_seed(seed)
    d = len(tolerances.active().items)
    if d == 0:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(nominal)
    # the sample matrix (N (D + 2) or N (2D + 2) rows of D columns) and two outputs per row
    check_memory(int(n) * rows_per_sample(d, second_order), d + 2, value=n)


def sample(problem: dict, n: int, seed: int, second_order: bool = False) -> np.ndarray:
    check_power_of_two(n)
    return sobol_sample.sample(problem, int(n), calc_second_order=bool(second_order),
                               scramble=True, seed=seed)


def _salib_seed(seed: int) -> int:
    """SALib seeds its bootstrap only `if seed:`, so seed 0 would draw from numpy's global state
    and the confidence intervals would change from run to run. Seed 0 is a seed: it maps to a
    fixed non-zero one (every other seed is passed as it is, so their tables are unchanged)."""
    if seed:
        return int(seed)
    return int(np.random.SeedSequence(0).generate_state(1)[0]) or 1


def _analyze(problem: dict, y: np.ndarray, seed: int, resamples: int, conf_level: float,
             second_order: bool):
    if isinstance(resamples, bool) or int(resamples) != resamples or resamples < 2:
        raise ParameterError("resamples", "must be a whole number >= 2", resamples)
    if not (0 < conf_level < 1):
        raise ParameterError("conf_level", "must be in (0, 1)", conf_level)
    res = sobol_analyze.analyze(problem, y, calc_second_order=bool(second_order),
                                num_resamples=resamples, conf_level=conf_level,
                                seed=_salib_seed(seed))
    first = pd.DataFrame({"param": problem["names"], "S1": res["S1"], "S1_conf": res["S1_conf"],
                          "ST": res["ST"], "ST_conf": res["ST_conf"]})
    if not second_order:
        return first, None
    names = problem["names"]
    pairs = pd.DataFrame([{"param_i": names[i], "param_j": names[j], "S2": res["S2"][i, j],
                           "S2_conf": res["S2_conf"][i, j]}
                          for i in range(len(names)) for j in range(i + 1, len(names))],
                         columns=["param_i", "param_j", "S2", "S2_conf"])
    return first, pairs


def analyze(problem: dict, y: np.ndarray, seed: int, resamples: int = 200,
            conf_level: float = 0.95) -> pd.DataFrame:
    return _analyze(problem, y, seed, resamples, conf_level, False)[0]


@dataclass(frozen=True)
class SobolResult:
    """Sobol indices per case at n and n/2 base samples, and their convergence.

    ``to_dataframe()`` has the indices at n: ``param``, ``S1``, ``S1_conf``, ``ST``,
    ``ST_conf`` (first-order and total indices with the half-widths of their bootstrap
    intervals) and ``case``; ``convergence`` the largest change of S1 and ST between n/2 and n;
    ``failed`` the machines per case that could not run.
    """

    indices: pd.DataFrame  # param, S1, S1_conf, ST, ST_conf, case, n
    convergence: pd.DataFrame  # case, max |dS1|, max |dST| between n/2 and n
    n: int
    seed: int
    failed: dict
    tolerances: str
    # second_order=True: S2 of every pair (param_i, param_j, S2, S2_conf, case) at n
    second_order: pd.DataFrame | None = None
    model_runs: int = 0  # model evaluations per case (N (D + 2) or N (2D + 2))

    def second_order_frame(self) -> pd.DataFrame:
        """S2 per pair and case, largest first within each case; refused without the design."""
        if self.second_order is None:
            raise ParameterError("second_order", "was not computed; run with "
                                 "second_order=True (sewtol needle sobol --second-order)", False)
        return self.second_order.reset_index(drop=True)

    def to_dataframe(self) -> pd.DataFrame:
        """The indices at n: param, S1, S1_conf, ST, ST_conf, case."""
        return self.indices[self.indices["n"] == self.n].drop(columns="n").reset_index(drop=True)

    def to_records(self) -> list[dict]:
        """The indices at n as dicts (the JSON rows of ``sewtol needle sobol``)."""
        return self.to_dataframe()[["param", "S1", "S1_conf", "ST", "ST_conf", "case"]].to_dict(
            orient="records")


def sobol_indices(model, problem: dict, n: int, seed: int, case: str = "y",
                  resamples: int = 200) -> tuple[pd.DataFrame, pd.DataFrame, int]:
    """Indices of model at n and n/2 base samples; model maps (N, D) to (N,)."""
    X = sample(problem, n, seed)
    y = np.asarray(model(X), float)
    return indices_from(problem, y, n, seed, case, resamples)


def sobol_pairs(model, problem: dict, n: int, seed: int, case: str = "y",
                resamples: int = 200, conf_level: float = 0.95
                ) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """First, total and second-order Sobol indices of any vectorised model (SALib).

    Parameters
    ----------
    model : callable
        Maps an (N, D) array of inputs to N outputs.
    problem : dict
        SALib's problem: ``num_vars``, ``names``, ``bounds`` (and optionally ``dists``).
    n : int
        Base samples, a power of 2 (>= 16); the model runs n (2D + 2) times.
    seed : int
        Seeds the scrambled Sobol' sample and the bootstrap (0 is a seed).
    case : str
        The label of the rows (the ``case`` column).
    resamples : int
        Bootstrap resamples of the confidence intervals.
    conf_level : float
        Their confidence level, in (0, 1).

    Returns
    -------
    tuple of DataFrame
        S1/ST per parameter at n and n/2 (``n`` column), the convergence row (max |dS1|,
        |dST|, |dS2| between them) and the S2 of every pair at n (``param_i``, ``param_j``,
        ``S2``, ``S2_conf``, ``case``).
    """
    X = sample(problem, n, seed, second_order=True)
    y = np.asarray(model(X), float)
    both, conv, _, pairs = indices_and_pairs(problem, y, n, seed, case, resamples, conf_level,
                                              True)
    return both, conv, pairs


def indices_from(problem, y, n, seed, case, resamples, conf_level=0.95):
    return indices_and_pairs(problem, y, n, seed, case, resamples, conf_level, False)[:3]


def indices_and_pairs(problem, y, n, seed, case, resamples, conf_level=0.95,
                       second_order=False):
    d = rows_per_sample(problem["num_vars"], second_order) - 2
    failed = int(np.isnan(y).sum())
    if failed:
        raise ParameterError("sobol", f"{failed} of {y.size} samples cannot assemble ({case}); "
                             "Sobol indices need a model defined on the whole tolerance box",
                             failed)
    frames, pairs = [], []
    for m in (n // 2, n):  # the first m (d + 2) rows are the design of m base samples
        f, p = _analyze(problem, y[: m * (d + 2)], seed, resamples, conf_level, second_order)
        f["case"] = case
        f["n"] = m
        frames.append(f)
        pairs.append(p)
    both = pd.concat(frames, ignore_index=True)
    half, full = frames
    conv = {"case": case, "n_half": n // 2, "n": n,
            "max_abs_dS1": float(np.max(np.abs(full["S1"] - half["S1"]))),
            "max_abs_dST": float(np.max(np.abs(full["ST"] - half["ST"]))),
            "max_ST_conf": float(np.max(full["ST_conf"]))}
    if second_order:
        d2 = pairs[1]["S2"].to_numpy() - pairs[0]["S2"].to_numpy()
        conv["max_abs_dS2"] = float(np.max(np.abs(d2), initial=0.0))
        pairs[1].insert(4, "case", case)
    return both, pd.DataFrame([conv]), failed, pairs[1]
