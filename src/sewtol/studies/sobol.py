"""Sobol global sensitivity with SALib: first and total order (and, with second_order, S2 of
every pair) with bootstrap intervals, of one output of any protocol mechanism, as evaluated
and/or adjusted per machine, run in chunks (`sewtol.studies.parallel.run_chunks`). The design
of 2N base points starts with that of N, so one run gives the indices at N and 2N. Machines
that cannot be built are never refused nor dropped: every row gets an outcome, `feasibility`
holds the indices of "assembles", S1/ST/S2 come from the complete blocks and S1_given from all
assembled rows (docs/studies.md, "Sobol with machines that cannot be built").
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from SALib.analyze import sobol as sobol_analyze
from SALib.sample import sobol as sobol_sample
from scipy import stats

from sewtol.errors import ParameterError
from sewtol.law import refuse_conditioned
from sewtol.protocol import machines, words_of
from sewtol.studies.adjusting import adjusted, evaluated, failures_of
from sewtol.studies.parallel import chunk_bounds, run_chunks
from sewtol.tolerances import ToleranceSet

CHUNK = 1000
POLICY = ("rows that cannot be built are counted, never dropped: feasibility = Sobol indices of "
          "the indicator 'assembles' on the whole design; S1, ST (and S2) = the output's indices "
          "on the base samples whose every row assembled (exact when the machines that assemble "
          "form a box of tolerances, otherwise leaning to machines far from the failure "
          "boundary); S1_given = the output's first-order index among all assembled rows "
          "(correlation ratio over quantile bins, exact under the dependence failures induce)")
# the given-data first-order index bins each input into quantile bins of ROWS_PER_BIN rows,
# between 10 and 100 bins: a bin averages E[Y | x] over its width (Ishigami's 7 sin^2 x2 loses
# 3 % of its variance to 20 bins, 0.1 % to 100), while epsilon^2 removes the noise of the means
ROWS_PER_BIN, MAX_BINS = 100, 100
# below these, an index is NaN (undefined, never a guess): complete base samples for S1/ST (the
# floor MIN_N // 2 of the convergence check) and assembled rows for S1_given (2 per bin)
MIN_COMPLETE, MIN_GIVEN_ROWS = 8, 20
# the bootstraps hold one block of resamples at a time: about this many (sample, resample)
# cells per array (2 MB), so SALib's estimators hold about 25 MB of temporaries at any N
BOOTSTRAP_CELLS = 2**18
BOOTSTRAP_ARRAYS = 12  # such arrays alive at once (measured: 7 without S2, 10 with)


def check_independent(tolerances: ToleranceSet) -> None:
    """Sobol indices decompose the variance of independent inputs only: a set with a
    dependence (`correlation`, `setup`) is refused, pointing to the Shapley effects, and so is
    one with relations (sewtol.relations)."""
    dep = tolerances.active().dependence
    if dep is not None:
        raise ParameterError("tolerances", f"ties {', '.join(dep.params)} (a correlation); Sobol "
                             "indices need independent inputs: use the Shapley effects "
                             "(sewtol run NAME shapley)", tolerances.name)
    refuse_conditioned(tolerances, "limits a quantity of several deviations (a relation), so "
                       "the inputs are not independent: Sobol indices need independent inputs",
                       "matches parts at assembly, so the inputs are not independent: Sobol "
                       "indices need independent inputs")


def problem_of(tolerances: ToleranceSet) -> dict:
    check_independent(tolerances)
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


def check_sobol(nominal, tolerances: ToleranceSet, n, seed, second_order: bool = False,
                resamples: int = 200) -> None:
    """Every input of a Sobol study that can be checked before it runs (nothing is written)."""
    from sewtol.studies.montecarlo import check_memory, check_seed

    check_power_of_two(n)
    check_seed(seed)
    check_independent(tolerances)
    d = len(tolerances.active().items)
    if d == 0:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(nominal)
    # the peak when a row fails (the design is then kept for S1_given): per row its D inputs,
    # two outputs, the output analysed and five columns more (the words counted before the
    # bootstraps), 8 bytes each; r (4 bytes per base sample and resample) and a block's arrays
    # shared out over the rows; the run's machinery beside them (check_memory's reserve)
    rows = int(n) * rows_per_sample(d, second_order)
    boot = 4 * int(resamples) * int(n) + BOOTSTRAP_ARRAYS * 8 * BOOTSTRAP_CELLS
    check_memory(rows, d + 2, value=n, rows_per_unit=rows_per_sample(d, second_order),
                 power_of_two=True, bytes_per_row=8 * (d + 8) + -(-boot // rows))


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


def _check_bootstrap(resamples, conf_level) -> None:
    if isinstance(resamples, bool) or int(resamples) != resamples or resamples < 2:
        raise ParameterError("resamples", "must be a whole number >= 2", resamples)
    if not (0 < conf_level < 1):
        raise ParameterError("conf_level", "must be in (0, 1)", conf_level)


def _column_blocks(resamples: int, n: int) -> list[slice]:
    """Blocks of about BOOTSTRAP_CELLS // n resample columns, each of >= 2 columns: numpy sums
    the (n, k) arrays of SALib's estimators down axis 0 row after row as it sums SALib's
    (n, resamples) ones, while one column would be summed pairwise (other bits)."""
    k = max(2, BOOTSTRAP_CELLS // max(int(n), 1))
    starts = list(range(0, resamples, k))
    if resamples - starts[-1] < 2:  # a last block of one column joins the one before it
        starts.pop()
    return [slice(a, b) for a, b in zip(starts, [*starts[1:], resamples], strict=True)]


def _analyze(problem: dict, y: np.ndarray, seed: int, resamples: int, conf_level: float,
             second_order: bool):
    """SALib's sobol.analyze, bit for bit, in bounded memory: its point estimators, its
    resamples r (drawn whole by its call), and its bootstrap intervals evaluated over blocks
    of r's columns (SALib's estimators on (N, resamples) arrays held ten 0.2-0.4 GB
    temporaries at N = 2**17)."""
    _check_bootstrap(resamples, conf_level)
    d, resamples = problem["num_vars"], int(resamples)
    n = y.size // rows_per_sample(d, second_order)
    # SALib's (y - mean) / std, the division in place: one array of the rows, not three
    mean, std = y.mean(), y.std()
    y = y - mean
    y /= std
    a, b, ab, ba = sobol_analyze.separate_output_values(y, d, n, second_order)
    # SALib's r by its call, held as int32: the same numbers (numpy draws any integers below
    # 2**32 by one 32-bit path; tested) in half the memory, 0.1 GB at N = 2**17
    r = np.random.default_rng(_salib_seed(seed)).integers(n, size=(n, resamples), dtype=np.int32)
    pairs = [(j, k) for j in range(d) for k in range(j + 1, d)] if second_order else []
    s1_all, st_all = np.empty((d, resamples)), np.empty((d, resamples))
    s2_all = np.empty((len(pairs), resamples))
    high, low = -np.inf, np.inf
    with warnings.catch_warnings():  # a block of equal values: SALib's warning, once below
        warnings.simplefilter("ignore", UserWarning)
        for blk in _column_blocks(resamples, n):
            rb = r[:, blk]
            ar, br = a[rb], b[rb]
            high, low = np.max([high, ar.max(), br.max()]), np.min([low, ar.min(), br.min()])
            for j in range(d):
                s1_all[j, blk] = sobol_analyze.first_order(ar, ab[rb, j], br)
                st_all[j, blk] = sobol_analyze.total_order(ar, ab[rb, j], br)
            for i, (j, k) in enumerate(pairs):
                s2_all[i, blk] = sobol_analyze.second_order(ar, ab[rb, j], ab[rb, k], ba[rb, j],
                                                            br)
    if high - low <= np.finfo(float).eps:
        warnings.warn(sobol_analyze.CONST_RESULT_MSG, stacklevel=2)
    z = stats.norm.ppf(0.5 + conf_level / 2)
    # SALib's var_diff: the spread of the resampled outputs (0: every interval is 0)
    spread = (high - low) != 0.0
    s1, st = np.zeros(d), np.zeros(d)
    for j in range(d):
        s1[j] = sobol_analyze.first_order(a, ab[:, j], b)
        st[j] = sobol_analyze.total_order(a, ab[:, j], b)
    s2, s2_conf = np.full((d, d), np.nan), np.full((d, d), np.nan)
    for i, (j, k) in enumerate(pairs):
        s2[j, k] = sobol_analyze.second_order(a, ab[:, j], ab[:, k], ba[:, j], b)
        s2_conf[j, k] = z * s2_all[i].std(ddof=1)
    first = pd.DataFrame({
        "param": problem["names"],
        "S1": s1, "S1_conf": z * s1_all.std(axis=1, ddof=1) if spread else np.zeros(d),
        "ST": st, "ST_conf": z * st_all.std(axis=1, ddof=1) if spread else np.zeros(d)})
    return first, _pairs(problem["names"], s2, s2_conf) if second_order else None


def _pairs(names, s2, s2_conf) -> pd.DataFrame:
    """S2 and its interval of every pair i < j of the inputs."""
    return pd.DataFrame([{"param_i": names[i], "param_j": names[j], "S2": s2[i, j],
                          "S2_conf": s2_conf[i, j]}
                         for i in range(len(names)) for j in range(i + 1, len(names))],
                        columns=["param_i", "param_j", "S2", "S2_conf"])


@dataclass(frozen=True)
class SobolResult:
    """Sobol indices per case at n and n/2 base samples, and their convergence.

    ``to_dataframe()`` has the indices at n: ``param``, ``S1``, ``S1_conf``, ``ST``,
    ``ST_conf`` (first-order and total indices with the half-widths of their bootstrap
    intervals) and ``case``; ``convergence`` the largest change of S1 and ST between n/2 and n;
    ``failed`` the machines per case that could not run.
    """

    indices: pd.DataFrame  # param, S1, S1_conf, ST, ST_conf[, S1_given, S1_given_conf], case, n
    convergence: pd.DataFrame  # case, max |dS1|, max |dST| between n/2 and n
    n: int
    seed: int
    failed: dict  # case -> rows of the design that were not built (POLICY)
    tolerances: str
    # second_order=True: S2 of every pair (param_i, param_j, S2, S2_conf, case) at n
    second_order: pd.DataFrame | None = None
    model_runs: int = 0  # model evaluations per case (N (D + 2) or N (2D + 2))
    # POLICY: what became of each row, per case (the rows of a case add up to its design)
    outcomes: pd.DataFrame | None = None  # case, outcome, group, rows
    # param, S1, S1_conf, ST, ST_conf, case of "assembles", for the cases where a row failed
    feasibility: pd.DataFrame | None = None
    complete: dict | None = None  # case -> base samples (of n) whose every row assembled

    @property
    def has_failures(self) -> bool:
        """True when some row of some case was not built (the JSON and CSVs then say so)."""
        return any(self.failed.values())

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
        given = [c for c in ("S1_given", "S1_given_conf") if c in self.indices]
        return self.to_dataframe()[["param", "S1", "S1_conf", "ST", "ST_conf", *given,
                                    "case"]].to_dict(orient="records")

    def counts(self) -> dict[str, dict]:
        """Per case: rows, assembled, cannot_close, dead_point (and any other failure), the
        failures per group ("cannot_close at G") and the complete base samples; rows =
        assembled + every failure."""
        out = {}
        for case, f in self.outcomes.groupby("case", sort=False):
            by = f.groupby("outcome", sort=False)["rows"].sum()
            out[case] = {"rows": int(f["rows"].sum()), "assembled": int(by.get("assembled", 0)),
                         "cannot_close": int(by.get("cannot_close", 0)),
                         "dead_point": int(by.get("dead_point", 0)),
                         **{k: int(v) for k, v in by.items()
                            if k not in ("assembled", "cannot_close", "dead_point")},
                         "failed_groups": {f"{r.outcome} at {r.group}": int(r.rows)
                                           for r in f.itertuples() if r.group},
                         "base_samples": self.n, "complete_base_samples": self.complete[case]}
        return out

    def assembly(self) -> dict | None:
        """The JSON of machines that could not be built (None when every row assembled): the
        policy, the counts per case and the indices of the indicator "assembles"."""
        if not self.has_failures:
            return None
        return {"policy": POLICY, "counts": self.counts(),
                "feasibility": [] if self.feasibility is None
                else self.feasibility.to_dict(orient="records")}

    def notes(self) -> list[str]:
        """One line per case with rows that were not built (none without failures)."""
        out = []
        for case, c in self.counts().items():
            if c["rows"] > c["assembled"]:
                why = ", ".join(f"{k} {v}" for k, v in c.items() if k not in (
                    "rows", "assembled", "failed_groups", "base_samples",
                    "complete_base_samples") and v)
                out.append(f"{case}: {c['rows'] - c['assembled']} of {c['rows']} machines not "
                           f"built ({why}); S1/ST from the {c['complete_base_samples']} of "
                           f"{self.n} base samples whose every machine assembled, S1_given "
                           "from every assembled one (studies.sobol.POLICY)")
        return out

    def frames(self) -> dict[str, pd.DataFrame]:
        """The CSV tables of a study folder: indices, convergence, and (when present)
        second_order, outcomes and feasibility."""
        out = {"indices": self.to_dataframe(), "convergence": self.convergence}
        if self.second_order is not None:
            out["second_order"] = self.second_order_frame()
        if self.has_failures:
            out["outcomes"] = self.outcomes
            if self.feasibility is not None:
                out["feasibility"] = self.feasibility
        return out


@dataclass(frozen=True)
class CaseIndices:
    """One output's Sobol indices under POLICY (`case_indices`); `result_of` joins cases."""

    case: str
    indices: pd.DataFrame  # at n/2 and n (column n)
    convergence: pd.DataFrame
    pairs: pd.DataFrame | None
    outcomes: pd.DataFrame  # case, outcome, group, rows
    feasibility: pd.DataFrame | None  # indices of "assembles"; None if no row or every row did
    complete: int  # base samples whose every row assembled
    failed: int  # rows not assembled


def outcomes_of(y, status=None, group=None) -> tuple[np.ndarray, np.ndarray]:
    """(outcome, group) per row: "assembled" where y has a value, else the row's status when
    it is not "ok" (cannot_close, dead_point, ...: why the machine did not run in this case or
    another on the design), "undefined" for a row that runs without a value, and "no_value"
    when no status is known; group "" where unknown."""
    y = np.asarray(y, float)
    finite = np.isfinite(y)
    if status is None:
        outcome = words_of(["no_value"], np.zeros(y.shape, np.uint8))
    else:
        outcome = np.asarray(status, object).copy()
        outcome[outcome == "ok"] = "undefined"
    outcome[finite] = "assembled"
    grp = np.full(y.shape, "", object) if group is None else np.asarray(group, object).copy()
    grp[outcome == "assembled"] = ""
    return outcome, grp


def _given_s1(X, y, usable, step, seed, resamples, conf_level) -> tuple[np.ndarray, np.ndarray]:
    """First-order index of y among the usable rows (the correlation ratio of
    montecarlo.contributors over quantile bins of ROWS_PER_BIN rows, equal inputs in one bin),
    with a bootstrap over base samples (the rows of one base sample share inputs, so they are
    resampled together)."""
    from sewtol.studies.montecarlo import correlation_ratio

    if usable.sum() < MIN_GIVEN_ROWS:
        return np.full(X.shape[1], np.nan), np.full(X.shape[1], np.nan)
    yy = y[usable]
    blocks = y.size // step
    block = (np.arange(y.size) // step)[usable]
    z = stats.norm.ppf(0.5 + conf_level / 2)
    s1, conf = [], []
    for j in range(X.shape[1]):
        x = X[usable, j]
        bins = int(np.clip(x.size // ROWS_PER_BIN, 10, MAX_BINS))
        _, b = np.unique(np.searchsorted(np.sort(x), x) * bins // max(x.size, 1),
                         return_inverse=True)
        k = int(b.max(initial=0)) + 1
        s1.append(correlation_ratio(b, yy, k))
        # each resample drawn and weighted when used, the draws made again for each input: the
        # rows of one draw of (resamples, blocks) (tested), which held 8 bytes x blocks x
        # resamples (0.2 GB at N = 2**17), the weights 8 bytes x rows x resamples
        rng = np.random.default_rng(seed)
        conf.append(z * np.std([correlation_ratio(b, yy, k, np.bincount(
            rng.integers(blocks, size=blocks), minlength=blocks)[block])
            for _ in range(int(resamples))], ddof=1))
    return np.array(s1), np.array(conf)


def _undefined(problem: dict, second_order: bool):
    """The frames of `_analyze` with every index NaN (too few complete base samples)."""
    names = problem["names"]
    first = pd.DataFrame({"param": names, **dict.fromkeys(("S1", "S1_conf", "ST", "ST_conf"),
                                                           np.nan)})
    nan = np.full((len(names), len(names)), np.nan)
    return first, _pairs(names, nan, nan) if second_order else None


def case_indices(problem: dict, X: np.ndarray, y: np.ndarray, n: int, seed: int,
                 case: str = "y", resamples: int = 200, conf_level: float = 0.95,
                 second_order: bool = False, status=None, group=None) -> CaseIndices:
    """Sobol indices of one output on the Saltelli design X (`sample`) under POLICY.

    Parameters
    ----------
    problem : dict
        SALib's problem of the design.
    X, y : ndarray
        The design (rows, D) and the output per row (NaN where a machine was not built); X is
        read only when some row failed (None serves when none did).
    n : int
        Base samples of the design; the indices are given at n/2 and n.
    seed : int
        Seeds the bootstraps.
    case : str
        The label of the rows.
    resamples, conf_level
        The bootstrap intervals.
    second_order : bool
        The design holds the second-order rows (S2 per pair).
    status, group : array or None
        Per row: "ok" or why the machine was not built (cannot_close, dead_point, ...) and
        the group that failed ("" unknown); None: a non-finite y is "no_value". Released
        once counted: a caller that passes them inline holds them no longer.

    Returns
    -------
    CaseIndices
        The output's S1/ST (S2) on the complete base samples, S1_given among all assembled
        rows (only when some row failed), the outcomes, the indices of "assembles".
    """
    _check_bootstrap(resamples, conf_level)
    y = np.asarray(y, float)
    step = rows_per_sample(problem["num_vars"], second_order)
    outcome, grp = outcomes_of(y, status, group)
    usable = outcome == "assembled"
    failed = int(np.sum(~usable))
    complete = usable.reshape(-1, step).all(axis=1)
    keys = sorted(set(zip(outcome, grp, strict=True)), key=lambda k: (k[0] != "assembled", k))
    outcomes = pd.DataFrame([{"case": case, "outcome": o, "group": g,
                              "rows": int(np.sum((outcome == o) & (grp == g)))} for o, g in keys])
    del outcome, grp, status, group  # counted: no column of words during the bootstraps
    frames, pairs = [], []
    for m in (n // 2, n):  # the first m blocks of rows are the design of m base samples
        part = y[: m * step]
        if not complete[:m].all():
            part = part[np.repeat(complete[:m], step)]
        f, p = _analyze(problem, part, seed, resamples, conf_level, second_order) \
            if complete[:m].sum() >= MIN_COMPLETE else _undefined(problem, second_order)
        if failed:
            s1, conf = _given_s1(X[: m * step], y[: m * step], usable[: m * step], step, seed,
                                 resamples, conf_level)
            f["S1_given"], f["S1_given_conf"] = s1, conf
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
    feasibility = None
    if 0 < failed < y.size:
        feasibility = _analyze(problem, usable.astype(float), seed, resamples, conf_level,
                               second_order)[0]
        feasibility["case"] = case
    return CaseIndices(case, both, pd.DataFrame([conv]), pairs[1] if second_order else None,
                       outcomes, feasibility, int(complete.sum()), failed)


def result_of(cases: list[CaseIndices], n: int, seed: int, tolerances: str,
              second_order: bool = False, model_runs: int = 0) -> SobolResult:
    """One SobolResult of the cases (its JSON and CSVs name the outcomes and feasibility only
    when some row of some case was not built, so a study without failures writes what it
    always wrote)."""
    feas = [c.feasibility for c in cases if c.feasibility is not None]
    return SobolResult(
        pd.concat([c.indices for c in cases], ignore_index=True),
        pd.concat([c.convergence for c in cases], ignore_index=True), int(n), int(seed),
        {c.case: c.failed for c in cases}, tolerances,
        pd.concat([c.pairs for c in cases], ignore_index=True) if second_order else None,
        int(model_runs),
        pd.concat([c.outcomes for c in cases], ignore_index=True),
        pd.concat(feas, ignore_index=True) if feas else None,
        {c.case: c.complete for c in cases})


def case_values(mech, output: str, cases: Mapping, names: list, X: np.ndarray,
                fast: bool = True, options: Mapping | None = None) -> tuple[np.ndarray, ...]:
    """`output` of the machines of design rows X (deviations of `names`), one array per case:
    as evaluated (compensators None) or adjusted over the case's compensators (NaN where a
    machine does not run). One chunk of `sobol`."""
    values = machines(mech, {k: X[:, i] for i, k in enumerate(names)})
    return tuple(evaluated(mech, values, output, fast=fast) if comps is None
                 else adjusted(mech, values, comps, output, fast=fast, **(options or {})).value
                 for comps in cases.values())


def sobol(mech, tolerances: ToleranceSet, output: str, n: int, seed: int, *,
          cases: Mapping | None = None, resamples: int = 200, conf_level: float = 0.95,
          second_order: bool = False, n_jobs: int = 1, progress: bool | Callable = False,
          backend: str | None = None, chunk_size: int = CHUNK, store=None, scheduler=None,
          failures: Callable | None = None, fast: bool = True, **options) -> SobolResult:
    """Sobol indices of one output of a protocol mechanism at n and n/2 base samples.

    Parameters
    ----------
    mech : Mechanism
        Any protocol mechanism (sewtol.protocol); its plug-ins serve where they apply.
    tolerances : ToleranceSet
        The inputs: each active tolerance is one factor with its distribution.
    output : str
        The output studied.
    n, seed : int
        Base samples (a power of 2, >= 16) and the seed of the design and the bootstraps.
    cases : mapping or None
        Case name -> compensators (as `adjusting.adjusted` takes them), None for the output as
        evaluated; default {output: None}. Every case runs on the same design.
    resamples, conf_level, second_order
        As `case_indices`.
    n_jobs, progress, backend, chunk_size, store, scheduler
        How the model runs (sewtol.studies.parallel.run_chunks); the indices do not depend on
        them.
    failures : callable or None
        ``failures(mech, values, output) -> (status, group)`` of the machines (absolute
        values) that give no value in some case: why they do not run, in the mechanism's words
        (POLICY); None: the mechanism's plug-in (fast), else its evaluation.
    fast : bool
        Use the mechanism's plug-ins (False: the generic reference path).
    options
        Go to the strategy adjuster of the mechanism (e.g. the needle's limit_um, plateaus).

    Returns
    -------
    SobolResult
        The indices per case under POLICY (a machine without a value in some case is counted
        with the reason `failures` gives, at the mechanism's nominal compensators).
    """
    mech.output(output)
    cases = {output: None} if cases is None else dict(cases)
    check_sobol(mech.parameter_record(), tolerances, n, seed, second_order, resamples)
    problem = problem_of(tolerances)
    names = problem["names"]
    X = sample(problem, n, seed, second_order)
    bounds = chunk_bounds(len(X), chunk_size)

    def validate(i, part):
        m = bounds[i][1] - bounds[i][0]
        if not (isinstance(part, tuple) and len(part) == len(cases)
                and all(np.shape(p) == (m,) for p in part)):
            return f"does not hold {len(cases)} outputs of {m} samples"
        return None

    runs, why = len(X), None
    ys = [np.empty(runs) for _ in cases]

    def keep(i, part):  # each chunk's outputs written in place as it arrives, never held
        for y, p in zip(ys, part, strict=True):
            y[bounds[i][0]:bounds[i][1]] = p
        return True

    run_chunks(case_values, [(mech, output, cases, names, X[a:b], fast, options)
                             for a, b in bounds],
               n_jobs=n_jobs, progress=progress, desc="Sobol", backend=backend, store=store,
               validate=validate, scheduler=scheduler, keep=keep)
    bad = ~np.logical_and.reduce([np.isfinite(y) for y in ys])
    if bad.any():
        why = failures_of(mech, fast, failures)(
            mech, machines(mech, {k: X[bad, i] for i, k in enumerate(names)}), output)
    else:  # every row ran in every case: only S1_given, where a row failed, reads the design
        X = None

    def column(i):  # status (0) or group (1) per row, made for each case, which releases it
        if why is None:
            return None
        out = words_of([("ok", "")[i]], np.zeros(runs, np.uint8))
        out[bad] = why[i]
        return out

    return result_of([case_indices(problem, X, y, n, seed, case, resamples, conf_level,
                                   second_order, column(0), column(1))
                      for case, y in zip(cases, ys, strict=True)],
                     n, seed, tolerances.name, second_order, runs)
