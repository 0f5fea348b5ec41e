"""Chunked, parallel, reproducible execution of a study.

The work is cut into chunks of a fixed size that does not depend on the number of workers; chunk
i draws its random numbers from the i-th child of one Generator (NEP 19 `spawn`), so the results
are the same for any n_jobs and on any cluster. joblib runs the chunks: on this machine with
`n_jobs` (any joblib backend through `backend=`; "threading" on the standard library's thread
pool), or on a Dask cluster through joblib's dask backend with `scheduler=` (an address such
as "tcp://host:8786", or a distributed.Client).
Results are taken as they complete, so progress (a tqdm bar on stderr, or a callback
progress(done, total)) and the checkpoint store follow the work, in any order of completion.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence

from sewtol.errors import ParameterError

# how long to wait for a scheduler to answer (s); a wrong address fails after this
CONNECT_TIMEOUT_S = 10


def chunk_bounds(n: int, chunk_size: int) -> list[tuple[int, int]]:
    return [(i, min(i + chunk_size, n)) for i in range(0, n, chunk_size)]


def check_address(address) -> str:
    """`address` if it reads as a Dask scheduler address (scheme://host:port, a port in
    1..65535, or an in-process inproc:// address), else ParameterError; nothing is
    contacted."""
    from distributed.comm.addressing import get_address_host_port, parse_address

    rule = "must be a Dask scheduler address such as tcp://host:8786"
    if not isinstance(address, str) or not address.strip() or any(c.isspace() for c in address):
        raise ParameterError("scheduler", rule, address)
    try:
        if parse_address(address)[0] == "inproc":  # a cluster in this process
            return address
        port = get_address_host_port(address)[1]
    except ValueError as exc:
        raise ParameterError("scheduler", f"{rule} ({exc})", address) from None
    if not 0 < port < 65536:
        raise ParameterError("scheduler", f"{rule} (port {port} is not in 1..65535)", address)
    return address


def probe(address: str, timeout: float) -> str | None:
    """Ask `address` who it is, all within `timeout` s: None if a Dask scheduler answers,
    else why not, in words. Whatever the other end does (no answer, an HTTP server that waits
    for a request line, random bytes that decode to a 3 EiB frame) ends in a reason, never a
    hang or a traceback: the question runs in its own thread and event loop, abandoned at the
    deadline."""
    import asyncio

    from distributed.comm import connect as open_comm

    stage = ["connecting"]

    async def ask():
        comm = await open_comm(address, timeout=timeout)
        stage[0] = "answered"
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    outcome: dict = {}

    def run():
        try:
            outcome["reply"] = asyncio.run(asyncio.wait_for(ask(), timeout))
        except Exception as exc:  # kept whole and turned into the reason below
            outcome["error"] = exc

    thread = threading.Thread(target=run, name="sewtol-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 1)  # the loop's own deadline, plus a second to wind down
    error, reply = outcome.get("error"), outcome.get("reply")
    if thread.is_alive() or isinstance(error, (TimeoutError, asyncio.TimeoutError)):
        return f"no Dask scheduler answers there within {timeout:g} s"
    if error is not None and stage[0] == "connecting" and isinstance(error, OSError):
        return f"no Dask scheduler answers there within {timeout:g} s ({type(error).__name__})"
    if error is not None:
        return f"something answers there, but not as a Dask scheduler ({type(error).__name__})"
    if not (isinstance(reply, dict) and reply.get("type") == "Scheduler"):
        return "something answers there, but not as a Dask scheduler"
    return None


def connect(address: str, timeout: float = CONNECT_TIMEOUT_S):
    """A distributed.Client on the scheduler at `address`, made within `timeout` s (the probe
    and the client share it); ParameterError, naming the address, if no scheduler answers."""
    from distributed import Client

    check_address(address)
    start = time.monotonic()
    why = probe(address, timeout)
    if why is not None:
        raise ParameterError("scheduler", why, address)
    left = max(1.0, timeout - (time.monotonic() - start))
    made: dict = {}

    def make():  # in a thread: Client's own timeout does not cover a stalled handshake
        try:
            made["client"] = _closing_client(Client, address, left)
        except Exception as exc:  # kept whole and turned into the one line below
            made["error"] = exc

    thread = threading.Thread(target=make, name="sewtol-scheduler-client", daemon=True)
    thread.start()
    thread.join(left + 0.25)
    if "client" in made:
        return made["client"]
    # the scheduler went away (or stalled) between the probe and the client
    why = type(made["error"]).__name__ if "error" in made else f"no answer within {timeout:g} s"
    raise ParameterError("scheduler", f"the Dask scheduler there stopped answering ({why})",
                         address)


def _closing_client(Client, address: str, timeout: float):
    """Client(address) whose failed start closes it at once: a half-made client left to the
    garbage collector waits twice the timeout in __del__ and prints "Exception ignored"."""

    class ClosingClient(Client):
        def start(self, **kwargs):
            try:
                super().start(**kwargs)
            except BaseException:
                with contextlib.suppress(Exception):
                    self.close(timeout=1)
                self.status = "closed"  # __del__ has nothing left to close
                raise

    return ClosingClient(address, timeout=timeout, set_as_default=False)


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


def local_workers(n_jobs: int) -> int:
    """The worker count n_jobs stands for on this machine (-1: one per core)."""
    return max(1, os.cpu_count() or 1) if n_jobs == -1 else n_jobs


@functools.cache
def _numba_cores() -> int:
    """numba.config.NUMBA_NUM_THREADS as numba will read it at import (NUMBA_NUM_THREADS, else
    the cores this process may run on), before anything here sets the variable."""
    if os.environ.get("NUMBA_NUM_THREADS"):
        return int(os.environ["NUMBA_NUM_THREADS"])
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else os.cpu_count() or 1)


def numba_threads_local(n_jobs: int, process: bool = False) -> int:
    """In one of n_jobs local workers (processes, or threads of this process: numba's count
    is per thread): NUMBA_NUM_THREADS // n_jobs numba threads (at
    least 1), so the workers together run no more threads than the cores numba sees (the
    strategies study already did this in its chunks). The kernels' loops are over independent
    machines: no number depends on it. A worker process (`process`) that has not imported
    numba is not made to: the share goes into NUMBA_NUM_THREADS, which numba reads if the
    work imports it (the strategies study's workers run the needle's kernels compiled ahead of
    time, without numba)."""
    share = max(1, _numba_cores() // max(1, n_jobs))
    if process and "numba" not in sys.modules:
        os.environ["NUMBA_NUM_THREADS"] = str(share)
        return share
    import numba

    share = min(share, numba.config.NUMBA_NUM_THREADS)  # a reused worker: as numba started
    numba.set_num_threads(share)
    return share


def _indexed(fn: Callable, run: tuple[int, ...], args: Sequence, parent_pid: int | None,
             on_cluster: bool, n_jobs: int = 1):
    """The results of chunks `run` with their indices (results arrive in any order): fn(*args)
    is chunk run[0]'s result, or with several chunks their list. A local worker process
    watches the main process (parent_pid) and takes its share of the numba threads; a
    cluster's workers outlive it by design."""
    if parent_pid is not None:
        _watch_parent(parent_pid)
    if n_jobs > 1:  # numba's thread count is per thread: a worker thread takes its share too
        numba_threads_local(n_jobs, process=parent_pid is not None)
    if on_cluster:
        numba_threads_on_worker()
    return run, fn(*args) if len(run) > 1 else [fn(*args)]


def runs_of(todo: Sequence[int], size: int) -> list[tuple[int, ...]]:
    """`todo` (ascending chunk indices) as runs of consecutive indices, at most `size` long."""
    runs: list[tuple[int, ...]] = []
    for i in todo:
        if runs and len(runs[-1]) < size and runs[-1][-1] == i - 1:
            runs[-1] += (i,)
        else:
            runs.append((i,))
    return runs


def _threaded(tasks: list, workers: int, stack: contextlib.ExitStack) -> Iterator:
    """The tasks' results as they complete, on `workers` threads of this process (the
    plug-ins' GIL-free kernels: `montecarlo.gil_free`): the standard library's pool, without
    joblib's tenth of a second of import. An error or ^C cancels the tasks not yet started; a
    result is dropped by the pool once it is taken (as_completed releases its futures)."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    pool = stack.enter_context(ThreadPoolExecutor(workers, thread_name_prefix="sewtol-chunk"))
    stack.callback(pool.shutdown, cancel_futures=True)
    return (done.result() for done in as_completed(
        [pool.submit(_indexed, f, run, a, None, False, workers) for f, a, run in tasks]))


def run_chunks(fn: Callable, args: Sequence, n_jobs: int = 1, progress=False,
               desc: str = "", backend: str | None = None, store=None,
               validate: Callable | None = None, scheduler=None,
               keep: Callable | None = None, together: int = 1,
               join: Callable | None = None) -> list:
    """[fn(*a) for a in args] in order, in parallel when n_jobs != 1 or on a Dask cluster.

    progress: True for a tqdm bar on stderr, or a callable progress(done, total) called once
    before the first chunk (done counts chunks loaded from the store) and after each chunk.
    scheduler: run on a Dask cluster (address or distributed.Client; the cluster's workers set
    the parallelism, so n_jobs must stay 1). A worker that dies has its chunks recomputed
    elsewhere by the scheduler; every chunk's numbers depend only on its index.
    With a ChunkStore, chunks saved by an earlier (interrupted) run are loaded instead of
    computed, and each newly finished chunk is saved as soon as it arrives. A saved chunk is used
    only if the store accepts it (study hash, index, checksum) and `validate(i, result)` (the
    study's own check of its rows) returns None; any other chunk is recomputed and stderr says
    which one and why. Local workers exit when the main process is gone (see `_watch_parent`).
    keep: what is kept of chunk i, keep(i, result), applied as each chunk arrives (after it is
    saved or loaded and validated): a study that reduces its chunks never holds them whole.
    together, join: a study whose every call costs the same whatever its size (the needle's
    kernels: parameter columns, feasibility, statuses, a task's dispatch) computes up to
    `together` consecutive chunks in one call, join(run) -> (f, a) with f(*a) the list of the
    results of chunks `run` (indices); fewer when that leaves under two calls per worker, and
    one on a cluster. Each chunk is still saved, kept and counted on its own, so results,
    progress and the store are those of single chunks.
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
            if i >= len(args):
                store.warn(i, f"the study has only {len(args)} chunks; ignoring it")
                continue
            result, why = store.load(i)
            if why is None and validate is not None:
                why = validate(i, result)
            if why is None:
                out[i] = result if keep is None else keep(i, result)
            else:
                store.warn(i, why)
        others = store.others()
        if others:
            print(f"sewtol: {store.label}: ignoring {len(others)} file(s) that are not chunks of "
                  f"this format (never opened): {', '.join(others[:5])}", file=sys.stderr)
        todo = [i for i in todo if out[i] is None]
    done = len(args) - len(todo)
    bar = None
    if report is None and progress:
        from tqdm.auto import tqdm  # here: it imports asyncio, a tenth of a second of start-up

        bar = tqdm(total=len(args), initial=done, desc=desc, file=sys.stderr, leave=False)
    with contextlib.ExitStack() as stack:
        if bar is not None:
            stack.enter_context(bar)
        if report is not None:
            report(done, len(args))
        serial = scheduler is None and n_jobs == 1 and backend is None
        workers = local_workers(n_jobs)
        # on a cluster one chunk per task (progress and resume per chunk, as below)
        size = 1 if join is None or scheduler is not None else \
            max(1, min(int(together), len(todo) // (2 * workers)))
        tasks = [(*join(run), run) if len(run) > 1 else (fn, args[run[0]], run)
                 for run in runs_of(todo, size)]
        if serial:
            results = (_indexed(f, run, a, None, False) for f, a, run in tasks)
        elif backend == "threading" and scheduler is None:
            results = _threaded(tasks, workers, stack)
        else:
            import joblib  # here: a serial run never needs it (a tenth of a second to import)

            batch = "auto"
            on_cluster = scheduler is not None
            if on_cluster:
                client = connect(scheduler) if isinstance(scheduler, str) else scheduler
                if isinstance(scheduler, str):
                    stack.enter_context(client)
                stack.enter_context(joblib.parallel_config(backend="dask", client=client))
                n_jobs, batch = -1, 1  # one chunk per task: progress and resume per chunk
            elif backend:
                stack.enter_context(joblib.parallel_config(backend=backend))
            # local worker processes watch this one; a cluster's workers outlive it by design;
            # local workers (processes, or threads of this one) share numba's threads
            local = not on_cluster and backend in (None, "loky", "multiprocessing")
            parent = os.getpid() if local else None
            share = local or backend == "threading"
            results = joblib.Parallel(n_jobs=n_jobs, return_as="generator_unordered",
                                      batch_size=batch)(
                joblib.delayed(_indexed)(f, run, a, parent, on_cluster,
                                         joblib.effective_n_jobs(n_jobs) if share else 1)
                for f, a, run in tasks)
        for run, rs in results:
            for i, r in zip(run, rs, strict=True):
                if store is not None:
                    store.save(i, r)
                out[i] = r if keep is None else keep(i, r)
                done += 1
                if bar is not None:
                    bar.update()
                if report is not None:
                    report(done, len(args))
            del rs, r
    return out
