"""One sampler: for one seed and one tolerance set, Monte-Carlo, strategies, ppm by plain
Monte-Carlo and allocation draw the same machines (studies.montecarlo.draw_deviations)."""

from dataclasses import replace
from pathlib import Path

import numpy as np

from sewtol.mechanism import load
from sewtol.mechanisms.needle_208 import compensators as C
from sewtol.studies import allocation as AL
from sewtol.studies import montecarlo as mc
from sewtol.studies import rare_event as PPM
from sewtol.studies import rare_event as R
from sewtol.tables.needle_208 import (
    allocate,
    montecarlo,
    needle_limit_state,
    strategies_table,
)
from sewtol.tolerances import NEEDLE_208_SETS

FILE = str(Path(__file__).parent / "data" / "crank_slider.toml")
N, SEED = 620, 11  # two chunks of CHUNK machines, the second partial


def _ppm_machines(ls):
    """The deviations a plain Monte-Carlo ppm evaluates (the response records its z)."""
    seen = []

    def response(z):
        seen.append(np.array(z))
        return ls.response(z)

    R.monte_carlo(replace(ls, response=response), N, np.random.default_rng(SEED),
                  chunk_size=200)
    return ls.to_physical(np.concatenate(seen))


def _same(a: dict, b: dict, rtol=0.0):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float), rtol=rtol,
                                   atol=0.0, err_msg=k)


def test_window_of_the_streams_draws_the_same_uniforms():
    s = mc.unit_streams(SEED, 1234)
    whole = mc.draw_units(s, 3, 0, 1234)
    for a, b in ((0, 1234), (480, 1100), (1000, 1234), (7, 8)):
        np.testing.assert_array_equal(mc.draw_units(*_window(s, a, b)), whole[a:b])
    # a Generator gives the streams of its seed (rare_event passes default_rng(seed))
    np.testing.assert_array_equal(
        mc.draw_units(mc.unit_streams(np.random.default_rng(SEED), 1234), 3, 0, 1234), whole)


def _window(s, a, b):
    streams, lo, hi = mc.stream_window(s, a, b)
    return streams, 3, lo, hi


def test_needle_studies_draw_the_same_machines(nominal, monkeypatch):
    tol = NEEDLE_208_SETS["recommended"]
    want = mc.draw_deviations(tol, N, SEED)
    assert len(want["LF"]) == N
    # Monte-Carlo, for any evaluation chunk size
    for chunk in (mc.CHUNK, 150):
        m = montecarlo(nominal, tol, N, SEED, chunk_size=chunk).machines
        _same({k: m[k] for k in want}, want)
    # strategies
    s = strategies_table(nominal, tol, N, SEED, strategies=[C.strategy_of(("beta",))])
    _same({k: s.deviations[k] for k in want}, want)
    # ppm by plain Monte-Carlo: z = Phi^-1(u) and back, equal to the last bits
    _same(_ppm_machines(needle_limit_state(nominal, tol, adjust="none")), want, rtol=1e-12)
    # allocation: its last trial (the scale it reports) evaluates montecarlo's machines of the
    # allocated set
    calls = _recording(monkeypatch)
    a = allocate(nominal, tol, target=0.9, n=N, seed=SEED, steps=3)
    _one_trial_draws(calls, mc.draw_deviations(a.as_tolerance_set(), N, SEED))


def test_file_studies_draw_the_same_machines(monkeypatch):
    mech = load(FILE)
    tol = mech.tolerance_sets["normal"]
    want = mc.draw_deviations(tol, N, SEED)
    m = mc.montecarlo(mech, tol, N, SEED).machines
    _same({k: m[k] for k in want}, want)
    _same(_ppm_machines(PPM.limit_state(mech, tol, "stroke_mm", upper=20.02)), want,
          rtol=1e-12)
    calls = _recording(monkeypatch)
    a = AL.allocate(mech, tol, "stroke_mm", 0.9, upper=20.02, lower=19.98, n=N, seed=SEED)
    _one_trial_draws(calls, mc.draw_deviations(a.as_tolerance_set(), N, SEED))


def _recording(monkeypatch) -> list:
    """The deviations of every trial of studies.allocation (its machines)."""
    calls = []
    real = AL.machines

    def recording(mech_, dev):
        calls.append(dev)
        return real(mech_, dev)

    monkeypatch.setattr(AL, "machines", recording)
    return calls


def _one_trial_draws(calls, allocated):
    # one trial is at the reported scale: montecarlo's machines of the allocated set
    assert sum(all(np.allclose(d[k], v, rtol=1e-12, atol=0.0) for k, v in allocated.items())
               for d in calls) >= 1
