"""Chunked, parallel, reproducible execution of a study.

The work is cut into chunks of a fixed size that does not depend on the number of workers; chunk
i draws its random numbers from the i-th child of one Generator (NEP 19 `spawn`), so the results
are the same for any n_jobs and on any cluster. joblib runs the chunks: on this machine with
`n_jobs` (any joblib backend through `backend=`), or on a Dask cluster through joblib's dask
backend with `scheduler=` (an address such as "tcp://host:8786", or a distributed.Client).
Results are taken as they complete, so progress (a tqdm bar on stderr, or a callback
progress(done, total)) and the checkpoint store follow the work, in any order of completion.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Sequence

import joblib
import numpy as np
from tqdm.auto import tqdm

from ..errors import ParameterError

# how long to wait for a scheduler to answer (s); a wrong address fails after this
CONNECT_TIMEOUT_S = 10


def chunk_bounds(n: int, chunk_size: int) -> list[tuple[int, int]]:
    return [(i, min(i + chunk_size, n)) for i in range(0, n, chunk_size)]


def child_generators(seed: int | np.random.SeedSequence, n: int) -> list[np.random.Generator]:
    return np.random.default_rng(seed).spawn(n)


def connect(address: str, timeout: float = CONNECT_TIMEOUT_S):
    """A distributed.Client on the scheduler at `address`; ParameterError if it does not answer."""
    from distributed import Client

    if not isinstance(address, str) or not address.strip() or any(c.isspace() for c in address):
        raise ParameterError("scheduler", "must be a scheduler address such as "
                             "tcp://host:8786", address)
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ParameterError("scheduler", f"no Dask scheduler answers there within {timeout:g} s "
                             f"({type(exc).__name__})", address) from None


def numba_threads_on_worker() -> int | None:
    """On a Dask worker running k tasks at once, give each task NUMBA_NUM_THREADS // k numba
    threads (at least 1), so a worker never runs more threads than NUMBA_NUM_THREADS says.
    Returns the number set, or None outside a Dask worker."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    import numba

    share = max(1, numba.config.NUMBA_NUM_THREADS // max(1, worker.state.nthreads))
    numba.set_num_threads(share)
    return share


def _indexed(fn: Callable, i: int, args: Sequence, on_cluster: bool):
    if on_cluster:
        numba_threads_on_worker()
    return i, fn(*args)


def run_chunks(fn: Callable, args: Sequence, n_jobs: int = 1, progress=False,
               desc: str = "", backend: str | None = None, store=None, scheduler=None) -> list:
    """[fn(*a) for a in args] in order, in parallel when n_jobs != 1 or on a Dask cluster.

    progress: True for a tqdm bar on stderr, or a callable progress(done, total) called once
    before the first chunk (done counts chunks loaded from the store) and after each chunk.
    scheduler: run on a Dask cluster (address or distributed.Client; the cluster's workers set
    the parallelism, so n_jobs must stay 1). A worker that dies has its chunks recomputed
    elsewhere by the scheduler; every chunk's numbers depend only on its index.
    With a ChunkStore, chunks saved by an earlier (interrupted) run are loaded instead of
    computed, and each newly finished chunk is saved as soon as it arrives.
    """
    if n_jobs == 0 or n_jobs < -1:
        raise ParameterError("n_jobs", "must be a positive number of workers or -1 (all cores)",
                             n_jobs)
    if scheduler is not None and (n_jobs != 1 or backend is not None):
        raise ParameterError("n_jobs", "is the single-machine path: with a scheduler the "
                             "cluster's workers set the parallelism (leave n_jobs = 1 and "
                             "backend = None)", n_jobs if n_jobs != 1 else backend)
    report = progress if callable(progress) else None
    out: list = [None] * len(args)
    todo = list(range(len(args)))
    if store is not None:
        for i in store.done():
            if i < len(args):
                out[i] = store.load(i)
        todo = [i for i in todo if out[i] is None]
    done = len(args) - len(todo)
    bar = tqdm(total=len(args), initial=done, desc=desc, disable=report is not None or not progress,
               file=sys.stderr, leave=False)
    with bar, contextlib.ExitStack() as stack:
        if report is not None:
            report(done, len(args))
        if scheduler is None and n_jobs == 1 and backend is None:
            results = (_indexed(fn, i, args[i], False) for i in todo)
        else:
            batch = "auto"
            if scheduler is not None:
                client = (connect(scheduler) if isinstance(scheduler, str) else scheduler)
                if isinstance(scheduler, str):
                    stack.enter_context(client)
                stack.enter_context(joblib.parallel_config(backend="dask", client=client))
                n_jobs, batch = -1, 1  # one chunk per task: progress and resume per chunk
            elif backend:
                stack.enter_context(joblib.parallel_config(backend=backend))
            results = joblib.Parallel(n_jobs=n_jobs, return_as="generator_unordered",
                                      batch_size=batch)(
                joblib.delayed(_indexed)(fn, i, args[i], scheduler is not None) for i in todo)
        for i, r in results:
            out[i] = r
            if store is not None:
                store.save(i, r)
            done += 1
            bar.update()
            if report is not None:
                report(done, len(args))
    return out
