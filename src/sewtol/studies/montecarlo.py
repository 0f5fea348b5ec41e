"""Monte-Carlo machinery shared by every mechanism: reproducible sampling of machines, checks,
and the contributors to an output's variance.

The one sampler of every study (Monte-Carlo, strategies, ppm by plain Monte-Carlo, allocation):
machine k is row k % CHUNK of the standard uniforms drawn from child k // CHUNK of the seed
(`unit_streams`, `draw_units`), tied by the set's dependence and mapped through each
tolerance's inverse CDF (`InputLaw.of_uniforms`). So one seed and one tolerance set give the
same machines in every study, for any number of workers and any evaluation chunk size, and a
study that scales the set (allocation) keeps every machine's uniforms, hence its rank, for
every scale.
`sample_machines` evaluates any vectorised model on those machines; `draw_deviations` gives the
deviations alone; `record` is the JSON shape every Monte-Carlo shares (docs/studies.md, "One
Monte-Carlo JSON"); `contributors` and `with_remainder` give each
tolerance's eta^2 (correlation ratio) as a share of the output's variance, the rest named as
interaction. `montecarlo` is THE Monte-Carlo of any mechanism (every output, its status, and with
a compensator the adjusted case through sewtol.studies.adjusting); the needle's beta fixed and
adjusted table is sewtol.mechanisms.needle_208.tables.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.law import STREAM, InputLaw, draw_units, stream_window, unit_streams
from sewtol.studies.parallel import chunk_bounds, run_chunks
from sewtol.tolerances import ToleranceSet

# machines per evaluation chunk: the sampler's streams (sewtol.law.STREAM), so a chunk is one stream
CHUNK = STREAM
YIELD_CI_METHOD = "Clopper-Pearson exact binomial interval of ok / n"
QUANTILES_MEAN = ("p50, p95 and p99 of the spec'd output over all n machines, failed machines "
                  "ranked as infinitely bad (numpy method 'higher': always a machine's value)")
# bytes per machine and column of a study table (float64) plus pandas' working copies
BYTES_PER_CELL = 8 * 4
# the protocol's status words for a plug-in's (the needle's adjusters speak with spaces); a
# machine out of spec still runs: the study's spec decides
WORDS = {"cannot assemble": "cannot_close", "dead point": "dead_point", "out of spec": "ok",
         "out_of_spec": "ok"}


def quantiles(values) -> dict[str, float]:
    """p50, p95, p99 of one case's output; NaN (a machine that cannot run) ranks as +inf."""
    x = np.where(np.isnan(np.asarray(values, float)), np.inf, np.asarray(values, float))
    return {f"p{q}": float(np.quantile(x, q / 100, method="higher")) for q in (50, 95, 99)}


def record(*, mechanism: str, n: int, seed: int, tolerances: str, output: str, unit: str,
           spec, counts: dict[str, dict], quantiles: dict[str, dict], extra: dict) -> dict:
    """The JSON of a Monte-Carlo, the same keys whatever the path (docs/studies.md): per case
    (e.g. fixed_beta, adjusted_beta) its counts (ok + out_of_spec + failed = n), yield ok / n
    with its Clopper-Pearson interval and quantiles; `spec` the limits in force (None: every
    machine that runs is ok); `extra` what only this path computes."""
    from scipy import stats

    ci = {}
    for case, k in counts.items():
        c = stats.binomtest(k["ok"], k["n"]).proportion_ci(0.95, method="exact")
        ci[case] = [float(c.low), float(c.high)]
    first = next(iter(counts.values()))
    return {"mechanism": mechanism, "n": int(n), "seed": int(seed), "tolerances": tolerances,
            "output": output, "unit": unit,
            "spec": None if spec is None else spec.to_dict(),
            "cases": list(counts), "failed": first["failed"], "counts": counts,
            "yields": {case: k["ok"] / k["n"] for case, k in counts.items()},
            "yield_ci": {"method": YIELD_CI_METHOD, "level": 0.95, **ci},
            "quantiles": {"definition": QUANTILES_MEAN, **quantiles},
            "extra": extra}


def check_seed(seed) -> int:
    """A seed is a whole number >= 0 (checked before anything is computed)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError("seed", "must be a whole number >= 0", seed)
    return int(seed)


def available_memory_bytes() -> int | None:
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import os

        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(n: int, columns: int, what: str = "n", value=None) -> None:
    """Refuse a study whose result table cannot fit in the memory available now."""
    need = int(n) * int(columns) * BYTES_PER_CELL
    have = available_memory_bytes()
    if have is not None and need > have:
        raise ParameterError(what, f"needs about {need / 2**30:.3g} GiB for {columns} columns of "
                             f"{int(n)} rows, more than the memory available "
                             f"({have / 2**30:.3g} GiB)", n if value is None else value)


def _chunk(model, nominal, law: InputLaw, window, kwargs):
    streams, a, b = window
    dev = law.of_uniforms(draw_units(streams, law.dim, a, b))
    return dev, model(nominal, dev, **kwargs)


def sample_machines(model, nominal, tolerances: ToleranceSet, n: int, seed: int,
                    n_jobs: int = 1, progress=False, backend: str | None = None,
                    chunk_size: int = CHUNK, desc: str = "Monte-Carlo", store=None,
                    scheduler=None, **kwargs) -> pd.DataFrame:
    """Deviations and model outputs of n machines, one row each (generic over mechanisms).

    model(nominal, deviations, **kwargs) returns a dict of output arrays. The machines are the
    module's one draw (`draw_deviations`); chunk_size only splits the evaluation, so any
    n_jobs, chunk size or cluster gives the same rows. progress: True (bar on stderr) or
    progress(done, total) in chunks; scheduler: a Dask scheduler address or
    distributed.Client to run the chunks on (parallel.run_chunks).
    """
    check_sampling(nominal, tolerances, n, seed, chunk_size)
    law = InputLaw.of(tolerances)
    bounds = chunk_bounds(int(n), chunk_size)
    streams = unit_streams(seed, n)

    def validate(i, part):
        """A saved chunk must hold exactly the machines chunk i draws from the seed."""
        try:
            dev, out = part
            m = bounds[i][1] - bounds[i][0]
            if sorted(dev) != sorted(law.params):
                return f"holds deviations of {sorted(dev)}, not {sorted(law.params)}"
            for k, v in list(dev.items()) + list(out.items()):
                if np.shape(v) != (m,):
                    return f"column {k} has shape {np.shape(v)}, not ({m},)"
            again = law.of_uniforms(draw_units(streams, law.dim, *bounds[i]))
            for k, v in again.items():
                if not np.allclose(dev[k], v, rtol=1e-12, atol=0.0):
                    return f"its {k} deviations are not the ones chunk {i} draws from the seed"
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            return f"malformed ({type(exc).__name__}: {exc})"
        return None

    parts = run_chunks(_chunk, [(model, nominal, law, stream_window(streams, a, b), kwargs)
                                for a, b in bounds],
                       n_jobs=n_jobs, progress=progress, desc=desc, backend=backend, store=store,
                       validate=validate, scheduler=scheduler)
    frames = []
    for dev, out in parts:
        f = pd.DataFrame(dict(dev))
        for k, v in out.items():
            f[k] = v
        frames.append(f)
    machines = pd.concat(frames, ignore_index=True)
    machines.insert(0, "machine", np.arange(len(machines)))
    return machines


def draw_deviations(tolerances: ToleranceSet, n: int, seed: int) -> dict[str, np.ndarray]:
    """The deviations of machines 0 .. n-1 of the tolerances that scatter: the one draw of
    every study (`sample_machines`, strategies, ppm by plain Monte-Carlo, allocation)."""
    return InputLaw.of(tolerances).draw(n, seed)


def check_sampling(nominal, tolerances: ToleranceSet, n, seed, chunk_size: int = CHUNK,
                   columns: int | None = None) -> None:
    """Every input of a Monte-Carlo that can be checked before it runs (nothing is written)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer, float)) or int(n) != n or n < 2:
        raise ParameterError("n", "must be a whole number >= 2", n)
    check_seed(seed)
    if isinstance(chunk_size, bool) or int(chunk_size) != chunk_size or chunk_size < 1:
        raise ParameterError("chunk_size", "must be a whole number >= 1", chunk_size)
    tol = tolerances.active()
    if not tol.items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(nominal)
    check_memory(n, columns if columns is not None else 2 * len(tol.items) + 16)


def correlation_ratio(bin_of: np.ndarray, y: np.ndarray, bins: int,
                      weights: np.ndarray | None = None) -> float:
    """eta^2 = Var(E[Y | bin]) / Var(Y) of y grouped by bin_of (0 .. bins-1), bias-corrected
    (epsilon^2: bins of pure noise give about (bins-1)/n) and never below 0; weights: rows
    counted that many times (a bootstrap resample)."""
    w = np.ones(y.size) if weights is None else np.asarray(weights, float)
    total = w.sum()
    mean = np.sum(w * y) / total
    var = np.sum(w * (y - mean) ** 2) / total
    if not var > 0 or total <= bins:
        return 0.0
    counts = np.bincount(bin_of, weights=w, minlength=bins)
    means = np.bincount(bin_of, weights=w * y, minlength=bins) / np.maximum(counts, 1e-300)
    eta2 = float(np.sum(counts * (means - mean) ** 2) / total / var)
    return max(0.0, 1.0 - (1.0 - eta2) * (total - 1) / (total - bins))


def contributors(machines: pd.DataFrame, params, output: str, bins: int = 20) -> pd.DataFrame:
    """Contributors to the scatter of `output`: the correlation ratio eta^2 of each tolerance.

    eta^2_i = Var(E[Y | X_i]) / Var(Y), with E[Y | X_i] from `bins` quantile bins of X_i: a
    given-data estimate of the first-order effect that, unlike a linear regression, sees a
    V-shaped response (SumDelta to a lateral shift). Bias-corrected (epsilon^2), since bins of
    pure noise give eta^2 of about (bins-1)/n.

    variance_pct = 100 eta^2 is each tolerance's share of the whole variance of `output`; their
    sum is the part single tolerances explain, the rest is interactions (and estimation noise):
    `with_remainder` adds both as rows. share_pct (cumulative_pct) rescales eta^2 to the
    explained part only (100 % in all, whatever the interactions): a ranking, not a variance
    share.
    """
    m = machines.dropna(subset=[output])
    y = m[output].to_numpy()
    rows = []
    for p in params:
        x = m[p].to_numpy()
        ranks = np.argsort(np.argsort(x, kind="stable"), kind="stable")
        rows.append({"param": p, "eta2": correlation_ratio(ranks * bins // len(x), y, bins)})
    frame = pd.DataFrame(rows).sort_values("eta2", ascending=False).reset_index(drop=True)
    total = frame["eta2"].sum()
    frame["share_pct"] = 100 * frame["eta2"] / total if total > 0 else 0.0
    frame["cumulative_pct"] = frame["share_pct"].cumsum()
    frame["variance_pct"] = 100 * frame["eta2"]
    frame["cumulative_variance_pct"] = frame["variance_pct"].cumsum()
    return frame[["param", "eta2", "variance_pct", "cumulative_variance_pct", "share_pct",
                  "cumulative_pct"]]


EXPLAINED, REMAINDER = "(sum: explained by single tolerances)", \
    "(remainder: interactions and estimation noise)"


def with_remainder(frame: pd.DataFrame, top: int | None = None) -> pd.DataFrame:
    """A `contributors` table with the explained sum and the interaction remainder as rows.

    Parameters
    ----------
    frame : DataFrame
        The result of `contributors` (every tolerance, largest first).
    top : int or None
        Keep only the first `top` tolerances' rows; the sum still covers every tolerance.

    Returns
    -------
    DataFrame
        The rows, then ``EXPLAINED`` (the sum of every tolerance's first-order share of the
        variance, ``variance_pct``) and ``REMAINDER`` (100 - sum: what no single tolerance
        explains, i.e. interactions and estimation noise; negative when the estimates' noise
        exceeds the interactions).
    """
    explained = float(frame["variance_pct"].sum())
    frame = frame if top is None else frame.head(top)
    rows = pd.DataFrame([{"param": EXPLAINED, "eta2": explained / 100,
                          "variance_pct": explained},
                         {"param": REMAINDER, "eta2": 1 - explained / 100,
                          "variance_pct": 100.0 - explained}])
    return pd.concat([frame, rows], ignore_index=True)
