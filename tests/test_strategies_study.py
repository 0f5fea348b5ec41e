"""THE strategies study (sewtol.studies.strategies) on any mechanism: `run NAME|FILE strategies`
agrees with `needle strategies` on the needle file, counts add up to n on a second mechanism,
and every row sees the same machines (the one sampler)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanism import load
from sewtol.mechanism.loader import loads
from sewtol.mechanism.spec import Spec
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
        # both in the needle's words (its Plugins.columns["strategies"])
        counts = ("ok", "out_of_spec", "cannot_assemble", "dead_point")
        assert [a[k] for k in counts] == [b[k] for k in counts], name
        assert a["yield"] == b["yield"] and a["n"] == 300
        assert a["p50_um"] == pytest.approx(b["p50_um"], abs=1e-3)
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


CRANK_SLIDER = Path(__file__).parent / "data" / "crank_slider.toml"


def _stepped_crank_slider():
    """crank_slider (no plug-ins: the generic optimiser) with its rod stepped: 39.85 + k 0.1
    up to 40.15 (the last step below the box's top, 40.2)."""
    text = CRANK_SLIDER.read_text().replace("low = 39.0\nhigh = 41.0",
                                            "low = 39.85\nhigh = 40.2\nstep = 0.1")
    return loads(text)


def test_the_row_figures_come_from_the_adjusted_batch():
    """Every figure of a row recomputed from the adjusted batch itself, on a file mechanism with
    a two-sided spec: counts (they add up to n), yield, quantiles (a failure ranks as +inf; the
    'higher' order statistic), Cpk by its formula (the nearer limit: the upper one binds as
    built, the lower one after the rod is set short), at-limit shares (the settings at an end of
    the box), achieved yield (no resolution: the yield) and the distinct settings of the
    stepped rod over the ok machines."""
    upper, lower, n = 50.0, 49.75, 200
    res = ST.strategies(_stepped_crank_slider(), "normal", n, 4, None, "J_x_max_mm",
                        Spec("J_x_max_mm", upper, lower))
    f = res.to_dataframe().set_index("strategy")
    assert list(f.index) == ["none", "rod"]
    binding = {}
    for name in f.index:
        r, y = f.loc[name], np.asarray(res.get(name).value, float)
        ok = (y >= lower) & (y <= upper)
        assert (r.ok, r.out_of_spec) == (ok.sum(), (np.isfinite(y) & ~ok).sum())
        assert r.ok + r.out_of_spec + r.cannot_close + r.dead_point == r.n == n
        assert r.failed == r.cannot_close + r.dead_point
        assert r["yield"] == ok.sum() / n and r.achieved_yield == r["yield"]
        x = np.sort(np.where(np.isfinite(y), y, np.inf))
        for q in (50, 95, 99):
            assert r[f"p{q}"] == x[int(np.ceil(q / 100 * (n - 1)))]
        m, s = y.mean(), y.std(ddof=1)
        assert r.Cpk == pytest.approx(min(upper - m, m - lower) / (3 * s), rel=1e-12)
        binding[name] = "upper" if upper - m < m - lower else "lower"
    assert binding == {"none": "upper", "rod": "lower"}
    rod = res.get("rod").settings["L"]
    at_end = np.isclose(rod, 39.85, atol=1e-9) | np.isclose(rod, 40.15, atol=1e-9)
    assert f.loc["rod", "at_limit_rod"] == f.loc["rod", "at_limit_share"] == at_end.mean() == 1
    assert f.loc["none", "at_limit_share"] == 0 and np.isnan(f.loc["none", "at_limit_rod"])
    ok = res.status("rod") == "ok"
    assert f.loc["rod", "distinct_settings"] == \
        f"rod {np.unique(np.round(rod[ok], 9)).size}" == "rod 1"


def test_run_strategies_prints_context_and_rows():
    """`run FILE strategies --format json`: one object, `context` (what decides the numbers:
    the run's keys plus the rows compared, the output and its spec) and `rows`."""
    code, out, err = run("run", str(CRANK_SLIDER), "strategies", "--n", "30", "--seed", "2",
                         "--output", "J_x_max_mm", "--limit", "50", "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert list(obj) == ["context", "rows"]
    ctx = obj["context"]
    assert (ctx["mechanism"], ctx["n"], ctx["seed"], ctx["output"], ctx["path"]) == \
        ("crank_slider", 30, 2, "J_x_max_mm", "generic")
    assert ctx["strategy"] == [r["strategy"] for r in obj["rows"]] == ["none", "rod"]
    assert ctx["spec"]["upper"] == 50.0 and ctx["spec"]["lower"] is None
    assert ctx["unit"] == "mm" and "yield_ci_method" in ctx
    for r in obj["rows"]:
        assert r["ok"] + r["out_of_spec"] + r["cannot_close"] + r["dead_point"] == r["n"] == 30
