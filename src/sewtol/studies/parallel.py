"""Chunked, parallel, reproducible execution of a study.

The work is cut into chunks of a fixed size that does not depend on the number of workers; chunk
i draws its random numbers from the i-th child of one Generator (NEP 19 `spawn`), so the results
are the same for any n_jobs. joblib runs the chunks (any joblib backend, e.g. "dask" with a
dask.distributed Client, through `backend=`), tqdm shows progress on stderr.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Sequence

import joblib
import numpy as np
from tqdm.auto import tqdm

from ..errors import ParameterError


def chunk_bounds(n: int, chunk_size: int) -> list[tuple[int, int]]:
    return [(i, min(i + chunk_size, n)) for i in range(0, n, chunk_size)]


def child_generators(seed: int | np.random.SeedSequence, n: int) -> list[np.random.Generator]:
    return np.random.default_rng(seed).spawn(n)


def run_chunks(fn: Callable, args: Sequence, n_jobs: int = 1, progress: bool = False,
               desc: str = "", backend: str | None = None, store=None) -> list:
    """[fn(*a) for a in args] in order, in parallel when n_jobs != 1.

    With a ChunkStore, chunks saved by an earlier (interrupted) run are loaded instead of
    computed, and each newly finished chunk is saved as soon as it arrives.
    """
    if n_jobs == 0 or n_jobs < -1:
        raise ParameterError("n_jobs", "must be a positive number of workers or -1 (all cores)",
                             n_jobs)
    out: list = [None] * len(args)
    todo = list(range(len(args)))
    if store is not None:
        for i in store.done():
            if i < len(args):
                out[i] = store.load(i)
        todo = [i for i in todo if out[i] is None]
    bar = tqdm(total=len(args), initial=len(args) - len(todo), desc=desc, disable=not progress,
               file=sys.stderr, leave=False)
    with bar, contextlib.ExitStack() as stack:
        if n_jobs == 1 and backend is None:
            results = (fn(*args[i]) for i in todo)
        else:
            if backend:
                stack.enter_context(joblib.parallel_config(backend=backend))
            results = joblib.Parallel(n_jobs=n_jobs, return_as="generator")(
                joblib.delayed(fn)(*args[i]) for i in todo)
        for i, r in zip(todo, results, strict=True):
            out[i] = r
            if store is not None:
                store.save(i, r)
            bar.update()
    return out
