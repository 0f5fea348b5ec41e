"""Chunked, parallel, reproducible execution of a study.

The work is cut into chunks of a fixed size that does not depend on the number of workers; chunk
i draws its random numbers from the i-th child of one Generator (NEP 19 `spawn`), so the results
are the same for any n_jobs. joblib runs the chunks (any joblib backend, e.g. "dask" with a
dask.distributed Client, through `backend=`), tqdm shows progress on stderr.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence

import joblib
import numpy as np
from tqdm.auto import tqdm

from ..errors import ParameterError


def chunk_bounds(n: int, chunk_size: int) -> list[tuple[int, int]]:
    return [(i, min(i + chunk_size, n)) for i in range(0, n, chunk_size)]


def child_generators(seed: int | np.random.SeedSequence, n: int) -> list[np.random.Generator]:
    return np.random.default_rng(seed).spawn(n)


_WATCHDOG: list[int] = []  # the parent pid this worker process watches (set once)


def _parent_alive(pid: int, ppid_at_start: int) -> bool:
    if ppid_at_start == pid:  # our direct parent: re-parenting means it is gone
        return os.getppid() == pid
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a killed parent not yet reaped by its own parent is a zombie: gone too
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def _watch_parent(pid: int, every_s: float = 0.25) -> None:
    """In a worker: exit at once when the process that started the study is gone.

    SIGKILL of the main process (a scheduler, `timeout -s KILL`, the OOM killer) gives it no
    chance to stop its workers; without this they would compute on, holding its stdout open.
    """
    if os.getpid() == pid or _WATCHDOG:
        return
    _WATCHDOG.append(pid)
    ppid = os.getppid()
    if ppid == pid and sys.platform.startswith("linux"):
        # the kernel's own parent-death signal acts at once, even while a numba kernel holds
        # the GIL; the polling thread below covers other platforms and indirect parents
        with contextlib.suppress(OSError, AttributeError):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, 9, 0, 0, 0)  # PR_SET_PDEATHSIG, SIGKILL
            if os.getppid() != pid:  # the parent died before the call
                os._exit(1)

    def loop():
        while _parent_alive(pid, ppid):
            time.sleep(every_s)
        os._exit(1)

    threading.Thread(target=loop, name="sewtol-parent-watch", daemon=True).start()


def _guarded(fn, parent_pid, *a):
    _watch_parent(parent_pid)
    return fn(*a)


def run_chunks(fn: Callable, args: Sequence, n_jobs: int = 1, progress: bool = False,
               desc: str = "", backend: str | None = None, store=None,
               validate: Callable | None = None) -> list:
    """[fn(*a) for a in args] in order, in parallel when n_jobs != 1.

    With a ChunkStore, chunks saved by an earlier (interrupted) run are loaded instead of
    computed, and each newly finished chunk is saved as soon as it arrives. A saved chunk is used
    only if the store accepts it (study hash, index, checksum) and `validate(i, result)` (the
    study's own check of its rows) returns None; any other chunk is recomputed and stderr says
    which one and why. Workers exit when the main process is gone (see `_watch_parent`).
    """
    if n_jobs == 0 or n_jobs < -1:
        raise ParameterError("n_jobs", "must be a positive number of workers or -1 (all cores)",
                             n_jobs)
    out: list = [None] * len(args)
    todo = list(range(len(args)))
    if store is not None:
        for i in store.done():
            if i >= len(args):
                store.warn(i, f"the study has only {len(args)} chunks; ignoring it")
                continue
            result, why = store.load(i)
            if why is None and validate is not None:
                why = validate(i, result)
            if why is None:
                out[i] = result
            else:
                store.warn(i, why)
        others = store.others()
        if others:
            print(f"sewtol: {store.label}: ignoring {len(others)} file(s) that are not chunks of "
                  f"this format (never opened): {', '.join(others[:5])}", file=sys.stderr)
        todo = [i for i in todo if out[i] is None]
    bar = tqdm(total=len(args), initial=len(args) - len(todo), desc=desc, disable=not progress,
               file=sys.stderr, leave=False)
    with bar, contextlib.ExitStack() as stack:
        if n_jobs == 1 and backend is None:
            results = (fn(*args[i]) for i in todo)
        else:
            if backend:
                stack.enter_context(joblib.parallel_config(backend=backend))
            # local worker processes watch this one; a cluster's workers outlive it by design
            local = backend in (None, "loky", "multiprocessing")
            results = joblib.Parallel(n_jobs=n_jobs, return_as="generator")(
                joblib.delayed(_guarded)(fn, os.getpid(), *args[i]) if local
                else joblib.delayed(fn)(*args[i]) for i in todo)
        for i, r in zip(todo, results, strict=True):
            out[i] = r
            if store is not None:
                store.save(i, r)
            bar.update()
    return out
