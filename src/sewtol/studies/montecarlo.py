"""THE Monte-Carlo of any mechanism, and the sampling machinery every study shares.

The one sampler of every study (Monte-Carlo, strategies, ppm by plain Monte-Carlo, allocation):
machine k is row k % CHUNK of the standard uniforms drawn from child k // CHUNK of the seed
(`unit_streams`, `draw_units`), tied by the set's dependence and mapped through each
tolerance's inverse CDF (`InputLaw.of_uniforms`), the candidates that break a relation of the
set left out (`InputLaw.rank_rows`). So one seed and one tolerance set give the
same machines in every study, for any number of workers and any evaluation chunk size, and a
study that scales the set (allocation) keeps every machine's uniforms, hence its rank, for
every scale.
`sample_machines` evaluates any vectorised model on those machines; `draw_deviations` gives the
deviations alone; `contributors` and `with_remainder` give each tolerance's eta^2 (correlation
ratio) as a share of the output's variance, the rest named as interaction.

`montecarlo` is the study: n machines of the one sampler, every output and each machine's status
(ok + out_of_spec + cannot_close + dead_point = n, out_of_spec by the mechanism's [[specs]]
unless limits are given) and, with a compensator, the adjusted case through
sewtol.studies.adjusting.adjusted (the generic optimiser; with fast=True the mechanism's
plug-ins: its kernel for the outputs it gives, its exact adjuster). Its `MonteCarloResult` is the
one result of every Monte-Carlo: one summary row per output, or (summary="cases") one row per
case of the spec'd output with its capability and the compensators' plateaus; a mechanism whose
tables name the columns otherwise passes its column map (`MonteCarloResult.columns`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import STREAM, InputLaw, draw_units, stream_window, unit_streams  # noqa: F401 re-exports draw_units
from sewtol.mechanism.spec import Spec
from sewtol.protocol import NO_PLUGINS, machines, plugins, words_of
from sewtol.studies.parallel import chunk_bounds, run_chunks
from sewtol.tolerances import ToleranceSet

if TYPE_CHECKING:
    import pandas as pd

# machines per evaluation chunk: the sampler's streams (sewtol.law.STREAM), so a chunk is one stream
CHUNK = STREAM
# chunks one call evaluates on the plug-ins alone (`gil_free`): a call's fixed cost (parameter
# columns, feasibility, statuses, the task; about 2 ms) is shared by 4000 machines of ~15 us
TOGETHER = 8
YIELD_CI_METHOD = "Clopper-Pearson exact binomial interval of ok / n"
QUANTILES_MEAN = ("p50, p95 and p99 of the spec'd output over all n machines, failed machines "
                  "ranked as infinitely bad (numpy method 'higher': always a machine's value)")
# bytes per machine and column of a study table (float64) plus pandas' working copies
BYTES_PER_CELL = 8 * 4
# the protocol's status words for a plug-in's (an adjuster may speak with spaces); a
# machine out of spec still runs: the study's spec decides
WORDS = {"cannot assemble": "cannot_close", "dead point": "dead_point", "out of spec": "ok",
         "out_of_spec": "ok"}


def quantiles(values) -> dict[str, float]:
    """p50, p95, p99 of one case's output; NaN (a machine that cannot run) ranks as +inf."""
    x = np.where(np.isnan(np.asarray(values, float)), np.inf, np.asarray(values, float))
    return {f"p{q}": float(np.quantile(x, q / 100, method="higher")) for q in (50, 95, 99)}


# an adjusted optimum whose plateau reaches a bound and is narrower than this (in the
# compensator's unit: deg for an angle) is pinned there
PINNED_PLATEAU = 0.1
CAPABILITY_DEFINITION = {
    "Cpu": "one-sided (limit_{unit} - mean) / (3 sd) of {name} over the machines that run "
           "(failed machines are in counts, not in Cpu)",
    "Cpu_percentile": "(limit_{unit} - p50) / (p99.865 - p50) over the machines that run"}


def check_seed(seed) -> int:
    """A seed is a whole number >= 0 (checked before anything is computed)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError("seed", "must be a whole number >= 0", seed)
    return int(seed)


def _read_int(path: str) -> int | None:
    """The whole number in a one-value file (a cgroup's limit or usage); None if absent,
    unreadable or unlimited ("max")."""
    try:
        with open(path) as fh:
            return int(fh.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def _status_bytes(key: str) -> int | None:
    """A "kB" field of /proc/self/status (VmSize: this process's address space) in bytes."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


# (limit, usage) of the container's memory: cgroup v2, then v1
CGROUP_MEMORY_FILES = (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                       ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                        "/sys/fs/cgroup/memory/memory.usage_in_bytes"))
# a cgroup v1 "no limit" is a page-rounded 2**63 - 1; anything above 2**60 is no limit
_NO_LIMIT = 1 << 60


def memory_limits_bytes() -> dict[str, int]:
    """What this process may still allocate, by source, in bytes (an absent source is left
    out): the machine's available memory (MemAvailable), the address-space limit (`ulimit -v`,
    RLIMIT_AS, less the address space in use) and the container's cgroup limit (v2 memory.max
    or v1 memory.limit_in_bytes, less its usage)."""
    out = {}
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    out["available memory"] = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if "available memory" not in out:
        import os

        try:
            out["available memory"] = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            pass
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError):
        soft = None
    if soft is not None and soft != resource.RLIM_INFINITY:
        used = _status_bytes("VmSize") or 0
        out["address-space limit (ulimit -v)"] = max(0, soft - used)
    for limit, usage in CGROUP_MEMORY_FILES:
        cap = _read_int(limit)
        if cap is not None and cap < _NO_LIMIT:
            out["container memory limit (cgroup)"] = max(0, cap - (_read_int(usage) or 0))
            break
    return out


def available_memory_bytes() -> int | None:
    """The least of memory_limits_bytes(), None if none is known."""
    limits = memory_limits_bytes()
    return min(limits.values()) if limits else None


# what a Monte-Carlo's machinery reaches whatever n, beyond its machines (measured: needle
# montecarlo --n 10000, numba and the kernels loaded, the worker threads' stacks and malloc
# arenas): peak address space (VmPeak 777 MB with --n-jobs 1, 1074 MB with 2) and peak resident
# size (245 MB); the part not yet reached when a study is checked is kept free for it
RUN_ADDRESS_SPACE = 1100 * 2**20
RUN_RESIDENT = 250 * 2**20
# what each local worker process adds (needle strategies --n-jobs 2 at n 10^4 and 5*10^4: a
# worker's private memory, RssAnon, peaks at 87 MB; its shared libraries are the parent's pages)
WORKER_RESIDENT = 100 * 2**20


def run_reserve_bytes(source: str, workers: int = 0) -> int:
    """What the machinery of a run still adds to a memory source (`memory_limits_bytes`' name)
    after this point: RUN_ADDRESS_SPACE less the address space in use (a worker process has
    its own), or RUN_RESIDENT less the resident size now, plus WORKER_RESIDENT per worker
    process."""
    if source.startswith("address-space"):
        return max(0, RUN_ADDRESS_SPACE - (_status_bytes("VmSize") or 0))
    return (max(0, RUN_RESIDENT - (_status_bytes("VmRSS") or 0))
            + max(0, int(workers)) * WORKER_RESIDENT)


def largest_that_fits(have_bytes: int, columns: int, rows_per_unit: int = 1,
                      power_of_two: bool = False, bytes_per_row: int | None = None) -> int:
    """The largest n whose n * rows_per_unit rows of `columns` columns (or of bytes_per_row
    bytes each) fit in have_bytes (the estimate of `check_memory`); the largest power of two
    with power_of_two (Sobol)."""
    row = int(columns) * BYTES_PER_CELL if bytes_per_row is None else int(bytes_per_row)
    n = int(have_bytes) // (row * max(1, int(rows_per_unit)))
    if power_of_two and n >= 1:
        n = 1 << (n.bit_length() - 1)
    return n


def check_memory(n: int, columns: int, what: str = "n", value=None, rows_per_unit: int = 1,
                 power_of_two: bool = False, bytes_per_row: int | None = None,
                 workers: int = 0) -> None:
    """Refuse a study whose result table cannot fit in the memory available now, before it
    starts, naming the largest `what` that fits (`value` rows per unit of it: n rows are
    value * rows_per_unit). A study that holds its machines compactly gives their bytes each
    (bytes_per_row, e.g. `montecarlo_bytes`) instead of a table's columns, and the worker
    processes it starts (`parallel.local_workers`)."""
    row = int(columns) * BYTES_PER_CELL if bytes_per_row is None else int(bytes_per_row)
    need = int(n) * row
    limits = memory_limits_bytes()
    if not limits:
        return
    if bytes_per_row is not None:  # a compact study: its machinery counts beside the machines
        limits = {k: max(0, v - run_reserve_bytes(k, workers)) for k, v in limits.items()}
    source = min(limits, key=limits.get)
    have = limits[source]
    if need > have:
        fits = largest_that_fits(have, columns, rows_per_unit, power_of_two, bytes_per_row)
        held = (f"{columns} columns of {int(n)} rows" if bytes_per_row is None else
                f"{int(n)} machines of {int(bytes_per_row)} bytes each")
        raise ParameterError(what, f"needs about {need / 2**30:.3g} GiB for {held}, "
                             "more than the memory this process may still use "
                             f"({have / 2**30:.3g} GiB, {source}): at most {what} = {fits} "
                             "fits", n if value is None else value)


def _chunk(model, nominal, law: InputLaw, window, kwargs):
    streams, a, b = window
    dev = law.window(streams, a, b)
    return dev, model(nominal, dev, **kwargs)


def _chunks(model, nominal, law: InputLaw, window, kwargs, sizes):
    """Consecutive chunks of `sizes` machines drawn and evaluated as one window (one call of
    the model), each chunk's (deviations, outputs) as `_chunk` gives it: a model's every value
    is its machine's own, so the same numbers."""
    dev, out = _chunk(model, nominal, law, window, kwargs)
    parts, a = [], 0
    for m in sizes:
        parts.append(tuple({k: v[a:a + m] for k, v in d.items()} for d in (dev, out)))
        a += m
    return parts


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
    parts, _ = _sampled(model, nominal, tolerances, n, seed, n_jobs, progress, backend,
                        chunk_size, desc, store, scheduler, None, kwargs)
    return _joined(parts)


@dataclass(frozen=True)
class Draw:
    """The machines of one seed and tolerance set, chunk by chunk (the deviations are drawn
    again from these whenever a table asks for them, never held by a study)."""

    law: InputLaw
    streams: tuple
    bounds: tuple[tuple[int, int], ...]

    def deviations(self) -> dict[str, np.ndarray]:
        """Every machine's deviations, each chunk drawn as its chunk drew it."""
        parts = [self.law.window(list(self.streams), a, b) for a, b in self.bounds]
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _sampled(model, nominal, tolerances, n, seed, n_jobs, progress, backend, chunk_size, desc,
             store, scheduler, keep, kwargs, bytes_per_row=None,
             together: int = 1) -> tuple[list, Draw]:
    """The chunks of `sample_machines` (each reduced by keep(i, (deviations, outputs)) as it
    arrives) and the draw they came from; bytes_per_row: what the study holds per machine
    (default: `sample_machines`' table); together: chunks evaluated in one call of the model
    (`run_chunks`)."""
    check_sampling(nominal, tolerances, n, seed, chunk_size, bytes_per_row=bytes_per_row)
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
            again = law.window(streams, *bounds[i])
            for k, v in again.items():
                if not np.allclose(dev[k], v, rtol=1e-12, atol=0.0):
                    return f"its {k} deviations are not the ones chunk {i} draws from the seed"
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            return f"malformed ({type(exc).__name__}: {exc})"
        return None

    def join(run):
        a, b = bounds[run[0]][0], bounds[run[-1]][1]
        return _chunks, (model, nominal, law, stream_window(streams, a, b), kwargs,
                         [bounds[i][1] - bounds[i][0] for i in run])

    parts = run_chunks(_chunk, [(model, nominal, law, stream_window(streams, a, b), kwargs)
                                for a, b in bounds],
                       n_jobs=n_jobs, progress=progress, desc=desc, backend=backend, store=store,
                       validate=validate, scheduler=scheduler, keep=keep, together=together,
                       join=join)
    return parts, Draw(law, tuple(streams), tuple(bounds))


def _joined(parts: list) -> pd.DataFrame:
    """The chunks' (deviations, outputs) as one table (machine, deviations, outputs), joined
    column by column: each chunk's array of a column is dropped as soon as it is copied, so
    the chunks and the table are never held whole at once (one DataFrame per chunk and
    pd.concat held both, and set 10 columns per chunk one by one)."""
    import pandas as pd

    names = list(parts[0][0]) + [k for k in parts[0][1] if k not in parts[0][0]]
    cols = {"machine": np.arange(sum(len(next(iter(d.values()))) for d, _ in parts))}
    for k in names:
        pieces = []
        for dev, out in parts:
            src = dev if k in dev else out
            pieces.append(np.asarray(src.pop(k)))
        cols[k] = np.concatenate(pieces) if len(pieces) > 1 else pieces[0]
        del pieces
    return pd.DataFrame(cols, copy=False)


def _coded(words: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]] | None:
    """A column of words (text, or objects that are all str) as (codes, vocabulary, sorted as
    np.unique sorts them): one byte a machine, not a pointer and an object (a machine's
    status, the group that failed); None for any other column. The distinct words are taken
    once (a set: a third of np.unique's time on strings); a handful of them is coded by one
    comparison each, more through a dict."""
    a = np.asarray(words)
    if a.dtype.kind not in "UO":
        return None
    listed = a.ravel().tolist()
    try:
        distinct = set(listed)
    except TypeError:  # objects that cannot be hashed are no words
        return None
    if a.dtype.kind == "O" and not all(isinstance(x, str) for x in distinct):
        return None
    vocab = sorted(distinct)
    dtype = np.uint8 if len(vocab) <= 256 else np.int32
    if len(vocab) <= 8:
        codes = np.zeros(len(listed), dtype)
        for i, w in enumerate(vocab[1:], 1):
            codes[a.ravel() == w] = i
    else:
        index = {w: i for i, w in enumerate(vocab)}
        codes = np.fromiter(map(index.__getitem__, listed), dtype, len(listed))
    return codes, tuple(vocab)


class _Collector:
    """What `montecarlo` keeps of each chunk as it arrives (run_chunks' keep): its outputs
    written into columns of all n machines, allocated once, words as codes (`_coded`); the
    deviations are dropped (`Draw` draws them again for a table that shows them). So the study
    holds one compact copy of the machines' figures, never the chunks and the table at once."""

    def __init__(self, bounds):
        self.bounds, self.n = bounds, bounds[-1][1]
        self.order: list[str] | None = None
        self.arrays: dict[str, np.ndarray] = {}
        self.words: dict[str, tuple[np.ndarray, list[str], dict[str, int]]] = {}

    def __call__(self, i: int, part) -> None:
        dev, out = part
        a, b = self.bounds[i]
        if self.order is None:
            self.order = [k for k in out if k not in dev]
        for k in self.order:
            v = np.asarray(out[k])
            coded = _coded(v)
            if coded is not None:
                codes, vocab = coded
                into, words, index = self.words.setdefault(
                    k, (np.zeros(self.n, np.uint8), [], {}))
                for w in vocab:
                    if w not in index:
                        index[w] = len(words)
                        words.append(w)
                if len(words) > 256 and into.dtype == np.uint8:
                    into = into.astype(np.int32)
                    self.words[k] = (into, words, index)
                into[a:b] = np.asarray([index[w] for w in vocab], into.dtype)[codes]
            else:
                into = self.arrays.get(k)
                if into is None or np.result_type(into, v) != into.dtype:
                    into = self.arrays[k] = (np.empty(self.n, v.dtype) if into is None
                                             else into.astype(np.result_type(into, v)))
                into[a:b] = v
        return None

    def table(self, order, renamed: Mapping[str, str], draw: Draw, params) -> MachineColumns:
        """The columns in `order` (chunk names, with machine and the deviations), renamed."""
        return MachineColumns(
            self.n, tuple(renamed.get(k, k) for k in order),
            {renamed.get(k, k): v for k, v in self.arrays.items()},
            {renamed.get(k, k): (codes, tuple(words)) for k, (codes, words, _) in
             self.words.items()}, draw, tuple(params))


@dataclass(frozen=True)
class MachineColumns:
    """Every machine's figures of a Monte-Carlo, compact: the outputs as arrays, each column of
    words as one-byte codes into its vocabulary, the deviations drawn again from the seed only
    when a table shows them (`frame`). `names` is the table's column order (machine, the
    deviations, then the outputs, in the mechanism's names); `renamed` maps a column's name
    in the chunks to it."""

    n: int
    names: tuple[str, ...]
    arrays: Mapping[str, np.ndarray]  # numeric columns (table names)
    words: Mapping[str, tuple[np.ndarray, tuple[str, ...]]]  # text columns: (codes, vocabulary)
    draw: Draw | None = None
    params: tuple[str, ...] = ()  # the deviation columns (drawn again by `draw`)

    def __contains__(self, name) -> bool:
        return name in self.arrays or name in self.words or name in self.names

    def codes(self, name: str) -> tuple[np.ndarray, tuple[str, ...]]:
        """A text column as (codes, vocabulary)."""
        return self.words[name]

    def column(self, name: str) -> np.ndarray:
        """One column, a text column as an array of its words (objects)."""
        if name in self.words:
            codes, vocab = self.words[name]
            return np.asarray(vocab, object)[codes]
        if name in self.arrays:
            return self.arrays[name]
        if name == "machine":
            return np.arange(self.n)
        if name in self.params:
            return self.draw.deviations()[name]
        raise KeyError(name)

    def frame(self, columns=None) -> pd.DataFrame:
        """The table (one row per machine) of these columns (default: all, in order)."""
        import pandas as pd

        columns = list(self.names if columns is None else columns)
        dev = self.draw.deviations() if any(c in self.params for c in columns) else {}
        return pd.DataFrame({c: dev[c] if c in dev else self.column(c) for c in columns},
                            copy=False)

    def frames(self):
        """The table chunk by chunk (the rows of each chunk of the draw, every column): what a
        writer streams without holding the whole table (`frame` joined)."""
        import pandas as pd

        for a, b in self.draw.bounds:
            dev = self.draw.law.window(list(self.draw.streams), a, b)
            yield pd.DataFrame({c: dev[c] if c in dev else self.rows(c, a, b)
                                for c in self.names}, copy=False)

    def rows(self, name: str, a: int, b: int) -> np.ndarray:
        """Machines a .. b-1 of a column other than a deviation (`column`)."""
        if name in self.words:
            codes, vocab = self.words[name]
            return np.asarray(vocab, object)[codes[a:b]]
        return np.arange(a, b) if name == "machine" else self.arrays[name][a:b]


def draw_deviations(tolerances: ToleranceSet, n: int, seed: int) -> dict[str, np.ndarray]:
    """The deviations of machines 0 .. n-1 of the tolerances that scatter: the one draw of
    every study (`sample_machines`, strategies, ppm by plain Monte-Carlo, allocation)."""
    return InputLaw.of(tolerances).draw(n, seed)


def check_sampling(nominal, tolerances: ToleranceSet, n, seed, chunk_size: int = CHUNK,
                   columns: int | None = None, bytes_per_row: int | None = None) -> None:
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
    check_memory(n, columns if columns is not None else 2 * len(tol.items) + 16,
                 bytes_per_row=bytes_per_row)


# what `montecarlo` holds per machine (its _Collector): 8 bytes per number (each output, the
# adjusted output, a compensator's setting, plateau ends and at-bound flag, a plug-in's failure
# figures, FAILURE_FIGURES at most per case: the needle's angle, gap, transmission angle), 1
# per column of words (status, failed group per case), and the summary's working copies of
# one output (failures ranked as +inf, the quantiles' partition, the spec's test)
FAILURE_FIGURES = 3
SUMMARY_WORKING_BYTES = 3 * 8


def montecarlo_bytes(outputs: int, compensators: int = 0) -> int:
    """Bytes `montecarlo` holds per machine of `outputs` outputs and, with compensators, the
    adjusted case (measured: 113 bytes a machine beyond the start-up at 10^6 needle machines,
    against 124 estimated)."""
    cases = 2 if compensators else 1
    numbers = outputs + (1 if compensators else 0) + 4 * compensators + FAILURE_FIGURES * cases
    return 8 * numbers + 2 * cases + SUMMARY_WORKING_BYTES


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
    import pandas as pd

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
    import pandas as pd

    explained = float(frame["variance_pct"].sum())
    frame = frame if top is None else frame.head(top)
    rows = pd.DataFrame([{"param": EXPLAINED, "eta2": explained / 100,
                          "variance_pct": explained},
                         {"param": REMAINDER, "eta2": 1 - explained / 100,
                          "variance_pct": 100.0 - explained}])
    return pd.concat([frame, rows], ignore_index=True)


def _file_model(record, dev, mech, outputs, compensator=None, target=None, fast=False,
                objective=None):
    """One chunk of `montecarlo`: the outputs of machines nominal + dev as built (the plug-in
    kernel where it gives every output, the status of the machines it cannot run from
    mech.evaluate) and, with a compensator, the adjusted case (target brought to `objective`)."""
    from sewtol.studies.adjusting import adjusted

    values = machines(mech, dev)
    pl = plugins(mech) if fast else NO_PLUGINS
    a = None
    if compensator is not None:
        comps = [compensator] if isinstance(compensator, str) else compensator
        a = adjusted(mech, values, comps, target, fast=fast, figures=False,
                     objective=objective)
    if pl.kernel is not None and set(outputs) <= set(pl.kernel_outputs):
        # the adjuster's as_built: the kernel's outputs from the work they share
        got = a.extras["as_built"] if a is not None and "as_built" in a.extras and \
            set(outputs) <= set(a.extras["as_built"]) else pl.kernel(mech, values)
        out = {o: got[o] for o in outputs}
        m = len(got[outputs[0]])
        status, group = np.full(m, "ok", object), np.full(m, "", object)
        bad = ~np.all([np.isfinite(v) for v in out.values()], axis=0)
        if bad.any():
            ev = mech.evaluate({k: v[bad] for k, v in values.items()}, outputs)
            status[bad], group[bad] = ev.status, ev.failed_group
        out.update({"status": status, "failed_group": group})
    else:
        ev = mech.evaluate(values, outputs)
        out = {**ev.outputs, "status": ev.status, "failed_group": ev.failed_group}
    if a is not None:
        out[f"{target}_adjusted"] = a.value
        for param, setting in a.settings.items():
            out[f"{param}_setting"] = setting
            if a.path != "generic":  # a plug-in's plateau of optimal settings and its bound
                out[f"{param}_low"] = a.extras["low"][param]
                out[f"{param}_high"] = a.extras["high"][param]
                out[f"{param}_at_bound"] = np.asarray(a.at_bound[param], float)
        which, words = _coded(np.asarray(a.status, object)) or _coded(np.asarray(a.status, str))
        out["status_adjusted"] = words_of([WORDS.get(w, w) for w in words] or [""], which)
        out["failed_group_adjusted"] = a.extras.get("failed_group", np.full(len(a.value), ""))
    return out


def failure_blank(mech, failure_table, deviations) -> dict:
    """The failure table's columns and their types, as the plug-in gives them for the first of
    these machines (what `named_failures` takes from machine 0 when none fails)."""
    one = {k: np.asarray(v, float)[:1] for k, v in deviations.items()}
    return {k: np.asarray(v).dtype for k, v in failure_table(mech, machines(mech, one)).items()}


def _montecarlo_chunk(record, dev, mech, outputs, compensator=None, target=None, fast=False,
                      spec=None, blank=None, objective=None):
    """One chunk of `montecarlo`: `_file_model`, and on the fast path each failure named by the
    plug-in (`failure_columns`), chunk by chunk (the study never holds all n machines' values);
    blank: `failure_blank` of the run's first machine."""
    out = _file_model(record, dev, mech, outputs, compensator, target, fast, objective)
    pl = plugins(mech) if fast else NO_PLUGINS
    if pl.failure_table is not None:
        out.update(failure_columns(mech, pl.failure_table, dev, {**dev, **out}, target, spec,
                                   compensator, blank))
    return out


@dataclass(frozen=True)
class MonteCarloResult:
    """The machines of a Monte-Carlo and what they give (see `montecarlo`).

    Cases: ``fixed`` (every machine as drawn, compensators at their nominal), and with a
    compensator C ``fixed_C`` and ``adjusted_C`` (C set per machine); ``counts``, ``yield_of``,
    ``yield_ci``, ``quantiles``, ``capability`` and ``pareto`` take a case (its full name or
    ``"fixed"``/``"adjusted"``) or an output. ``summary_frame()`` has one row per output, or with
    summary="cases" one row per case of the spec'd output: counts (``ok + out_of_spec + failed =
    n``), the yield with its Clopper-Pearson interval, quantiles, capability and the machines
    whose optimum reaches a bound of the compensator's range. ``machines`` has every machine's
    deviations, outputs and status; `columns` maps the generic column names (OUTPUT,
    OUTPUT_adjusted, PARAM_setting, PARAM_low, PARAM_high, PARAM_at_bound, status,
    status_adjusted, and the JSON key PARAM_picks) to the mechanism's where its table names them
    otherwise; `extra` is what the mechanism adds to the JSON's extra (summary="cases").
    """

    mechanism: str
    table: MachineColumns  # machine, deviations, outputs, status, failed_group (compact)
    outputs: tuple[str, ...]
    tolerances: str
    seed: int
    limit_output: str  # the spec'd output of the JSON's cases (its spec may be None)
    specs: tuple[Spec, ...] = ()  # the limits in force, at most one per output
    spec_source: str | None = None  # of limit_output's spec: "file", "command line" or None
    adjust: str | None = None  # the compensator of the adjusted case (column NAME_adjusted)
    unit: str = ""  # limit_output's unit
    params: tuple[str, ...] = ()  # the tolerances that scatter (deviation columns)
    summary: str = "outputs"  # summary_frame and JSON: one row per "outputs" or per "cases"
    columns: Mapping[str, str] = field(default_factory=dict)
    extra: Mapping = field(default_factory=dict)
    # with relations (sewtol.relations): the candidates drawn for the n machines built (the
    # others broke a relation and were rejected at inspection); None: the set has none
    candidates: int | None = None
    held: Mapping[str, float] = field(default_factory=dict)  # the fixed case's nominal values

    @property
    def n(self) -> int:
        """The number of machines drawn."""
        return self.table.n

    @cached_property
    def machines(self) -> pd.DataFrame:
        """One row per machine: its deviations, outputs, status and the group that failed
        (built from `table` when first asked for; the summaries never need it)."""
        return self.table.frame()

    def inspection(self) -> dict | None:
        """With relations: candidates drawn, machines built (n) and rejected, and the
        relations' pass rate n / candidates; None without relations."""
        if self.candidates is None:
            return None
        return {"candidates": self.candidates, "built": self.n,
                "rejected": self.candidates - self.n, "acceptance": self.n / self.candidates}

    @property
    def failed(self) -> int:
        """Machines that cannot run in the fixed case (see `counts`)."""
        return self.counts(next(iter(self.cases())))["failed"]

    @property
    def adjusted_output(self) -> str | None:
        return None if self.adjust is None else f"{self.limit_output}_adjusted"

    def column(self, name: str) -> str:
        """The machines' column (or JSON key) of a generic name, by the mechanism's `columns`."""
        return self.columns.get(name, name)

    def values(self, name: str) -> np.ndarray:
        """The machines' column of a generic name (`column`), text as an array of words."""
        return self.table.column(self.column(name))

    def spec(self, output: str | None = None) -> Spec | None:
        """The limits in force for an output (its adjusted case keeps the output's limits)."""
        if output is None or output == self.adjusted_output:
            output = self.limit_output
        return next((s for s in self.specs if s.output == output), None)

    def cases(self) -> dict[str, str]:
        """Case name -> output: "fixed" (every machine as drawn), or with a compensator C the
        cases "fixed_C" (C at its nominal) and "adjusted_C" (C set per machine)."""
        if self.adjust is None:
            return {"fixed": self.limit_output}
        return {f"fixed_{self.adjust}": self.limit_output,
                f"adjusted_{self.adjust}": self.adjusted_output}

    def case_of(self, case: str) -> str:
        """The full name of a case; "fixed" and "adjusted" name the cases with a compensator."""
        names = list(self.cases())
        for name in names:
            if case in (name, name.split("_", 1)[0]):
                return name
        words = list(dict.fromkeys([k.split("_", 1)[0] for k in names] + names))
        raise ParameterError("case", f"must be {', '.join(words[:-1])} or {words[-1]}"
                             if len(words) > 1 else f"must be {words[0]}", case)

    def output_of(self, key: str | None) -> str | None:
        """An output studied, or the output of a case (`case_of`)."""
        return key if key is None or key in self.outputs else self.cases()[self.case_of(key)]

    def status(self, output: str | None = None) -> np.ndarray:
        """Per machine: ok, out_of_spec (outside the output's spec; no value fails a spec),
        cannot_close, dead_point (the adjusted case: at the machine's chosen setting), or
        unexplained (a mechanism's status that finds no reason)."""
        codes, words = self._status_codes(output)
        return np.asarray(words, object)[codes]

    def _status_codes(self, output: str | None) -> tuple[np.ndarray, tuple[str, ...]]:
        """`status` as codes into its words (one byte a machine)."""
        output = self.output_of(output)
        adjusted = output is not None and output == self.adjusted_output
        codes, words = self.table.codes(self.column("status_adjusted" if adjusted
                                                    else "status"))
        spec = self.spec(output) if output is not None else None
        if spec is not None and "ok" in words:
            if "out_of_spec" not in words:
                words = (*words, "out_of_spec")
            fails = (codes == words.index("ok")) & ~spec.passes(
                np.asarray(self.values(output), float))
            codes = np.where(fails, np.asarray(words.index("out_of_spec"), codes.dtype), codes)
        return codes, words

    def counts(self, output: str | None = None) -> dict[str, int]:
        """ok + out_of_spec + failed = n, failed = cannot_close + dead_point + unexplained, of
        an output or a case."""
        codes, words = self._status_codes(output)
        count = dict(zip(words, np.bincount(codes, minlength=len(words)).tolist(), strict=True))
        c = {k: int(count.get(k, 0)) for k in ("ok", "out_of_spec", "cannot_close",
                                                "dead_point", "unexplained")}
        c["failed"] = c["cannot_close"] + c["dead_point"] + c["unexplained"]
        c["n"] = int(codes.size)
        return c

    def yield_of(self, case: str) -> float:
        """The share of machines that pass (ok) in a case or for an output."""
        return self.counts(case)["ok"] / self.n

    def yield_ci(self, case: str = "adjusted", level: float = 0.95) -> tuple[float, float]:
        """Clopper-Pearson interval of the yield."""
        return clopper_pearson(self.counts(case)["ok"], self.n, level)

    def quantiles(self, case: str) -> dict:
        """p50, p95 and p99 of a case's output; failed machines rank as infinitely bad, so they
        are not hidden by the quantiles (`quantiles`)."""
        return quantiles(self.values(self.output_of(case)))

    def capability(self, case: str) -> dict:
        """Cpu = (USL - mean) / 3 sigma, and the percentile form (USL - p50) / (p99.865 - p50),
        of the spec's upper limit (USL) over the machines that run."""
        output = self.output_of(case)
        x = np.asarray(self.values(output), float)
        x = x[~np.isnan(x)]
        if x.size < 2:  # (almost) every machine failed: no scatter to speak of
            return {"Cpu": float("nan"), "Cpu_percentile": float("nan")}
        limit = self.spec(output).upper
        mean, sd = float(np.mean(x)), float(np.std(x, ddof=1))
        p50, p99865 = np.quantile(x, [0.5, 0.99865])
        return {"Cpu": (limit - mean) / (3 * sd) if sd > 0 else float("inf"),
                "Cpu_percentile": float((limit - p50) / (p99865 - p50))
                if p99865 > p50 else float("inf")}

    def pareto(self, case: str = "adjusted", bins: int = 20) -> pd.DataFrame:
        """Contributors to a case's scatter (`contributors`), with the explained sum and the
        interaction remainder as the last two rows (`with_remainder`)."""
        column = self.column(self.output_of(case))
        return with_remainder(contributors(self.table.frame([*self.params, column]),
                                           self.params, column, bins))

    def compensators(self) -> list[str]:
        return [] if self.adjust is None else [c.strip() for c in self.adjust.split(",")]

    def setting_range(self, param: str) -> tuple[float, float]:
        """The smallest and largest per-machine setting of a compensator among machines that run."""
        b = np.asarray(self.values(f"{param}_setting"), float)
        b = b[~np.isnan(b)]
        return (float(b.min()), float(b.max())) if len(b) else (float("nan"), float("nan"))

    def at_bound(self, param: str, pinned: bool = False) -> int:
        """Machines whose adjusted optimum's plateau (the output within the plug-in's tolerance
        of its minimum) reaches a bound of the searched range; pinned=True: only those whose
        plateau is narrower than PINNED_PLATEAU, where the output still falls at the bound and
        the optimum likely lies outside the range (a wide plateau is flat: the setting hardly
        matters there). 0 without the plug-in's plateau columns."""
        if self.column(f"{param}_at_bound") not in self.table:
            return 0
        at = np.asarray(self.values(f"{param}_at_bound"), float) == 1.0
        if pinned:
            at &= (self.values(f"{param}_high") - self.values(f"{param}_low")) < PINNED_PLATEAU
        return int(at.sum())

    def failed_groups(self, adjusted: bool = False) -> dict[str, int]:
        codes, words = self.table.codes(self.column("failed_group_adjusted" if adjusted
                                                    else "failed_group"))
        count = np.bincount(codes, minlength=len(words))
        return {w: int(count[j]) for j, w in sorted(enumerate(words), key=lambda x: x[1])
                if w != "" and count[j] > 0}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per machine: deviations, outputs, status and the group that failed."""
        return self.machines.copy()

    def summary_frame(self) -> pd.DataFrame:
        """One row per output (or with summary="cases", per case: `case_rows`)."""
        import pandas as pd

        return pd.DataFrame(self.summary_rows())

    def summary_rows(self) -> list[dict]:
        """`summary_frame`'s rows as records (the table a command prints, without pandas)."""
        if self.summary == "cases":
            return self.case_rows()
        rows = []
        for name in self.outputs:
            v = np.asarray(self.table.column(name), float)
            ok = v[~np.isnan(v)]
            c = self.counts(name)
            row = {"output": name, **{k: c[k] for k in ("n", "ok", "out_of_spec",
                                                         "cannot_close", "dead_point")}}
            # machines that run but whose output has no value (e.g. the contact-loss angle of a
            # presser foot that never loses contact): counted here, left out of the statistics
            running = np.isin(self.status(name), ("ok", "out_of_spec"))
            row["undefined"] = int(np.sum(running & np.isnan(v)))
            if ok.size:
                q = np.quantile(ok, [0.5, 0.95, 0.99])
                row.update({"mean": float(ok.mean()),
                            "std": float(ok.std(ddof=1)) if ok.size > 1 else float("nan"),
                            "min": float(ok.min()), "p50": q[0], "p95": q[1], "p99": q[2],
                            "max": float(ok.max())})
            else:
                row.update(dict.fromkeys(("mean", "std", "min", "p50", "p95", "p99", "max"),
                                         float("nan")))
            spec = self.spec(name)
            if spec is not None:
                lo, hi = self.yield_ci(name)
                row.update({"limit": spec.upper, "lower_limit": spec.lower,
                            "yield": c["ok"] / c["n"], "yield_ci_low": lo, "yield_ci_high": hi})
            rows.append(row)
        return rows

    def case_rows(self) -> list[dict]:
        """One row per case of the spec'd output: counts (ok + out_of_spec + failed = n), yield
        and interval, quantiles (p50_UNIT ...), Cpu, and per compensator its machines at a bound
        (`at_bound`; 0 in the fixed case)."""
        rows = []
        suffix = f"_{self.unit}" if self.unit else ""
        for i, case in enumerate(self.cases()):
            q, (lo, hi), cap, k = (self.quantiles(case), self.yield_ci(case),
                                   self.capability(case), self.counts(case))
            rows.append({"case": case, "n": self.n,
                         **{w: k[w] for w in ("ok", "out_of_spec", "failed", "cannot_close",
                                              "dead_point")},
                         "yield": self.yield_of(case), "yield_ci_low": lo, "yield_ci_high": hi,
                         **{f"{p}{suffix}": v for p, v in q.items()}, **cap})
            for param in self.compensators():
                rows[-1][f"{param}_at_bound"] = self.at_bound(param) if i else 0
                rows[-1][f"{param}_pinned_at_bound"] = self.at_bound(param, True) if i else 0
        return rows

    def to_dict(self) -> dict:
        """The Monte-Carlo JSON every path shares (docs/studies.md, "One Monte-Carlo JSON"): per
        case its counts (ok + out_of_spec + failed = n), yield ok / n with its Clopper-Pearson
        interval and quantiles; `spec` the limits in force (None: every machine that runs is
        ok); extra: the compensator, the groups that failed per case and the summary of every
        output, or with summary="cases" the capability of both cases, each compensator's range
        of settings and its machines at a bound, and the mechanism's `extra`."""
        cases = self.cases()
        if self.summary == "cases":
            name = self.limit_output.removesuffix(f"_{self.unit}")
            definition = {k: v.format(unit=self.unit, name=name)
                          for k, v in CAPABILITY_DEFINITION.items()}
            extra = {"capability": {"definition": definition,
                                    **{c: self.capability(c) for c in cases}}}
            for p in self.compensators():
                extra[self.column(f"{p}_picks")] = list(self.setting_range(p))
                extra[f"{p}_at_bound"] = self.at_bound(p)
                extra[f"{p}_pinned_at_bound"] = self.at_bound(p, pinned=True)
            extra.update(self.extra)
        else:
            extra = {"adjust": self.adjust, "failed_groups": self.failed_groups(),
                     **({} if self.adjust is None else {
                         "failed_groups_adjusted": self.failed_groups(adjusted=True)}),
                     "summary": self.summary_frame().to_dict("records")}
        counts, spec = {c: self.counts(o) for c, o in cases.items()}, self.spec()
        return {"mechanism": self.mechanism, "n": self.n, "seed": int(self.seed),
                "tolerances": self.tolerances, "output": self.limit_output, "unit": self.unit,
                "spec": None if spec is None else spec.to_dict(), "cases": list(cases),
                "failed": next(iter(counts.values()))["failed"], "counts": counts,
                "yields": {c: k["ok"] / k["n"] for c, k in counts.items()},
                "yield_ci": {"method": YIELD_CI_METHOD, "level": 0.95,
                             **{c: list(self.yield_ci(c)) for c in cases}},
                "quantiles": {"definition": QUANTILES_MEAN,
                              **{c: self.quantiles(c) for c in cases}},
                **({} if self.candidates is None else {"inspection": self.inspection()}),
                "extra": extra}


def montecarlo(mech, tolerances: ToleranceSet, n: int, seed: int, outputs=None,
               limit: float | None = None, limit_output: str | None = None, n_jobs: int = 1,
               progress=False, chunk_size: int = CHUNK, adjust: str | None = None,
               lower_limit: float | None = None, *, fast: bool = False, backend=None,
               store=None, scheduler=None, hold: str = "nominal",
               objective=None) -> MonteCarloResult:
    """n machines of the file (see the module doc). Every output with a [[specs]] entry in the
    file splits its ok machines into ok and out_of_spec; `limit`/`lower_limit` replace the
    spec of limit_output (default: the first output studied with limits given, else the first
    output of the file's specs, else the first output). `adjust` (a compensator of the file)
    adds the adjusted case: limit_output minimised over the compensator on each machine, or
    brought to `objective` ("target=T", "centre=L,U": sewtol.adjuster.Objective)
    (`sewtol.studies.adjusting.adjusted`: the generic optimiser, or with fast=True the
    mechanism's plug-in where it takes the compensator and minimises), columns NAME_adjusted,
    PARAM_setting, status_adjusted, failed_group_adjusted; `adjust` may also map one parameter
    to its box (a plug-in's search range). fast=True: the plug-in kernel for the outputs it
    gives, the plug-in's words for why a machine fails (`named_failures`) and its names of the
    columns (`Plugins.columns["montecarlo"]`). hold (with a compensator): the fixed case keeps it at
    its "nominal" value or at the nominal machine's "optimum" (`at_optimum`: the setting an
    assembler finds for the nominal; the result's `held` has the values). backend, store,
    scheduler: as `sample_machines` (joblib backend, study folder, Dask cluster); on the
    plug-ins alone (`gil_free`) n_jobs > 1 runs threads of this process unless a backend is
    given. The machines are kept compactly as they arrive (`MachineColumns`: no deviations, words
    as codes); `MonteCarloResult.machines` builds their table when asked."""
    names = tuple(mech.output_names if outputs is None else outputs)
    for name in names:
        mech.output(name)
    for name in adjust.split(",") if isinstance(adjust, str) else ():
        if name.strip() not in mech.compensators:
            raise ParameterError("adjust", "must name a compensator of the file ("
                                 + (", ".join(mech.compensators) or "it has none") + ")", adjust)
    given = limit is not None or lower_limit is not None
    if limit_output is None and (given or not mech.specs):
        limit_output = names[0]
    limit_output, spec, source = mech.resolve_spec(limit_output, limit, lower_limit)
    if limit_output not in names:
        names = (*names, limit_output)
    specs = tuple(s for s in mech.specs if s.output in names and s.output != limit_output)
    specs += () if spec is None else (spec,)
    if hold not in HOLDS:
        raise ParameterError("hold", f"must be one of {', '.join(HOLDS)}", hold)
    if hold == "optimum" and adjust is not None:
        mech = at_optimum(mech, adjust, limit_output, fast, objective)
    nominal = mech.parameter_record()
    check_seed(seed)
    ncomp = 0 if adjust is None else len(adjust.split(",") if isinstance(adjust, str)
                                         else adjust)
    footprint = montecarlo_bytes(len(names), ncomp)
    check_sampling(nominal, tolerances, n, seed, chunk_size, bytes_per_row=footprint)
    pl = plugins(mech) if fast else NO_PLUGINS
    # another objective than the minimum takes the generic adjuster (Python: worker processes)
    if backend is None and scheduler is None and n_jobs != 1 and gil_free(pl, names, adjust) \
            and (adjust is None or objective in (None, "minimise")):
        backend = "threading"
    collect = _Collector(chunk_bounds(int(n), chunk_size))
    blank = None if pl.failure_table is None else failure_blank(
        mech, pl.failure_table, InputLaw.of(tolerances).window(unit_streams(seed, 1), 0, 1))
    _, draw = _sampled(_montecarlo_chunk, nominal, tolerances, n, seed, n_jobs, progress,
                       backend, chunk_size, f"Monte-Carlo {mech.name}", store, scheduler,
                       collect, dict(mech=mech, outputs=list(names), compensator=adjust,
                                     target=limit_output, fast=fast, spec=spec, blank=blank,
                                     objective=objective),
                       footprint, TOGETHER if gil_free(pl, names, adjust) else 1)
    params = tuple(tolerances.active().params)
    dev_names = tuple(draw.law.params)
    # the table's order: machine, deviations, outputs as the chunks give them; a mechanism's
    # names in its order after the deviations
    order = ["machine", *dev_names, *collect.order]
    columns = dict(pl.columns.get("montecarlo", {}))
    if columns:
        first = ["machine", *params, *(k for k in columns if k in order)]
        order = first + [k for k in order if k not in first]
    table = collect.table(order, columns, draw, dev_names)
    if adjust is not None:
        names = (*names, f"{limit_output}_adjusted")
        adjust = adjust if isinstance(adjust, str) else ",".join(adjust)
    law = InputLaw.of(tolerances)
    return MonteCarloResult(mech.name, table, names, tolerances.name, int(seed), limit_output,
                            specs, source, adjust, mech.output(limit_output).unit, params,
                            columns=columns, held=mech.nominal_values(),
                            candidates=law.acceptance(n, seed)[1] if law.relations else None)


HOLDS = ("nominal", "optimum")


def gil_free(pl, outputs, adjust) -> bool:
    """True when a Monte-Carlo chunk runs on the plug-ins alone (the kernel gives every output,
    the exact adjuster sets the compensator): numba kernels and whole-array numpy that release
    the GIL, so the local workers of `montecarlo` are threads of this process (no worker
    start-up, no chunk pickled back, one process's memory; benchmarks/cli.py measures it).
    The generic path's Python loops hold the GIL: it keeps joblib's worker processes."""
    return (pl.kernel is not None and set(outputs) <= set(pl.kernel_outputs)
            and (adjust is None or pl.adjuster is not None))


def at_optimum(mech, compensators, output: str, fast: bool = True, objective=None):
    """The mechanism with its compensators' nominals at the nominal machine's optimum of
    `output` (`adjusting.adjusted`, the same adjuster as every machine's): the setting an
    assembler finds for the nominal machine, held in a study's fixed case."""
    from sewtol.studies.adjusting import adjusted

    one = {k: np.array([v]) for k, v in mech.nominal_values().items()}
    comps = [compensators] if isinstance(compensators, str) else compensators
    settings = {k: float(v[0]) for k, v in adjusted(mech, one, comps, output, fast=fast,
                                                    objective=objective).settings.items()}
    if not np.all(np.isfinite(list(settings.values()))):
        raise ParameterError("hold", "optimum needs a nominal machine that runs at some "
                             "setting of the compensators", settings)
    return mech.override(**settings)


def named_failures(mech, failure_table, frame: pd.DataFrame, params, output: str, spec, adjust):
    """The machines' status in the mechanism's words, per case: ok, out_of_spec (by `spec`) or
    why it does not run (`Plugins.failure_table` of its values: in the adjusted case at its
    setting, or at the nominal where it has none), the group in failed_group and the plug-in's
    further figures in fail_NAME ("" and NaN where it runs)."""
    # a shallow copy: the columns set below replace the caller's (pandas >= 2 never writes a
    # whole-column assignment into the array it replaces), no deep copy of the table
    frame = frame.copy(deep=False)
    named = failure_columns(mech, failure_table, {p: frame[p].to_numpy(float) for p in params},
                            {k: frame[k] for k in frame}, output, spec, adjust)
    for k, v in named.items():
        frame[k] = v
    return frame


def failure_columns(mech, failure_table, deviations, columns, output: str, spec,
                    adjust, blank: Mapping | None = None) -> dict:
    """The columns `named_failures` sets (status, failed_group, fail_NAME per case, in that
    order) of machines `deviations` whose outputs and settings are `columns`. blank: the
    failure table's columns and types (`failure_blank`), so machines that all run ask the
    plug-in nothing (a Monte-Carlo's chunks, most of which have no failure)."""
    values = machines(mech, deviations)
    cases = {"": values}
    if adjust is not None:
        nominal = mech.nominal_values()
        cases["_adjusted"] = {**values, **{
            k.removesuffix("_setting"): np.where(np.isfinite(v), v, nominal[k.removesuffix(
                "_setting")]) for k, v in columns.items() if k.endswith("_setting")}}
    n = len(next(iter(values.values())))
    named = {}
    for suffix, vals in cases.items():
        value = np.asarray(columns[f"{output}{suffix}"], float)
        failed = np.isnan(value)
        # the reasons of the machines that fail only (each machine's reason is its own): the
        # table of all n machines held every parameter column n long, twice over; with none
        # failing, machine 0 gives the columns' names and types, its values unused
        rows = failed if failed.any() else np.arange(n) == 0
        why = dict(failure_table(mech, {k: (v[rows] if np.shape(v)[:1] == (n,) else v)
                                        for k, v in vals.items()})) \
            if failed.any() or blank is None else {k: np.empty(0, t) for k, t in blank.items()}
        passes = np.broadcast_to(np.where(spec is None or spec.passes(value), "ok",
                                          "out_of_spec").astype(object), (n,)).copy()
        named[f"status{suffix}"] = _scatter(passes, failed, why.pop("status"), object)
        named[f"failed_group{suffix}"] = _scatter(np.full(n, "", object), failed,
                                                  why.pop("group"), object)
        for k, v in why.items():
            v = np.asarray(v)
            named[f"fail_{k}{suffix}"] = _scatter(np.full(n, np.nan, np.result_type(v, float)),
                                                  failed, v)
    return named


def _scatter(out: np.ndarray, rows: np.ndarray, values, dtype=None) -> np.ndarray:
    """out with out[rows] = values (the values of the rows where mask `rows` holds)."""
    if rows.any():
        out[rows] = np.asarray(values, dtype)
    return out
