"""The study stack on the mechanism protocol: one adjustment dispatch (plug-in or generic), the
scan, the worst case, the largest tolerances and the settings comparison of any mechanism."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_helpers import run, strict_loads
from sewtol import Needle208, adjuster
from sewtol.errors import ParameterError
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file
from sewtol.mechanisms.needle_208 import fast_path as FP
from sewtol.mechanisms.needle_208.adjust import PLATEAU_TOL_UM
from sewtol.mechanisms.needle_208.compensators import strategy_of
from sewtol.studies import generic as G
from sewtol.studies import scan as S
from sewtol.studies import settings as ST
from sewtol.studies import worst_case as W
from sewtol.studies.adjusting import adjusted, evaluated
from sewtol.tables import needle_208 as T
from sewtol.tolerances import NEEDLE_208_SETS


@pytest.fixture(scope="module")
def needle():
    return load(mechanism_file("needle_208"))


@pytest.fixture(scope="module")
def khujand():
    return load(mechanism_file("khujand_feed"))


def _corners(mech, n=4):
    nom = mech.nominal_values()
    rng = np.random.default_rng(7)
    return {k: nom[k] + rng.uniform(-0.05, 0.05, n) for k in ("LF", "AB", "BE", "CD")}


def test_the_dispatch_takes_the_exact_plug_in_and_never_loses_to_the_generic_adjuster(needle):
    vals = _corners(needle)
    fast = adjusted(needle, vals, ["beta"], "SumDelta_um")
    slow = adjusted(needle, vals, ["beta"], "SumDelta_um", fast=False)
    assert (fast.path, slow.path) == ("needle_208", "generic")
    # the plug-in is the global optimum (its plateau centre within PLATEAU_TOL_UM of it); the
    # generic one samples 720 crank angles, which can only lower SumDelta by the kernel bound
    bound = FP.needle_kernel_bound(needle, {**vals, "beta": fast.settings["beta"]})["SumDelta_um"]
    assert np.all(fast.value <= slow.value + bound + PLATEAU_TOL_UM)
    assert np.all(np.abs(fast.value - slow.value) < 0.05)
    assert fast.extras["total_um"] == pytest.approx(fast.extras["plus_um"]
                                                    + fast.extras["minus_um"], abs=1e-12)
    # the generic branch is exactly sewtol.adjuster.adjust
    ref = adjuster.adjust(needle, vals, "SumDelta_um", ["beta"])
    np.testing.assert_array_equal(slow.value, ref.value)
    np.testing.assert_array_equal(slow.settings["beta"], ref.settings["beta"])


def test_the_dispatch_refuses_what_no_adjuster_takes(needle, khujand):
    with pytest.raises(ParameterError, match="generic adjuster sets compensators of the file"):
        adjusted(needle, None, {"beta": (10, 35), "CD": (29, 31)}, "SumDelta_um", fast=False)
    with pytest.raises(ParameterError, match="takes the file's boxes"):
        adjusted(needle, None, {"beta": (12, 30)}, "SumDelta_um", fast=False)
    with pytest.raises(ParameterError, match="must name a compensator of the file"):
        adjusted(khujand, None, ["beta"], khujand.output_names[0])


def test_a_strategy_goes_to_the_strategy_plug_in_with_its_status_words(needle):
    vals = _corners(needle)
    a = adjusted(needle, vals, strategy_of(("beta", "guide_shift_um")), "SumDelta_um",
                 limit_um=1e-6)
    assert set(a.status) == {"out of spec"}  # nothing keeps 1e-6 um
    b = adjusted(needle, vals, {"beta": (10.0, 35.0), "guide_shift_um": (-100.0, 100.0)},
                 "SumDelta_um")
    np.testing.assert_allclose(a.value, b.extras["total_um"], atol=2 * PLATEAU_TOL_UM)


def test_the_kernel_evaluation_agrees_with_the_generic_within_its_bound(needle):
    vals = _corners(needle)
    fast, slow = evaluated(needle, vals, "SumDelta_um"), evaluated(needle, vals, "SumDelta_um",
                                                                   fast=False)
    bound = FP.needle_kernel_bound(needle, vals)["SumDelta_um"]
    assert np.all(np.abs(fast - slow) <= bound) and np.all(slow <= fast + 1e-9)


def test_needle_tables_are_the_generic_studies_on_the_needle_as_a_mechanism(needle):
    nominal = Needle208.nominal()
    mech = T.as_mechanism(nominal)
    assert mech.nominal_values()["beta"] == nominal.beta and mech.header.fast_path == "needle_208"
    sc = T.scan(nominal, "base")
    rows = S.scan(mech, NEEDLE_208_SETS["base"], ["SumDelta_um"], {"beta": (10.0, 35.0)}).rows
    adj = rows[rows["output"] == "SumDelta_um_adjusted"].reset_index(drop=True)
    np.testing.assert_array_equal(adj["setting"], sc.rows["beta_deg"])
    wc = W.worst_case(mech, NEEDLE_208_SETS["base"], "SumDelta_um", extremes=("max",),
                      search=W.Search(starts=3, maxiter=200, step=None, failures="worst"),
                      axes=False)
    assert wc.rows["value"][0] == T.worst_case(nominal, "base", adjust=False)["total_um"]


def test_worst_case_bounds_every_corner_and_counts_failures_as_the_policy_says(khujand):
    ts = khujand.tolerance_sets["illustrative"]
    out = khujand.output_names[0]
    r = W.worst_case(khujand, ts, out, axes=False)
    top = r.rows.set_index("extreme")
    assert top.loc["max", "value"] >= top.loc["max", "corner_value"]
    assert top.loc["min", "value"] <= top.loc["min", "corner_value"]
    # a box so wide some machines cannot close: left out (counted) or the worst value
    wide = ts.scaled(dict.fromkeys(("Dx", "Dy", "Hx", "Hy"), 50.0))  # frame pivots +-5 mm
    skip = W.worst_case(khujand, wide, out, extremes=("max",), axes=False, maxiter=5)
    assert skip.failed_corners == 256 and np.isfinite(skip.rows["value"][0])
    worst = W.worst_case(khujand, wide, out, extremes=("max",), axes=False,
                         search=W.Search(maxiter=5, failures="worst"))
    assert worst.rows["value"][0] == np.inf


def test_largest_tolerances_sits_on_the_limit(khujand):
    out = "E_x_range_mm" if "E_x_range_mm" in khujand.output_names else khujand.output_names[0]
    nominal = G.nominal(khujand).rows.set_index("output")["value"][out]
    limit = nominal + 0.01
    t = S.largest_tolerances(khujand, ["AB", "CD"], out, limit, xtol=1e-9)
    for r in t.itertuples():
        if r.reaches_max:
            continue
        at = evaluated(khujand, {r.param: np.array([khujand.nominal_values()[r.param]
                                                      + r.largest_deviation])}, out)[0]
        assert at == pytest.approx(limit, abs=1e-6)


def test_settings_rows_are_the_nominal_figures_of_each_setting(khujand):
    nom = khujand.nominal_values()
    res = ST.compare(khujand, [ST.Setting("as drawn", {}),
                               ST.Setting("long AB", {"AB": nom["AB"] + 0.1}, {"dAB_mm": 0.1})])
    rows = res.to_dataframe().set_index("setting")
    base = G.nominal(khujand).rows.set_index("output")["value"]
    moved = G.nominal(khujand.override(AB=nom["AB"] + 0.1)).rows.set_index("output")["value"]
    for o in khujand.output_names:
        assert rows.loc["as drawn", o] == base[o] and rows.loc["long AB", o] == moved[o]
    assert rows.loc["long AB", "dAB_mm"] == 0.1 and pd.isna(rows.loc["as drawn", "dAB_mm"])
    far = ST.compare(khujand, [ST.Setting("no crank turn", {"AB": 40.0})]).rows.iloc[0]
    assert far["status"] == "cannot_close" and far["failed_group"] != ""
    assert all(np.isnan(far[o]) for o in khujand.output_names)
    with pytest.raises(ParameterError, match="distinct names"):
        ST.compare(khujand, [ST.Setting("a"), ST.Setting("a")])
    with pytest.raises(ParameterError, match="unknown parameter"):
        ST.compare(khujand, [ST.Setting("a", {"nope": 1.0})])


def test_run_settings_prints_one_row_per_setting_and_refuses_bad_ones_in_one_line(khujand):
    code, out, err = run("run", "khujand_feed", "settings", "--set", "drawn:AB=4",
                         "--set", "long AB:AB=4.1,CD=20.2", "--set", "BC=45.5", "--format", "json")
    assert code == 0, err
    rows = {r["setting"]: r for r in strict_loads(out)["rows"]}
    for name, changes in (("drawn", {"AB": 4.0}), ("long AB", {"AB": 4.1, "CD": 20.2})):
        ref = khujand.override(BC=45.5, **changes).evaluate()
        assert rows[name]["status"] == "ok"
        for o in khujand.output_names:
            assert rows[name][o] == float(ref.outputs[o][0])
    for args, msg in ((["--set", "AB=4"], "needs at least one SETTING:NAME=VALUE"),
                      (["--set", "a:AB=x"], "AB: must be a number"),
                      (["--set", "a:AB=4", "--method", "mc"],
                       "--method: is not used by `run settings`"),
                      (["--set", "a:AB=4", "--n", "1"], "--n: must be >= 2"),
                      (["--set", "a:AB=4", "--n", "5", "--adjust", "nope"],
                       "--adjust: must name compensators")):
        code, out, err = run("run", "khujand_feed", "settings", *args)
        assert code == 2 and out == "" and msg in err and len(err.strip().splitlines()) == 1


SLIDER = str(Path(__file__).parent / "data" / "crank_slider.toml")


def test_settings_yields_are_a_monte_carlo_by_hand_on_the_same_machines():
    """The crank-slider (J_x_max = L + r): per setting the same deviations added to its own
    nominals, J_x_max <= 49.02 counted as built and with the rod L set per machine; the rod's
    optimum by brute force over a dense grid of its box [39, 41] (the minimum 39 + r)."""
    from sewtol.mechanism.spec import Spec
    from sewtol.studies.montecarlo import draw_deviations

    mech, n, seed, limit = load(SLIDER), 300, 5, 49.02
    tol = mech.tolerance_sets["uniform"]
    settings = [ST.Setting("as drawn"), ST.Setting("long rod", {"L": 40.05}),
                ST.Setting("big crank", {"r": 10.012})]
    rows = ST.compare(mech, settings, ST.yield_figures(
        tol, n, seed, {"fixed": (), "adjusted": ("rod",)}, "J_x_max_mm",
        Spec("J_x_max_mm", limit))).to_dataframe().set_index("setting")
    dev = draw_deviations(tol, n, seed)  # montecarlo's machines for this seed
    grid = np.linspace(39.0, 41.0, 401)
    for s in settings:
        m = mech.override(**s.values)
        vals = {p: m.nominal_values()[p] + dev[p] for p in dev}
        fixed = m.evaluate(vals, ["J_x_max_mm"]).outputs["J_x_max_mm"]
        brute = np.min([m.evaluate({**vals, "L": np.full(n, x)}, ["J_x_max_mm"])
                        .outputs["J_x_max_mm"] for x in grid], axis=0)
        row = rows.loc[s.name]
        for case, y in (("fixed", fixed), ("adjusted", brute)):
            ok = int(np.sum(y <= limit))
            assert row[f"ok_{case}"] == ok and row[f"yield_{case}"] == ok / n
            assert row[f"ok_{case}"] + row[f"out_of_spec_{case}"] + row[f"cannot_close_{case}"] \
                + row[f"dead_point_{case}"] == n
            assert row[f"p95_{case}"] == pytest.approx(
                np.quantile(y, 0.95, method="higher"), abs=1e-6)
    # the settings move the counts (r's +12 um is 40 % of its tolerance), the machines do not
    assert rows.loc["big crank", "ok_adjusted"] < rows.loc["as drawn", "ok_adjusted"] < n
    assert rows.loc["long rod", "ok_adjusted"] == rows.loc["as drawn", "ok_adjusted"]
    # the CLI prints the same rows
    code, out, err = run("run", SLIDER, "settings", "--set", "as drawn:r=10",
                         "--set", "big crank:r=10.012", "--tolerances", "uniform", "--n",
                         str(n), "--seed", str(seed), "--output", "J_x_max_mm", "--limit",
                         str(limit), "--adjust", "rod", "--format", "json")
    assert code == 0, err
    got = {r["setting"]: r for r in strict_loads(out)["rows"]}
    for name in ("as drawn", "big crank"):
        for k in ("ok_fixed", "ok_adjusted", "out_of_spec_adjusted", "n"):
            assert got[name][k] == rows.loc[name, k]


def test_the_monte_carlo_holds_a_compensator_at_the_nominal_machines_optimum(needle):
    """hold="optimum": the fixed case's beta is the nominal machine's beta* (exactly what
    `needle nominal` prints, here with the guide shifted 50 um), every machine's fixed SumDelta
    is the kernel's at that beta, and the plug-in names every failure (counts add up to n)."""
    from sewtol.mechanisms.needle_208.single import nominal_figures
    from sewtol.protocol import machines
    from sewtol.studies import montecarlo as MC

    mech = needle.override(guide_shift_um=50.0)
    star = nominal_figures(Needle208.nominal().override(guide_shift_um=50.0)).beta_opt_deg
    assert star == pytest.approx(27.6817036, abs=1e-7)  # not the file's 22.58 deg
    r = MC.montecarlo(mech, NEEDLE_208_SETS["recommended"], 64, 5, ["SumDelta_um"], 10.0,
                      adjust={"beta": (10.0, 35.0)}, fast=True, hold="optimum")
    assert r.held["beta"] == star
    dev = {p: r.machines[p].to_numpy() for p in r.params}
    fixed = FP.needle_kernel(mech.override(beta=star), machines(mech, dev))["SumDelta_um"]
    np.testing.assert_array_equal(np.asarray(r.values("SumDelta_um")), fixed)
    assert "total_fixed_um" in r.machines and "fail_dyad_adjusted" in r.machines
    for case in r.cases():
        c = r.counts(case)
        assert c["ok"] + c["out_of_spec"] + c["failed"] == 64
    kept = MC.montecarlo(mech, NEEDLE_208_SETS["recommended"], 2, 5, ["SumDelta_um"], 10.0,
                         adjust={"beta": (10.0, 35.0)}, fast=True)
    assert kept.held["beta"] == mech.nominal_values()["beta"]
    with pytest.raises(ParameterError, match="hold"):
        MC.montecarlo(mech, NEEDLE_208_SETS["recommended"], 2, 5, hold="best")


def test_nothing_to_set_gives_the_machine_as_built_whatever_the_objective(needle):
    """A settings case with no compensators under a two-sided spec (objective centre): the
    plug-in's machine as built, as under the default objective."""
    vals = _corners(needle)
    built = adjusted(needle, vals, (), "SumDelta_um")
    centred = adjusted(needle, vals, (), "SumDelta_um", objective="centre=1,10")
    np.testing.assert_array_equal(centred.value, built.value)
    assert list(centred.status) == list(built.status) and centred.path == built.path
