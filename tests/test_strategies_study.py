"""THE strategies study (sewtol.studies.strategies) on any mechanism: `run NAME|FILE strategies`
agrees with `needle strategies` on the needle file, counts add up to n on a second mechanism,
and every row sees the same machines (the one sampler)."""

from __future__ import annotations

import numpy as np
import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file
from sewtol.studies import strategies as ST


@pytest.fixture(scope="module")
def needle_file():
    """The needle file: it declares the guide shift (+/-100 um about the nominal 0, the needle's
    built-in guide_shift_um compensator) as its second compensator."""
    path = mechanism_file("needle_208")
    g = load(path).compensators["guide_shift"]
    assert (g.parameter, g.low, g.high) == ("guide_shift_um", -100.0, 100.0)
    return path


def test_run_file_strategies_equals_needle_strategies_counts(needle_file):
    """beta and beta+guide_shift on the same 300 machines of seed 5: `run FILE strategies`
    (the file's exact plug-in over boxes) and `needle strategies` (needle_208.adjustment over
    the built-in compensators) count the same ok, out of spec and failed machines."""
    code, out, err = run("run", str(needle_file), "strategies", "--n", "300", "--seed", "5",
                         "--strategy", "beta=beta", "--strategy", "beta+shift=beta,guide_shift",
                         "--format", "json")
    assert code == 0, err
    rows = {r["strategy"]: r for r in strict_loads(out)["rows"]}
    code, out, err = run("needle", "strategies", "--n", "300", "--seed", "5", "--format", "json")
    assert code == 0, err
    needle = {r["strategy"]: r for r in strict_loads(out)["rows"]}
    for name in ("beta", "beta+shift"):
        a, b = rows[name], needle[name]
        assert (a["ok"], a["out_of_spec"], a["failed"]) == \
            (b["ok"], b["out_of_spec"], b["cannot_assemble"] + b["dead_point"]), name
        assert a["yield"] == b["yield"] and a["n"] == 300
        assert a["p50"] == pytest.approx(b["p50_um"], abs=1e-3)
    assert rows["beta+shift"]["ok"] > rows["beta"]["ok"]  # a second compensator only helps


def test_strategies_on_a_second_mechanism_count_every_machine():
    """feed_131 (no plug-ins: the generic optimiser): none and b alone over the same machines;
    ok + out_of_spec + failed = n, the 'none' row is the plain Monte-Carlo evaluation, and the
    adjusted output is never above the as-built one (b's nominal lies in its box)."""
    mech = load(mechanism_file("feed_131"))
    out = mech.output_names[0]
    res = ST.strategies(mech, "links", 24, 11, None, out)
    assert res.names == ("none", "b")
    f = res.to_dataframe()
    assert (f["ok"] + f["out_of_spec"] + f["failed"] == 24).all()
    law_machines = mech.evaluate({k: mech.nominal_values()[k] + v
                                  for k, v in res.deviations.items()}, [out]).outputs[out]
    np.testing.assert_array_equal(res.get("none").value, law_machines)
    assert np.all(res.get("b").value <= res.get("none").value + 1e-9)
    assert res.get("b").path == "generic"


def test_a_bad_strategy_is_refused_naming_it():
    code, _, err = run("run", "feed_131", "strategies", "--n", "4", "--strategy", "x=b,nope")
    assert code != 0 and "--strategy" in err and "nope" in err
    code, _, err = run("run", "feed_131", "strategies", "--n", "4", "--adjust", "b")
    assert code != 0 and "--adjust" in err
