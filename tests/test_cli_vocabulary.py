"""Issue 14 items 1, 3-7: one flag vocabulary, at-bound optima flagged, labelled contracts,
second-order Sobol indices (Ishigami), tolerances refused at load."""

import argparse
import io
import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from cli_helpers import run, strict_loads
from sewtol.cli import resolve_progress
from sewtol.errors import ParameterError
from sewtol.studies.sobol import case_indices, sample
from sewtol.tables.needle_208 import montecarlo
from sewtol.tolerances import NEEDLE_208_SETS, Tolerance, ToleranceSet, load_toml


def nominal_json(*extra):
    code, out, err = run("needle", "nominal", "--format", "json", *extra)
    assert code == 0, err
    return strict_loads(out)


def test_nominal_flags_an_optimum_on_a_bound_in_json_table_and_text():
    free = nominal_json()
    assert free["beta_at_bound"] is False and free["notes"] == []
    assert free["window_clipped"] == {"low": False, "high": False}
    assert 10.0 < free["window_deg"][0] < free["beta_opt_deg"] < free["window_deg"][1] < 35.0
    assert free["beta_search_range_deg"] == [10.0, 35.0]
    # CD + 0.3 mm: SumDelta falls all the way to the end of the regulating range
    cd = nominal_json("--set", "CD=30.3")
    assert cd["beta_at_bound"] is True and abs(cd["beta_opt_deg"] - 35.0) < 1e-3
    assert "the optimum reaches the bound 35 deg" in cd["notes"][0]
    code, text, _ = run("needle", "nominal", "--set", "CD=30.3")
    assert code == 0 and "note: beta* = 34.9999 deg: the optimum reaches the bound 35 deg" in text
    assert "| beta* on a bound of the searched range (1 = yes)     |   1.0000 |" in text
    # a window narrower than the optimum's: beta* at 23 (free: 22.58), both window ends clipped
    narrow = nominal_json("--beta-range", "23", "24")
    assert narrow["beta_at_bound"] is True and abs(narrow["beta_opt_deg"] - 23.0) < 1e-3
    assert narrow["window_deg"] == [23.0, 24.0]
    assert narrow["window_clipped"] == {"low": True, "high": True}
    assert len(narrow["notes"]) == 3
    # a range that holds beta* but cuts the window: only the window's low end is flagged
    cut = nominal_json("--beta-range", "22", "30")
    assert cut["beta_at_bound"] is False
    # (beta* is the centre of a flat plateau about 0.002 deg wide)
    assert abs(cut["beta_opt_deg"] - free["beta_opt_deg"]) < 1e-3
    assert cut["window_clipped"] == {"low": True, "high": False}
    assert cut["window_deg"][1] == pytest.approx(free["window_deg"][1], abs=1e-6)


def test_scan_flags_rows_at_the_bound_and_keeps_the_guide_shift():
    code, out, _ = run("needle", "scan", "--format", "json", "--beta-range", "22", "23")
    rows = {(r["param"], r["side"]): r for r in strict_loads(out)["rows"]}
    # LM +/-0.5 mm moves beta* out of [22, 23] (to 20.68 / 24.42 in [10, 35]): on the bound
    assert rows[("LM", "upper")]["beta_at_bound"] and rows[("LM", "lower")]["beta_at_bound"]
    assert abs(rows[("LM", "upper")]["beta_deg"] - 22.0) < 1e-3
    assert abs(rows[("LM", "lower")]["beta_deg"] - 23.0) < 1e-3
    # LF and AM keep beta* inside; AB/BC/BE: SumDelta flat up to a bound, flagged as well
    for key in (("LF", "upper"), ("LF", "lower"), ("AM", "upper"), ("AM", "lower")):
        assert not rows[key]["beta_at_bound"] and 22.001 < rows[key]["beta_deg"] < 22.999
    assert sum(r["beta_at_bound"] for r in rows.values()) == 8
    code, text, _ = run("needle", "scan", "--beta-range", "22", "23")
    assert "note: 8 of 12 rows have beta* on a bound" in text
    # in words: LM's optimum is pinned at an end (SumDelta still falling), BC upper and BE
    # lower are flat over the whole range, BE upper a plateau running into its lower end
    assert ("note: LM upper: SumDelta 7.1094 um for beta 22.0000 ... 22.0005 deg, pinned at "
            "the range's end 22 deg") in text
    assert "BC upper: SumDelta 12.5502 um for beta 22.0000 ... 23.0000 deg, the whole" in text
    assert "BE lower: SumDelta 52.2090 um for beta 22.0000 ... 23.0000 deg, the whole" in text
    assert ("BE upper: SumDelta 51.8111 um for beta 22.0000 ... 22.4972 deg, a flat plateau "
            "reaching the range's end 22 deg") in text
    # --set guide_shift_um reaches the scan (it used to be reset to 0 by the scan's default)
    _, shifted, _ = run("needle", "scan", "--format", "json", "--set", "guide_shift_um=20")
    _, flag, _ = run("needle", "scan", "--format", "json", "--guide-shift-um", "20")
    _, plain, _ = run("needle", "scan", "--format", "json")
    assert shifted == flag and shifted != plain
    assert nominal_json("--guide-shift-um", "20") == nominal_json("--set", "guide_shift_um=20")


@pytest.fixture(scope="module")
def mc_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc") / "o"
    code, text, err = run("needle", "montecarlo", "--n", "300", "--seed", "4", "--format",
                          "json", "--out", str(out), "--beta-range", "15", "30",
                          "--limit-um", "20")
    assert code == 0, err
    return strict_loads(text), out


def test_montecarlo_json_labels_every_interval_and_capability(mc_out):
    d, out = mc_out
    m = pd.read_csv(out / "machines.csv")  # plain CSV: its context is run.json beside it
    assert [c for c in m.columns if c.startswith("dev_")] == [
        "dev_LF_mm", "dev_LM_mm", "dev_AM_mm", "dev_AB_mm", "dev_BC_mm", "dev_BE_mm"]
    assert d["yield_ci"]["method"].startswith("Clopper-Pearson") and d["yield_ci"]["level"] == 0.95
    for case in ("fixed_beta", "adjusted_beta"):
        col = m[f"total_{case.split('_')[0]}_um"]
        k = int((col <= 20.0).sum())
        assert d["yields"][case] == k / 300
        ci = stats.binomtest(k, 300).proportion_ci(0.95, method="exact")
        assert d["yield_ci"][case] == pytest.approx([ci.low, ci.high], abs=1e-12)
        x = col.dropna().to_numpy()
        cpu = (20.0 - x.mean()) / (3 * x.std(ddof=1))
        assert d["extra"]["capability"][case]["Cpu"] == pytest.approx(cpu, rel=1e-8)  # CSV digits
    assert "one-sided" in d["extra"]["capability"]["definition"]["Cpu"]
    # the picks, not the searched range; and how many picks sit on its ends
    b = m["beta_opt_deg"]
    assert d["extra"]["beta_picks_deg"] == pytest.approx([b.min(), b.max()], abs=1e-6)  # CSV digits
    assert d["extra"]["beta_search_range_deg"] == [15.0, 30.0] and d["extra"]["limit_um"] == 20.0
    assert d["extra"]["beta_at_bound"] == int(m["beta_at_bound"].sum()) > 0
    # flagged: the optimum's plateau touches a bound; pinned: and it is narrower than 0.1 deg
    low, high = m["beta_low_deg"], m["beta_high_deg"]
    touches = ((low - 15.0).abs() < 1e-6) | ((high - 30.0).abs() < 1e-6)
    assert (touches == (m["beta_at_bound"] == 1)).all()
    pinned = touches & (high - low < 0.1)
    assert d["extra"]["beta_pinned_at_bound"] == int(pinned.sum()) > 0
    assert (np.minimum(b[pinned] - 15.0, 30.0 - b[pinned]) < 0.05).all()
    assert "nominal machine's beta*" in d["extra"]["fixed_beta_means"]
    ctx = d["context"]
    assert ctx["tolerances"] == "base" and ctx["seed"] == 4 and ctx["n"] == 300
    assert ctx["strategy"] == "beta" and ctx["guide_shift_um"] == 0.0 and ctx["frame"]
    run_json = strict_loads((out / "run.json").read_text())["inputs"]
    assert run_json["seed"] == 4 and run_json["tolerances"]["name"] == "base"
    assert strict_loads((out / "montecarlo.json").read_text())["context"] == ctx


def test_flags_reach_the_library_with_the_same_numbers(mc_out, nominal):
    d, _ = mc_out
    res = montecarlo(nominal, NEEDLE_208_SETS["base"], 300, seed=4, limit_um=20.0,
                     range_deg=(15.0, 30.0))
    assert res.to_dict()["yields"]["adjusted_beta"] == d["yields"]["adjusted_beta"]
    for name in ("fixed", "fixed_beta", "adjusted", "adjusted_beta"):
        assert res.yield_of(name) == d["yields"][res.case_of(name)]
    with pytest.raises(ParameterError, match="case: must be fixed, adjusted"):
        res.yield_of("fixed beta")


def test_tolerances_on_branches_and_negative_symmetric_ones_are_refused_at_load(tmp_path,
                                                                              nominal):
    f = tmp_path / "t.toml"
    f.write_text("[sets.b]\nbeta_sense = 0.5\n")
    names = list(nominal.as_dict()) if hasattr(nominal, "as_dict") else None
    from sewtol.mechanisms.params import field_names

    names = field_names(type(nominal))
    with pytest.raises(ParameterError, match=r"b\.beta_sense: is a branch choice"):
        load_toml(f, names)
    with pytest.raises(ParameterError, match="branch_M: is a branch choice"):
        ToleranceSet("x", (Tolerance("branch_M", -2.0, 0.0),)).check_against(nominal)
    f.write_text("[sets.a]\nAB = -0.005\n")
    with pytest.raises(ParameterError, match=r"a symmetric tolerance \+/-X needs X >= 0"):
        load_toml(f, names)
    for cmd in ("scan", "montecarlo", "sobol", "worst-case", "guides"):
        code, out, err = run("needle", cmd, "--tolerances", str(f))
        assert code == 2 and out == "" and err.count("\n") == 1
        assert "a.AB: must not be negative: a symmetric tolerance" in err


def ishigami(X, a=7.0, b=0.1):
    return np.sin(X[:, 0]) + a * np.sin(X[:, 1]) ** 2 + b * X[:, 2] ** 4 * np.sin(X[:, 0])


def test_second_order_indices_of_ishigami():
    """Analytic (a=7, b=0.1): S1 = 0.3139, 0.4424, 0; S13 = 0.2437, S12 = S23 = 0; the
    variance decomposes exactly into S1 + S2 + S3 + S13 = 1."""
    problem = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-np.pi, np.pi]] * 3}
    X = sample(problem, 4096, 3, second_order=True)
    c = case_indices(problem, X, ishigami(X), 4096, 3, second_order=True)
    both, conv, pairs = c.indices, c.convergence, c.pairs
    s1 = both[both["n"] == 4096].set_index("param")
    assert s1.loc["x1", "S1"] == pytest.approx(0.3139, abs=0.01)
    assert s1.loc["x2", "S1"] == pytest.approx(0.4424, abs=0.01)
    assert abs(s1.loc["x3", "S1"]) < 0.01
    s2 = pairs.set_index(["param_i", "param_j"])
    assert s2.loc[("x1", "x3"), "S2"] == pytest.approx(0.2437, abs=0.01)
    assert abs(s2.loc[("x1", "x3"), "S2"] - 0.2437) < s2.loc[("x1", "x3"), "S2_conf"]
    assert abs(s2.loc[("x1", "x2"), "S2"]) < 0.01 and abs(s2.loc[("x2", "x3"), "S2"]) < 0.01
    assert s1["S1"].sum() + s2["S2"].sum() == pytest.approx(1.0, abs=0.02)
    # ST_3 - S1_3 is all interaction, and it is the x1-x3 pair's
    assert s1.loc["x3", "ST"] - s1.loc["x3", "S1"] == pytest.approx(
        s2.loc[("x1", "x3"), "S2"], abs=0.01)
    assert conv.loc[0, "max_abs_dS2"] < 0.02
    # the design of n base samples is the head of the design of 2n (the convergence check)
    assert np.array_equal(sample(problem, 64, 5, True), sample(problem, 128, 5, True)[:64 * 8])


def test_needle_sobol_second_order_from_the_cli(tmp_path):
    out = tmp_path / "s"
    code, text, err = run("needle", "sobol", "--n", "16", "--second-order", "--format", "json",
                          "--out", str(out))
    assert code == 0, err
    d = strict_loads(text)
    assert d["model_runs_per_case"] == 16 * (2 * 6 + 2)  # base set: 6 toleranced lengths
    for case in ("fixed_beta", "adjusted_beta"):
        pairs = [p for p in d["second_order"] if p["case"] == case]
        assert len(pairs) == 15 and all(np.isfinite(p["S2_conf"]) for p in pairs)
    s2 = pd.read_csv(out / "second_order.csv")
    assert len(s2) == 30 and list(s2.columns) == ["param_i", "param_j", "S2", "S2_conf", "case"]
    # without the flag: the same object, the S1/ST records under "indices", no S2
    code, text, _ = run("needle", "sobol", "--n", "16", "--format", "json")
    plain = strict_loads(text)
    assert "second_order" not in plain and plain["context"] == d["context"]
    assert plain["model_runs_per_case"] == 16 * (6 + 2)
    assert [(r["case"], r["param"]) for r in plain["indices"]] == \
        [(r["case"], r["param"]) for r in d["indices"]]


@pytest.mark.parametrize("suffix,magic", [(".png", b"\x89PNG"), (".svg", b"<?xml"),
                                          (".pdf", b"%PDF")])
def test_plot_writes_the_figure_in_each_format_reproducibly(tmp_path, suffix, magic):
    a, b = tmp_path / f"a{suffix}", tmp_path / f"b{suffix}"
    assert run("needle", "nominal", "--plot", str(a))[0] == 0
    assert run("needle", "nominal", "--plot", str(b))[0] == 0
    assert a.read_bytes().startswith(magic) and a.read_bytes() == b.read_bytes()


def test_progress_is_on_by_default_only_on_a_terminal():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    for given, stream, expected in ((None, Tty(), True), (None, io.StringIO(), False),
                                    (False, Tty(), False), (True, io.StringIO(), True)):
        assert resolve_progress(argparse.Namespace(progress=given), stream).progress is expected
    code, _, err = run("needle", "montecarlo", "--n", "200", "--no-progress")
    assert code == 0 and err == ""


def test_beta_range_with_adjust_is_beta_s_range(nominal):
    code, a, err = run("needle", "montecarlo", "--n", "200", "--adjust", "beta",
                       "--beta-range", "15", "30", "--format", "json")
    assert code == 0, err
    code, b, _ = run("needle", "montecarlo", "--n", "200", "--adjust", "beta",
                     "--range", "beta=15,30", "--format", "json")
    da, db = json.loads(a), json.loads(b)
    assert da == db and da["compensators"]["beta"]["low"] == 15.0
    code, _, err = run("needle", "montecarlo", "--n", "200", "--adjust", "beta",
                       "--range", "beta=15,30", "--beta-range", "15", "30")
    assert code == 2 and "--beta-range: gives beta's range, which --range beta=" in err


def test_contributors_show_the_explained_share_and_the_interaction_remainder():
    """eta^2 as shares of the whole variance: an additive response is explained in full; a pure
    product of zero-mean tolerances has no first-order effect (100 % interaction), which the
    normalised ranking (share_pct) would have shown as 50 % + 50 %."""
    from sewtol.studies.montecarlo import REMAINDER, contributors, with_remainder

    rng = np.random.default_rng(8)
    x = pd.DataFrame({"a": rng.uniform(-1, 1, 20000), "b": rng.uniform(-1, 1, 20000)})
    x["additive"] = x["a"] + 2 * x["b"]  # Var shares 1/5 and 4/5
    x["product"] = x["a"] * x["b"]
    add = with_remainder(contributors(x, ["a", "b"], "additive")).set_index("param")
    assert add.loc["b", "variance_pct"] == pytest.approx(80.0, abs=1.0)
    assert add.loc["a", "variance_pct"] == pytest.approx(20.0, abs=1.0)
    assert abs(add.loc[REMAINDER, "variance_pct"]) < 1.0
    prod = with_remainder(contributors(x, ["a", "b"], "product")).set_index("param")
    assert prod.loc[REMAINDER, "variance_pct"] == pytest.approx(100.0, abs=1.0)
    assert prod.loc[["a", "b"], "variance_pct"].max() < 1.0
    # the explained and remainder rows add up to 100 % of the variance
    assert prod.iloc[-2:]["variance_pct"].sum() == pytest.approx(100.0, abs=1e-9)


def test_pareto_of_the_needle_is_mostly_interaction(nominal):
    """Base set, beta adjusted: AB and BE act together (SumDelta ~ |AB - k BE|-like V), so the
    first-order shares leave a large remainder, as the Sobol S1 / ST gap says."""
    from sewtol.studies.montecarlo import EXPLAINED, REMAINDER

    res = montecarlo(nominal, NEEDLE_208_SETS["base"], 1000, seed=2)
    p = res.pareto().set_index("param")
    assert p.loc[EXPLAINED, "variance_pct"] + p.loc[REMAINDER, "variance_pct"] == pytest.approx(
        100.0)
    assert p.loc[REMAINDER, "variance_pct"] > 30.0


def test_feed_scan_from_the_cli_is_the_library_scan():
    """`feed scan` (= `run feed_131 scan`) is sewtol.studies.scan on the file with --set."""
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file
    from sewtol.studies.scan import scan

    code, out, err = run("feed", "scan", "--format", "json", "--set", "b=25", "--tolerances",
                         "assumed")
    assert code == 0, err
    d = strict_loads(out)
    mech = load(mechanism_file("feed_131"), {"b": 25.0})
    ref = scan(mech, mech.tolerance_sets["assumed"]).rows
    got = pd.DataFrame(d["rows"])
    assert list(got["param"]) == list(ref["param"]) and list(got["output"]) == list(ref["output"])
    assert np.allclose(got["change"], ref["change"], atol=1e-12)
    assert d["context"]["tolerances"] == "assumed" and d["context"]["mechanism"] == "feed_131"


def test_feed_montecarlo_and_sobol_from_the_cli(tmp_path):
    out = tmp_path / "mc"
    code, text, err = run("feed", "montecarlo", "--n", "100", "--seed", "3", "--format", "json",
                          "--tolerances", "assumed", "--out", str(out))
    assert code == 0, err
    d = strict_loads(text)
    m = pd.read_csv(out / "machines.csv")
    assert "O1F" in m.columns and "O2x" in m.columns and len(m) == 100
    summary = {r["output"]: r for r in d["extra"]["summary"]}
    assert summary["lower_step_mm"]["mean"] == pytest.approx(m["lower_step_mm"].mean(), rel=1e-9)
    for r in summary.values():  # every machine counted once
        assert r["ok"] + r["out_of_spec"] + r["cannot_close"] + r["dead_point"] == r["n"] == 100
    assert d["context"]["seed"] == 3 and d["context"]["tolerances"] == "assumed"
    assert strict_loads((out / "run.json").read_text())["inputs"]["study"] == "run montecarlo"

    code, text, err = run("feed", "sobol", "--n", "16", "--seed", "3", "--output",
                          "lower_step_mm", "--format", "json")  # the first set, links
    assert code == 0, err
    s = strict_loads(text)
    assert s["output"] == "lower_step_mm" and s["n"] == 16
    assert sorted(r["param"] for r in s["rows"]) == sorted(
        ["O1A1", "DB", "A1B", "O3C", "BC", "O3E"])
    code, _, err = run("feed", "sobol", "--n", "8")
    assert code == 2 and "--n: must be a power of two >= 16" in err
    code, _, err = run("feed", "montecarlo", "--n", "1")
    assert code == 2 and "--n: must be >= 2" in err


def test_fixed_beta_is_the_nominal_beta_star_in_every_needle_study():
    """Item 1: with the guide shifted 20 um, every study's fixed case sits at the beta* that
    `needle nominal` prints for that machine, not at the stored beta."""
    star = nominal_json("--set", "guide_shift_um=20")["beta_opt_deg"]
    shift = ("--set", "guide_shift_um=20", "--format", "json")
    _, out, _ = run("needle", "worst-case", *shift)
    wc = strict_loads(out)
    assert wc["fixed_beta_deg"] == star
    assert next(r for r in wc["rows"] if r["case"] == "fixed_beta")["beta_deg"] == star
    _, out, _ = run("needle", "montecarlo", "--n", "50", *shift)
    assert strict_loads(out)["extra"]["nominal_beta_deg"] == star
    _, out, _ = run("needle", "montecarlo", "--n", "50", "--adjust", "guide_shift_um", *shift)
    assert strict_loads(out)["fixed_beta_deg"] == star
    _, out, _ = run("needle", "guides", "--n", "20", *shift)
    row = strict_loads(out)["rows"][0]
    assert row["guide"] == "nominal" and row["beta_opt_deg"] == star


def test_scan_says_where_a_plateau_reaching_the_bound_lies():
    """AB at its lower limit: beta* 16.49 deg is flagged at the bound although it lies inside
    [10, 35]: SumDelta is flat (within 1e-3 um) over 10 ... 22.99 deg, a plateau that runs into
    the range's end. beta_deg is its centre; a wider range extends the plateau and leaves
    SumDelta as it was, which the note allows ("may stay flat or fall beyond")."""
    def ab_lower(*extra):
        _, out, _ = run("needle", "scan", "--format", "json", *extra)
        return next(r for r in strict_loads(out)["rows"]
                    if (r["param"], r["side"]) == ("AB", "lower"))

    row = ab_lower()
    assert row["beta_at_bound"] and 16.4 < row["beta_deg"] < 16.6
    assert row["beta_low_deg"] == pytest.approx(10.0, abs=1e-6)
    assert 22.9 < row["beta_high_deg"] < 23.1
    assert row["beta_deg"] == pytest.approx(0.5 * (row["beta_low_deg"] + row["beta_high_deg"]),
                                            abs=1e-6)
    wider = ab_lower("--beta-range", "0", "35")
    assert not wider["beta_at_bound"] and 0 < wider["beta_low_deg"] < 10
    assert wider["beta_high_deg"] == pytest.approx(row["beta_high_deg"], abs=1e-3)
    assert wider["total_um"] == pytest.approx(row["total_um"], abs=1e-3)
    _, text, _ = run("needle", "scan")
    assert ("note: AB lower: SumDelta 55.0624 um for beta 10.0000 ... 22.9871 deg, a flat "
            "plateau reaching the range's end 10 deg") in text
    assert "note: 1 of 12 rows" in text and "LF upper:" not in text


def test_adjusted_scan_flags_the_same_rows():
    _, a, _ = run("needle", "scan", "--format", "json", "--beta-range", "22", "23")
    _, b, err = run("needle", "scan", "--format", "json", "--adjust", "beta", "--beta-range",
                    "22", "23")
    plain, adj = strict_loads(a)["rows"], strict_loads(b)["rows"]
    assert [r["beta_at_bound"] for r in adj] == [r["beta_at_bound"] for r in plain], err


def test_second_order_shows_the_ab_be_interaction_of_the_needle(nominal):
    """Base set: AB and BE have S1 ~ 0.13 but ST ~ 0.87; S2 names the partner: AB x BE carries
    the gap (0.75 +/- 0.27 at N = 256; 0.78 +/- 0.14 at N = 1024)."""
    from sewtol.tables.needle_208 import needle_sobol

    res = needle_sobol(nominal, NEEDLE_208_SETS["base"], 256, seed=1, second_order=True)
    assert res.model_runs == 256 * (2 * 6 + 2)
    s2 = res.second_order_frame()
    idx = res.to_dataframe()
    for case in ("fixed_beta", "adjusted_beta"):
        pairs = s2[s2["case"] == case].set_index(["param_i", "param_j"])
        top = pairs["S2"].abs().idxmax()
        assert top == ("AB", "BE") and pairs.loc[top, "S2"] > 0.5
        ab = idx[(idx["case"] == case) & (idx["param"] == "AB")].iloc[0]
        gap = ab["ST"] - ab["S1"]
        assert abs(gap - pairs.loc[top, "S2"]) < pairs.loc[top, "S2_conf"] + ab["ST_conf"]
    with pytest.raises(ParameterError, match="second_order: was not computed"):
        needle_sobol(nominal, NEEDLE_208_SETS["base"], 16, seed=1).second_order_frame()


@pytest.mark.parametrize("argv", [
    ("needle", "allocation", "--n", "50", "--guide-shift-um", "5"),
    ("needle", "ppm", "--budget", "200", "--guide-shift-um", "5"),
    ("needle", "sobol", "--n", "16", "--second-order", "--guide-shift-um", "5"),
    ("needle", "worst-case", "--guide-shift-um", "5"),
    ("needle", "guides", "--n", "20", "--guide-shift-um", "5"),
])
def test_dict_shaped_json_outputs_carry_their_context(argv):
    code, out, err = run(*argv, "--format", "json", "--frame", "window")
    assert code == 0, err
    ctx = strict_loads(out)["context"]
    assert ctx["frame"] == "window" and ctx["guide_shift_um"] == 5.0
    assert ctx["tolerances"] == "base" and ctx["strategy"] == "beta"


def test_feed_plots_and_strategy_machine_tables(tmp_path):
    assert run("feed", "regulator", "--b-range", "0", "60", "10", "--plot",
               str(tmp_path / "r.pdf"))[0] == 0
    assert (tmp_path / "r.pdf").read_bytes().startswith(b"%PDF")
    out = tmp_path / "st"
    assert run("needle", "strategies", "--n", "10", "--out", str(out))[0] == 0
    m = pd.read_csv(out / "machines_none.csv")
    assert list(m.columns[1:7]) == ["dev_LF_mm", "dev_LM_mm", "dev_AM_mm", "dev_AB_mm",
                                    "dev_BC_mm", "dev_BE_mm"]


def test_scan_and_sobol_carry_their_context_in_json_and_run_json(tmp_path):
    out = tmp_path / "scan"
    code, text, err = run("needle", "scan", "--format", "json", "--guide-shift-um", "5",
                          "--out", str(out))
    assert code == 0, err
    assert strict_loads((out / "scan.json").read_text()) == strict_loads(text)
    ctx = strict_loads((out / "run.json").read_text())["inputs"]["context"]
    assert ctx["guide_shift_um"] == 5.0 and ctx["tolerances"] == "base"
    back = pd.read_csv(out / "scan.csv")  # plain CSV: no comment lines to skip
    assert list(back["param"]) == [r["param"] for r in strict_loads(text)["rows"]]
    assert strict_loads(text)["context"] == ctx
    s = tmp_path / "sobol"
    assert run("needle", "sobol", "--n", "16", "--seed", "7", "--out", str(s))[0] == 0
    ctx = strict_loads((s / "run.json").read_text())["inputs"]["context"]
    assert ctx["seed"] == 7 and ctx["n"] == 16 and ctx["frame"] == "sewtol-0.1"


def test_a_flag_has_one_type_default_and_arity_in_every_command():
    """Item 7: the shared flags are the same argparse definition wherever they appear."""
    from sewtol.cli import build_parser

    shared = ("--beta-range", "--limit-um", "--guide-shift-um", "--frame", "--seed", "--n-jobs",
              "--out", "--plot", "--progress", "--set", "--resume", "--scheduler")
    seen: dict[str, dict] = {}
    commands = 0
    groups = build_parser()._subparsers._group_actions[0].choices
    # `run` and its aliases (`needle scan`, `feed scan`, ...) among them
    commands_of = {"run": groups["run"],
                   **{f"needle {k}": v for k, v in
                      groups["needle"]._subparsers._group_actions[0].choices.items()},
                   **{f"feed {k}": v for k, v in
                      groups["feed"]._subparsers._group_actions[0].choices.items()}}
    for name, cmd in commands_of.items():
        commands += 1
        for action in cmd._actions:
            flag = next((f for f in action.option_strings if f in shared), None)
            if flag is None:
                continue
            spec = {"type": action.type, "nargs": action.nargs, "default": action.default,
                    "kind": type(action).__name__}
            assert seen.setdefault(flag, spec) == spec, (name, flag, spec, seen[flag])
    assert commands >= 14 and set(seen) == set(shared)
    assert seen["--progress"]["kind"] == "BooleanOptionalAction"
    assert seen["--beta-range"]["nargs"] == 2 and seen["--beta-range"]["default"] is None


def test_montecarlo_and_compare_guides_agree_on_the_same_machine(nominal):
    """Trap 1 in the API: the guide comparison's nominal row is montecarlo's fixed case."""
    from sewtol.tables.needle_208 import compare_guides

    shifted = nominal.override(guide_shift_um=20.0)
    table = compare_guides(shifted, NEEDLE_208_SETS["base"], 150, 3,
                           variants=(("nominal", 0.0, 0.0),))
    res = montecarlo(shifted, NEEDLE_208_SETS["base"], 150, seed=3)
    assert table.loc[0, "beta_opt_deg"] == res.extra["nominal_beta_deg"]
    assert table.loc[0, "yield_fixed_beta"] == res.yield_of("fixed_beta")
    assert table.loc[0, "yield_adjusted_beta"] == res.yield_of("adjusted_beta")


def test_a_fixed_beta_on_the_bound_is_flagged_in_every_study():
    """--beta-range 23.5 24 excludes the nominal's free beta* (22.58): the fixed case sits on
    23.5 and every study says so; default range: no flag."""
    narrow = ("--beta-range", "23.5", "24", "--format", "json")
    _, out, _ = run("needle", "worst-case", *narrow)
    wc = strict_loads(out)
    assert wc["fixed_beta_at_bound"] is True and abs(wc["fixed_beta_deg"] - 23.5) < 1e-3
    adjusted = next(r for r in wc["rows"] if r["case"] == "adjusted_beta")
    assert adjusted["beta_at_bound"] is True and 23.5 <= adjusted["beta_deg"] <= 24.0
    _, out, _ = run("needle", "montecarlo", "--n", "50", *narrow)
    mc = strict_loads(out)
    assert mc["extra"]["fixed_beta_at_bound"] is True
    assert abs(mc["extra"]["nominal_beta_deg"] - 23.5) < 1e-3
    _, out, _ = run("needle", "montecarlo", "--n", "50", "--adjust", "beta", *narrow)
    assert strict_loads(out)["fixed_beta_at_bound"] is True
    _, text, _ = run("needle", "worst-case", "--beta-range", "23.5", "24")
    assert "note: the fixed case's beta = 23.5002 deg, the nominal's beta*, reaches a bound" in text
    _, out, _ = run("needle", "worst-case", "--format", "json")
    wc = strict_loads(out)
    assert wc["fixed_beta_at_bound"] is False
    assert not any(r["beta_at_bound"] for r in wc["rows"])
