"""The needle's kernels compiled ahead of time (needle_208/kernels/__init__.py, `make kernels`)
against numba's, bit for bit: the same Python functions, one serial and one parallel over the
machines, so every figure a short `needle montecarlo` and a worker of `needle strategies`
print is the one numba's kernels give."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import adjust as ad
from sewtol.mechanisms.needle_208 import kernels
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.tolerances import NEEDLE_208_SETS

# CI (SEWTOL_REQUIRE_AHEAD=1, .ci/run) fails here instead: there the build must have worked
if os.environ.get("SEWTOL_REQUIRE_AHEAD") == "1" and kernels.ahead() is None:
    raise AssertionError("SEWTOL_REQUIRE_AHEAD=1 but the kernels compiled ahead of time are not "
                         "built from these sources (make kernels)")
pytestmark = pytest.mark.skipif(kernels.ahead() is None, reason="the kernels compiled ahead of "
                                "time are not built from these sources (make kernels)")


@pytest.fixture(scope="module", params=["base", "recommended"])
def chunk(request):
    """2000 machines of a set (the base set's include machines that cannot run), as the
    kernels take them: P, beta, the rocker interval (NaN where a machine cannot run)."""
    n = 2000
    dev = NEEDLE_208_SETS[request.param].sample(np.random.default_rng(25), n)
    c, _ = nm.columns(P.with_deviations(Needle208.nominal(), dev))
    c = {k: np.broadcast_to(v, (n, 1)).copy() for k, v in c.items()}
    r_lo, r_hi, _ = ad._rocker(c, nm.feasibility(c))
    return kernels.pack(c), c["beta"][:, 0].copy(), r_lo, r_hi


def both(fn, *args):
    """fn(*args) compiled ahead of time and by numba."""
    with kernels.ahead_of_time() as ahead:
        assert ahead
        a = fn(*args)
    with kernels.ahead_of_time(False) as ahead:
        assert not ahead
        b = fn(*args)
    return a, b


def test_fixed_figures_are_numbas_bit_for_bit(chunk):
    Pm, beta, r_lo, r_hi = chunk
    a, b = both(kernels.fixed_batch, Pm, beta, r_lo, r_hi)
    assert np.isfinite(a).all(axis=1).sum() >= 1900
    assert np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("shift", [False, True])
def test_optimum_is_numbas_bit_for_bit(chunk, shift):
    Pm, _, r_lo, r_hi = chunk
    a, b = both(kernels.optimise_batch, Pm, r_lo, r_hi, 10.0, 35.0, -100.0, 100.0, shift, 2.0,
                1e-3)
    assert (a[:, 9] == 0).sum() >= 1900  # status ok: the optimum was searched
    assert np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("name, col, box, n_grid",
                         [("guide_angle", 13, (-0.1, 0.1), 21), ("CD", 3, (-0.3, 0.3), 61)])
def test_outer_search_is_numbas_bit_for_bit(chunk, name, col, box, n_grid):
    """window.outer_batch as the guide angle's and CD's outer searches call it (beta and the
    shift inside; 400 machines a case), without a cutoff and with one: 0 um on every other
    machine (no setting reaches it: the grid's best, not refined), +inf on the others (the
    compiled module takes the cutoff as an array; +inf is numba's None)."""
    Pm, _, r_lo, r_hi = (a[:400] for a in chunk)
    Pm = np.ascontiguousarray(Pm)
    args = (Pm, col, r_lo.copy(), r_hi.copy(), 10.0, 35.0, -100.0, 100.0, True,
            np.linspace(*box, n_grid), 2.0, 1e-3, 3)
    a, b = both(kernels.outer_batch, *args, None)
    assert np.isfinite(a).sum() >= 380 and np.unique(a).size > 100  # searched, not one value
    assert np.array_equal(a, b, equal_nan=True)
    even = np.arange(len(Pm)) % 2 == 0
    a_cut, b_cut = both(kernels.outer_batch, *args, np.where(even, 0.0, np.inf))
    assert np.array_equal(a_cut[~even], a[~even], equal_nan=True)
    changed = (a_cut[even] != a[even]).sum()  # grid points, not refined: the guide angle's
    assert changed >= 100 if name == "guide_angle" else changed == 0  # (CD's takes none)
    assert np.array_equal(a_cut, b_cut, equal_nan=True)


def test_cd_and_angle_search_is_numbas_bit_for_bit(chunk):
    """window.cd_angle_batch as the `all` strategy's first stage calls it (adjust.cd_and_angle;
    100 machines a set): CD's offset, SumDelta and the guide angle's offset."""
    Pm, _, r_lo, r_hi = (a[:100] for a in chunk)
    a, b = both(kernels.cd_angle_batch, np.ascontiguousarray(Pm), r_lo.copy(), r_hi.copy(), 10.0,
                35.0, -100.0, 100.0, True, np.linspace(-0.3, 0.3, 13), -0.1, 0.1, 21, 2.0, 1e-3,
                3e-6, 2e-7)
    assert np.isfinite(a[:, 1]).sum() >= 90 and np.unique(a[:, 0]).size > 50
    assert np.array_equal(a, b, equal_nan=True)


def test_positions_are_numbas_bit_for_bit():
    """positions.positions_kernel_serial (the measured adjuster's readings) on 2000 machines
    of the base set at 24 crank angles and one whose rod BC is too short to close (NaN)."""
    from sewtol.mechanisms.needle_208.kernels import positions

    assert kernels.POSITION_FIELDS == positions.FIELDS  # what the measured adjuster packs
    dev = NEEDLE_208_SETS["base"].sample(np.random.default_rng(25), 2000)
    Pm = positions.pack(P.with_deviations(Needle208.nominal(), dev))
    Pm = np.vstack([Pm, Pm[:1]])
    Pm[-1, kernels.POSITION_FIELDS.index("BC")] = 1e-3
    phi = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    a, b = both(kernels.positions_serial, Pm, phi)
    assert np.isfinite(a[:-1]).all() and np.isnan(a[-1]).all()
    assert np.array_equal(a, b, equal_nan=True)


def test_a_thread_started_inside_runs_numbas_kernels():
    """ahead_of_time holds on its own thread only: a pool's worker started inside it runs
    numba's (parallel) kernels."""
    from concurrent.futures import ThreadPoolExecutor

    with kernels.ahead_of_time(), ThreadPoolExecutor(1) as pool:
        assert pool.submit(kernels._IN_FORCE.get).result() is None
        assert kernels._IN_FORCE.get() is kernels.ahead()


@pytest.mark.parametrize("fmt", ["json", "table"])
def test_needle_montecarlo_prints_the_same_bytes_on_both(capsys, monkeypatch, fmt):
    """`needle montecarlo --n 1000` (the compiled kernels, serially) and the same run with the
    module hidden (numba's kernels, in parallel) print the same bytes."""
    from sewtol.cli import main

    argv = ["needle", "montecarlo", "--n", "1000", "--format", fmt]
    assert main(argv) == 0
    ahead = capsys.readouterr().out
    monkeypatch.setattr(kernels, "ahead", lambda: None)
    assert main(argv) == 0
    assert capsys.readouterr().out == ahead


def test_short_needle_strategies_prints_the_same_bytes_on_both(capsys, monkeypatch):
    """`needle strategies --n 40` (one process: the compiled kernels, `kernels.runs_ahead`)
    and the same run with the module hidden (numba's kernels) print the same bytes."""
    from sewtol.cli import main

    assert kernels.runs_ahead("strategies", 40) and not kernels.runs_ahead("strategies", 61)
    argv = ["needle", "strategies", "--n", "40", "--format", "json"]
    assert main(argv) == 0
    ahead = capsys.readouterr().out
    monkeypatch.setattr(kernels, "ahead", lambda: None)
    assert main(argv) == 0
    assert capsys.readouterr().out == ahead


def test_a_strategies_worker_never_imports_numba():
    """A chunk of `needle strategies` as a worker process runs it (`_drawn_chunk`, one thread:
    the mechanism's kernels compiled ahead of time), in a fresh process: every default row,
    the guide angle's setting error and a measured row (the readings' position kernel), and
    numba and llvmlite are never imported."""
    code = textwrap.dedent("""
        import sys
        import numpy as np
        from sewtol.measurement_error import MeasurementError
        from sewtol.mechanisms.needle_208.compensators import default_strategies
        from sewtol.protocol import input_law
        from sewtol.studies.strategies import _drawn_chunk
        from sewtol.mechanisms.needle_208.model import Needle208
        from sewtol.tables.needle_208 import as_mechanism
        from sewtol.tolerances import NEEDLE_208_SETS
        mech = as_mechanism(Needle208.nominal())
        dev = input_law(mech, NEEDLE_208_SETS["recommended"]).draw(40, 7)
        rows = default_strategies()
        out = _drawn_chunk(mech, dev, rows, "SumDelta_um", True, {"limit_um": 10.0}, 1, 7,
                           (0, 40))
        angle = [r for r in rows if r.name == "beta+shift+angle"]  # the all row read: 11 CPU-s
        measured = _drawn_chunk(mech, dev, angle, "SumDelta_um", True, {"limit_um": 10.0}, 1, 7,
                                (0, 40), MeasurementError(1.0, 12))
        assert len(out) == len(rows) and all(np.isfinite(a.value).sum() >= 30 for a in out)
        assert np.isfinite(measured[0].value).sum() >= 30
        print(sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "llvmlite")))
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"
