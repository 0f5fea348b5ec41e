"""Fused numba kernels of the needle drive (fast paths; the numpy engine is the reference they are
tested against), and those a Monte-Carlo and the strategies study call, compiled ahead of time.

A short `needle montecarlo` spent most of its start-up importing numba and setting up its
compiler context (about 0.7 s of 1.3 s warm), and every worker process of `needle strategies`
held numba and LLVM (about 100 MB of its resident size). `build()` (make's `kernels` step)
compiles the kernels of AHEAD (window.fixed_batch, window.optimise_batch, window.outer_batch,
window.cd_angle_batch, positions.positions_kernel_serial), the same Python functions run
serially (prange is range outside a parallel njit), with numba.pycc into an extension module
beside this file that runs without numba. Inside `ahead_of_time()` the functions of the same
names below run it on the calling thread; elsewhere, or when it is not built, numba's kernels
(window.py, positions.py).
tests/test_ahead.py holds each bit for bit equal to numba's.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import hashlib
import importlib
import importlib.util
from pathlib import Path

import numpy as np

# parameter columns passed to the kernels (fused.py, window.py), in this order
FIELDS = ("AB", "BC", "BE", "CD", "CBE", "Ax", "Ay", "Dx", "Dy", "branch_C", "beta_sense",
          "guide_x", "guide_y", "guide_angle", "guide_shift_um")
# parameter columns of the position kernel, positions.FIELDS (which imports numba; kept equal
# by tests/test_ahead.py)
POSITION_FIELDS = ("LF", "LM", "AM", "AB", "BC", "BE", "CD", "CBE", "beta", "Ax", "Ay", "Dx", "Dy",
                   "branch_M", "branch_C", "beta_sense")
# the kernels compiled ahead of time: name -> (module, function, signature: numba's; P's rows
# follow FIELDS, or POSITION_FIELDS for the positions). outer_batch's cutoff_um is always an
# array there (None: +inf for every machine, which is what numba's kernel makes of None)
AHEAD = {"fixed_batch": ("window", "fixed_batch",
                         "f8[:,:](f8[:,::1], f8[::1], f8[::1], f8[::1], f8)"),
         "optimise_batch": ("window", "optimise_batch",
                            "f8[:,:](f8[:,::1], f8[::1], f8[::1], f8, f8, f8, f8, b1, f8, f8)"),
         "outer_batch": ("window", "outer_batch", "f8[::1](f8[:,::1], i8, f8[::1], f8[::1], f8, f8, "
                         "f8, f8, b1, f8[::1], f8, f8, i8, f8[::1])"),
         "cd_angle_batch": ("window", "cd_angle_batch", "f8[:,:](f8[:,::1], f8[::1], f8[::1], "
                            "f8, f8, f8, f8, b1, f8[::1], f8, f8, i8, f8, f8, f8, f8)"),
         "positions_serial": ("positions", "positions_kernel_serial",
                              "f8[:,:,::1](f8[:,::1], f8[::1])")}
# the most machines a one-process run (n_jobs 1, no cluster) of each needle study computes with
# the compiled module on one thread, numba never imported, rather than on numba's kernels on
# every core (docs/layout.md has the crossings): montecarlo (beta fixed and adjusted) saves 0.7
# s of start-up and costs 19 us a machine; strategies saves 1.5 CPU-s and costs 12 ms a machine
AHEAD_MAX_N = {"montecarlo": 20_000, "strategies": 60}
# the module ahead_of_time() put in force on this thread (a context variable: a thread started
# inside it, such as a worker of a pool, runs numba's kernels)
_IN_FORCE: contextvars.ContextVar = contextvars.ContextVar("needle_ahead", default=None)


def pack(c: dict) -> np.ndarray:
    """Parameter columns (n, 1) to the kernel's (n, len(FIELDS)) matrix."""
    n = next(iter(c.values())).shape[0]
    out = np.empty((n, len(FIELDS)))
    for j, f in enumerate(FIELDS):
        out[:, j] = np.asarray(c[f], float).reshape(-1)  # a column, or one value for all
    return out


def _cpu() -> bytes:
    """This machine's CPU as the module is built for it: its model and feature flags
    (/proc/cpuinfo's first processor), else what the platform module says."""
    import platform

    try:
        info = Path("/proc/cpuinfo").read_text(errors="replace").split("\n\n", 1)[0]
        keep = [ln for ln in info.splitlines() if ln.split(":")[0].strip() in
                ("vendor_id", "cpu family", "model", "model name", "flags", "Features")]
    except OSError:
        keep = []
    return "\n".join(keep or [platform.machine(), platform.processor()]).encode()


def ahead_name() -> str:
    """The extension module's name: ahead_ and a digest of the kernels' sources (this file,
    fused.py, window.py, positions.py), of the numba and numpy versions and of the CPU it is
    built for (_cpu), so a module built from other sources or versions, or on another CPU, is
    never loaded (Python's version is in the file's suffix). Read without importing numba."""
    here = Path(__file__).parent
    h = hashlib.sha256(np.__version__.encode() + _cpu())
    numba = importlib.util.find_spec("numba").submodule_search_locations[0]
    for f in (here / "__init__.py", here / "fused.py", here / "window.py",
              here / "positions.py", Path(numba, "_version.py")):
        h.update(f.read_bytes())
    return "ahead_" + h.hexdigest()[:16]


@functools.cache
def ahead():
    """The extension module built from these sources, or None (not built)."""
    try:
        return importlib.import_module(f"{__name__}.{ahead_name()}")
    except ModuleNotFoundError:
        return None


def runs_ahead(study: str, n: int, n_jobs: int = 1, cluster: bool = False) -> bool:
    """Whether the calling thread of a needle `study` ("montecarlo" or "strategies") of n
    machines runs the compiled module (`ahead_of_time`): in one process, up to AHEAD_MAX_N
    machines; the strategies study on workers always (its chunks run in worker processes, each
    inside the mechanism's `Plugins.serial`: this one figures only the nominal machine)."""
    if cluster:
        return False
    if n_jobs != 1:
        return study == "strategies"
    return n <= AHEAD_MAX_N[study]


@contextlib.contextmanager
def ahead_of_time(use: bool = True):
    """Within, on this thread, the kernels of AHEAD run the module compiled ahead of time when
    it is built (serially, numba never imported); with use False, or without it, numba's
    kernels (parallel over the machines). Yields whether the module is in force."""
    token = _IN_FORCE.set(ahead() if use else None)
    try:
        yield _IN_FORCE.get() is not None
    finally:
        _IN_FORCE.reset(token)


def fixed_batch(P, beta, lo, hi):
    """window.fixed_batch (its default h_deg, 2): Delta+, Delta- (um) per machine."""
    if (m := _IN_FORCE.get()) is not None:
        return m.fixed_batch(P, beta, lo, hi, 2.0)
    from sewtol.mechanisms.needle_208.kernels.window import fixed_batch

    return fixed_batch(P, beta, lo, hi)


def optimise_batch(*args):
    """window.optimise_batch(P, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, h_deg,
    tol_um), every argument given: per machine the columns of window.COLUMNS."""
    if (m := _IN_FORCE.get()) is not None:
        return m.optimise_batch(*args)
    from sewtol.mechanisms.needle_208.kernels.window import optimise_batch

    return optimise_batch(*args)


def cd_angle_batch(*args):
    """window.cd_angle_batch(P, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active,
    cd_grid, a_lo, a_hi, n_a, h_deg, tol_um, xtol_cd, xtol_a), every argument given: per
    machine CD's offset, SumDelta and the guide angle's offset at their joint optimum."""
    if (m := _IN_FORCE.get()) is not None:
        return m.cd_angle_batch(*args)
    from sewtol.mechanisms.needle_208.kernels.window import cd_angle_batch

    return cd_angle_batch(*args)


def outer_batch(P, col, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, grid, h_deg,
                tol_um, rounds, cutoff_um):
    """window.outer_batch, every argument given (cutoff_um None or per machine): per machine
    the compensator's offset where the exact minimum over beta (and the shift) is least."""
    if (m := _IN_FORCE.get()) is not None:
        cut = np.full(P.shape[0], np.inf) if cutoff_um is None else cutoff_um
        return m.outer_batch(P, col, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active,
                             grid, h_deg, tol_um, rounds, cut)
    from sewtol.mechanisms.needle_208.kernels.window import outer_batch

    return outer_batch(P, col, lo, hi, blo, bhi, shift_lo_um, shift_hi_um, shift_active, grid,
                       h_deg, tol_um, rounds, cutoff_um)


def positions_serial(P, phi):
    """positions.positions_kernel_serial: E (n, m, 2) of n machines (rows of POSITION_FIELDS)
    at m crank angles, on this thread."""
    if (m := _IN_FORCE.get()) is not None:
        return m.positions_serial(P, phi)
    from sewtol.mechanisms.needle_208.kernels.positions import positions_kernel_serial

    return positions_kernel_serial(P, phi)


def build() -> Path:
    """Compile AHEAD from numba's kernels (their Python functions, serial) with numba.pycc
    into this folder unless the current module is there; stale ones are removed. For this
    machine's CPU (its name is in the module's), with the same bits as numba's kernels, also
    numba's for a generic CPU (tests/test_ahead.py, which CI repeats under
    NUMBA_CPU_NAME=generic). Returns its path."""
    import os
    import shutil
    import tempfile
    import warnings

    from numba.core.errors import NumbaPendingDeprecationWarning

    out, name = Path(__file__).parent, ahead_name()
    for old in out.glob("ahead_*"):
        if not old.name.startswith(name + "."):
            old.unlink()
    built = list(out.glob(name + ".*"))
    if built:
        return built[0]

    with warnings.catch_warnings():  # pycc is deprecated, not yet replaced; pinned by the lock
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        from numba.pycc import CC

        cc = CC(name, source_module=__name__)
    # for this machine's CPU, as numba's own kernels are compiled (a generic x86-64 build ran
    # the strategies study's kernels 10-20 % slower); llvmlite's name, not NUMBA_CPU_NAME's
    import llvmlite.binding as ll

    cc.target_cpu = ll.get_host_cpu_name()
    for name, (module, fn, sig) in AHEAD.items():
        kernel = getattr(importlib.import_module(f"{__name__}.{module}"), fn)
        cc.export(name, sig)(kernel.py_func)
    # compiled elsewhere and moved in whole (os.replace in this folder), so a build running
    # beside this one (make test and make report in one checkout) never loads a part-written
    # module
    with tempfile.TemporaryDirectory() as tmp:
        cc.output_dir = tmp
        cc.compile()
        part = out / f".{cc.output_file}.{os.getpid()}.part"
        shutil.copyfile(Path(tmp, cc.output_file), part)
        os.replace(part, out / cc.output_file)
    return out / cc.output_file
