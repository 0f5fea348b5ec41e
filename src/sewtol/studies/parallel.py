"""Chunked, parallel, reproducible execution of a study.

The work is cut into chunks of a fixed size that does not depend on the number of workers; chunk
i draws its random numbers from the i-th child of one Generator (NEP 19 `spawn`), so the results
are the same for any n_jobs. joblib runs the chunks (any joblib backend, e.g. "dask" with a
dask.distributed Client, through `backend=`), tqdm shows progress on stderr.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import joblib
import numpy as np
from tqdm.auto import tqdm


def chunk_bounds(n: int, chunk_size: int) -> list[tuple[int, int]]:
    return [(i, min(i + chunk_size, n)) for i in range(0, n, chunk_size)]


def child_generators(seed: int | np.random.SeedSequence, n: int) -> list[np.random.Generator]:
    return np.random.default_rng(seed).spawn(n)


def run_chunks(fn: Callable, args: Sequence, n_jobs: int = 1, progress: bool = False,
               desc: str = "", backend: str | None = None) -> list:
    """[fn(*a) for a in args] in order, in parallel when n_jobs != 1."""
    bar = tqdm(total=len(args), desc=desc, disable=not progress, file=sys.stderr, leave=False)
    try:
        if n_jobs == 1 and backend is None:
            out = []
            for a in args:
                out.append(fn(*a))
                bar.update()
            return out
        with joblib.parallel_config(backend=backend) if backend else _null():
            gen = joblib.Parallel(n_jobs=n_jobs, return_as="generator")(
                joblib.delayed(fn)(*a) for a in args)
            out = []
            for r in gen:
                out.append(r)
                bar.update()
            return out
    finally:
        bar.close()


class _null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False
