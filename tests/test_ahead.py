"""The needle's kernels compiled ahead of time (needle_208/kernels/__init__.py, `make kernels`)
against numba's, bit for bit: the same Python functions, one serial and one parallel over the
machines, so every figure a short `needle montecarlo` prints is the one numba's kernels give."""

import os

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
