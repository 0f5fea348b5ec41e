"""ppm, allocation and the report of any mechanism file, against analytic answers.

The case: a centred crank-slider (tests/data/crank_slider.toml) whose stroke is exactly 2 r at
the file's 8 sampled angles (the slider's extremes L + r and L - r are sampled at q = 0 and
180 deg), so every probability and scale below has a closed form in r's distribution."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from scipy import stats  # noqa: E402

from cli_helpers import run, strict_loads  # noqa: E402
from sewtol.intervals import clopper_pearson  # noqa: E402
from sewtol.mechanism import load  # noqa: E402
from sewtol.reports import generic_report as GR  # noqa: E402
from sewtol.studies import allocation as AL  # noqa: E402
from sewtol.studies import rare_event as PPM  # noqa: E402
from sewtol.studies import rare_event as R  # noqa: E402
from sewtol.studies import sobol as SO  # noqa: E402
from sewtol.studies.montecarlo import draw_deviations as draw_deviations_of  # noqa: E402
from sewtol.studies.montecarlo import draw_units, unit_streams  # noqa: E402
from sewtol.tolerances import Tolerance, ToleranceSet  # noqa: E402

FILE = str(Path(__file__).parent / "data" / "crank_slider.toml")
R0 = 10.0
SIGMA_R = 0.01  # the set "normal": r +/-0.03 at +/-3 sigma


@pytest.fixture(scope="module")
def mech():
    return load(FILE)


def test_stroke_is_exactly_two_r(mech):
    r = np.array([9.5, 10.0, 10.37])
    ev = mech.evaluate({"r": r, "L": [40.0, 39.0, 41.2]})
    np.testing.assert_allclose(ev.outputs["stroke_mm"], 2 * r, rtol=0, atol=1e-12)
    assert list(ev.status) == ["ok"] * 3


def test_ppm_subset_simulation_normal_tail_at_1e_5(mech):
    # P(stroke > limit) = P(r > limit / 2) = P(z > z_true) with z_true chosen for 1e-5
    truth = 1e-5
    limit = 2 * (R0 + SIGMA_R * stats.norm.isf(truth))
    ls = PPM.limit_state(mech, mech.tolerance_sets["normal"], "stroke_mm", upper=limit)
    assert ls.failure_modes == ("cannot_close at J", "dead_point at J")
    assert ls.limit == limit and ls.output == "stroke_mm"
    res = R.estimate(ls, np.random.default_rng(1), "auto", 1e-5, 20000)
    assert res.method == "subset"
    assert res.ci_low <= res.probability <= res.ci_high
    assert res.ci_low <= truth <= res.ci_high
    assert res.cov < 0.5
    assert res.mode_counts == {"value > limit": res.failures, "cannot_close at J": 0,
                               "dead_point at J": 0}
    # the failing examples sit beyond the limit in r, not in L
    assert (res.examples["r"] > limit / 2 - R0 - 1e-12).all()


def test_ppm_two_sided_and_lower_limit_monte_carlo(mech):
    tol = mech.tolerance_sets["normal"]
    a = 0.035  # limits 20 +/- a: fail when |2 d| > a
    truth = 2 * stats.norm.sf(a / (2 * SIGMA_R))
    ls = PPM.limit_state(mech, tol, "stroke_mm", upper=20 + a, lower=20 - a)
    assert ls.output == "stroke_mm_excess" and ls.limit == 0.0
    res = R.estimate(ls, np.random.default_rng(3), "montecarlo", 1e-2, 20000)
    assert res.ci_low <= truth <= res.ci_high
    low = PPM.limit_state(mech, tol, "stroke_mm", lower=20 - a)
    res = R.estimate(low, np.random.default_rng(4), "montecarlo", 1e-2, 20000)
    assert res.ci_low <= truth / 2 <= res.ci_high


def test_ppm_machines_that_cannot_close_are_failures_named_by_group():
    # L near r: at q = 90 deg the rod cannot reach the guide when L < r
    mech = load(FILE, {"L": 10.05})
    tol = ToleranceSet("L", (Tolerance("L", -0.3, 0.3, "normal"),))
    ls = PPM.limit_state(mech, tol, "stroke_mm", upper=100.0)
    res = R.estimate(ls, np.random.default_rng(5), "montecarlo", 0.1, 4000)
    truth = stats.norm.cdf((R0 - 10.05) / 0.1)
    assert res.mode_counts["cannot_close at J"] == res.failures > 0
    assert res.mode_counts["value > limit"] == 0
    assert res.ci_low <= truth <= res.ci_high


def test_ppm_no_failure_is_a_bound_never_zero_ppm(mech):
    ls = PPM.limit_state(mech, mech.tolerance_sets["uniform"], "stroke_mm", upper=20.5)
    res = R.estimate(ls, np.random.default_rng(0), "montecarlo", 0.01, 1000)
    assert not res.resolved and res.failures == 0
    assert res.statement.startswith("< ") and "at 95 %" in res.statement
    # Clopper-Pearson one-sided 95 % bound for 0 of 1000: 1 - 0.05 ** (1 / 1000)
    assert res.upper_95 == pytest.approx(1 - 0.05 ** (1 / 1000), rel=1e-9)


def test_ppm_with_compensator_is_the_adjusted_output(mech):
    # J_x_max = L + r, minimised over L in [39, 41] at L = 39: fails when 39 + r > limit
    truth = 1e-3
    limit = 39 + R0 + SIGMA_R * stats.norm.isf(truth)
    ls = PPM.limit_state(mech, mech.tolerance_sets["normal"], "J_x_max_mm", upper=limit,
                             adjust="rod")
    assert ls.output == "J_x_max_mm_adjusted"
    z = np.array([[0.0, 0.0], [1.0, -2.0], [-3.0, 3.0]])
    value, mode = ls.response(z)
    np.testing.assert_allclose(value, 39 + R0 + SIGMA_R * z[:, 0], rtol=0, atol=1e-9)
    assert list(mode) == [0, 0, 0]
    res = R.estimate(ls, np.random.default_rng(6), "subset", truth, 6000)
    assert res.ci_low <= truth <= res.ci_high


def _order_statistic_scale(n, seed, target, half_mm, t_mm):
    """The largest k at which the same uniforms give yield >= target: P(|d_r| <= half) with
    d_r = k * t * (2 u - 1), i.e. k <= half / (t * V_(m)), V = |2 u - 1|, m = ceil(target n)."""
    u = draw_units(unit_streams(seed, n), 2, 0, n)  # montecarlo's uniforms for the seed
    v = np.sort(np.abs(2 * u[:, 0] - 1))
    m = int(np.ceil(target * n))
    return half_mm / (t_mm * v[m - 1])


def test_allocation_in_a_given_bracket_finds_the_same_crossing(mech):
    # the needle's search: k in (0, 2) by 14 bisection steps; the yield is a monotone step
    # function here, so the sample's exact crossing lies in the last bracket
    target, n = 0.9973, 2000
    b = AL.allocate(mech, mech.tolerance_sets["uniform"], "stroke_mm", target, upper=20.02,
                    lower=19.98, n=n, seed=0, bracket=(0.0, 2.0), steps=14)
    k_sample = _order_statistic_scale(n, 0, target, 0.01, 0.03)
    assert b.scale <= k_sample * (1 + 1e-9) and k_sample - b.scale < 2.0 / 2**14
    assert len(b.trials) == 15 and b.yield_ >= target and not b.capped


def test_sobol_cases_of_a_file_adjusted_and_in_chunks(mech):
    # stroke = 2 r: the rod L (the compensator) explains nothing, fixed or adjusted, and the
    # adjusted case equals the fixed one; the chunks of the model runs change no number
    cases = {"fixed": None, "adjusted_rod": "rod"}
    tol = mech.tolerance_sets["uniform"]
    a = SO.sobol(mech, tol, "stroke_mm", 16, 1, cases=cases)
    b = SO.sobol(mech, tol, "stroke_mm", 16, 1, cases=cases, chunk_size=7)
    assert a.indices.equals(b.indices) and a.convergence.equals(b.convergence)
    ix = a.to_dataframe().set_index(["case", "param"])
    for case in cases:
        assert abs(ix.loc[(case, "L"), "S1"]) < 1e-12 and abs(ix.loc[(case, "L"), "ST"]) < 1e-12
    for k in ("S1", "ST"):
        assert ix.loc[("adjusted_rod", "r"), k] == pytest.approx(ix.loc[("fixed", "r"), k],
                                                                 rel=1e-9)


def test_allocation_uniform_scale_matches_closed_form(mech):
    # P(|2 r - 2 r0| <= 0.02) with r uniform +/- 0.03 k is 0.01 / (0.03 k) = target
    target, n = 0.9973, 2000
    a = AL.allocate(mech, mech.tolerance_sets["uniform"], "stroke_mm", target, upper=20.02,
                    lower=19.98, n=n, seed=0)
    k_true = 0.01 / (0.03 * target)
    k_sample = _order_statistic_scale(n, 0, target, 0.01, 0.03)
    # bisection to SCALE_RTOL below the sample's exact crossing
    assert k_sample * (1 - 2 * AL.SCALE_RTOL) <= a.scale <= k_sample * (1 + 1e-9)
    # the sample crossing is an order statistic: sd of V_(m) is sqrt(p (1 - p) / n) ~ 0.0012
    assert abs(a.scale / k_true - 1) < 4 * np.sqrt(target * (1 - target) / n)
    assert a.yield_ >= target and not a.capped
    tab = a.table.set_index("param")
    assert tab.loc["r", "upper"] == pytest.approx(0.03 * a.scale, rel=1e-12)
    assert tab.loc["L", "upper"] == pytest.approx(0.1 * a.scale, rel=1e-12)
    # every trial above the found scale has a yield below the target (monotone here)
    tr = a.trials
    assert (tr.loc[tr["scale"] > a.scale, "yield"] < target).all()
    assert (tr.loc[tr["scale"] <= a.scale, "yield"] >= target).all()
    # same seed, same answer
    b = AL.allocate(mech, mech.tolerance_sets["uniform"], "stroke_mm", target, upper=20.02,
                    lower=19.98, n=n, seed=0)
    assert b.scale == a.scale


def test_allocation_weight_halves_r_doubles_the_scale(mech):
    tol = mech.tolerance_sets["uniform"]
    a = AL.allocate(mech, tol, "stroke_mm", 0.95, upper=20.02, lower=19.98, n=500, seed=2)
    b = AL.allocate(mech, tol, "stroke_mm", 0.95, upper=20.02, lower=19.98, n=500, seed=2,
                    weights={"r": 0.5})
    # r's allocated limit is the same (stroke depends on r only): k_b * 0.5 = k_a
    assert b.scale * 0.5 == pytest.approx(a.scale, rel=3 * AL.SCALE_RTOL)
    ra = a.table.set_index("param").loc["r", "upper"]
    rb = b.table.set_index("param").loc["r", "upper"]
    assert rb == pytest.approx(ra, rel=3 * AL.SCALE_RTOL)


def test_cost_allocation_shapes_by_slope_holds_the_unseen_and_keeps_its_target(mech):
    # stroke = 2 r: r's slope is 2 (0.06 over +/-0.03), L's 0 (held at its reference limits,
    # not scaled); r alone is shaped (the largest shape, 1), so its half-width is the scale:
    # the sample's crossing 0.01 / V_(m) of the same uniforms (r's column), to SCALE_RTOL
    target, n = 0.9973, 2000
    a = AL.allocate_by_cost(mech, mech.tolerance_sets["uniform"], "stroke_mm", target,
                            upper=20.02, lower=19.98, n=n, seed=0)
    tab = a.table.set_index("param")
    assert tab.loc["r", "slope"] == pytest.approx(2.0, rel=1e-9)
    assert bool(tab.loc["L", "held_at_reference"]) and not tab.loc["r", "held_at_reference"]
    assert (tab.loc["L", "lower"], tab.loc["L", "upper"]) == (-0.1, 0.1)
    k_sample = _order_statistic_scale(n, 0, target, 0.01, 1.0)
    assert k_sample * (1 - 2 * AL.SCALE_RTOL) <= tab.loc["r", "upper"] <= k_sample * (1 + 1e-9)
    assert tab.loc["r", "upper"] == -tab.loc["r", "lower"] == pytest.approx(a.scale, rel=1e-12)
    # the yield it reports is that of its set on montecarlo's machines, and the target lies in
    # its exact interval (the crossing of a step function of n machines)
    dev = draw_deviations_of(a.as_tolerance_set(), n, 0)
    ok = int(np.sum(np.abs(2 * dev["r"]) <= 0.02 + 1e-12))
    assert ok / n == a.yield_ >= target
    lo, hi = clopper_pearson(ok, n)
    assert lo <= target <= hi


def test_allocation_counts_machines_that_cannot_close_against_the_yield():
    # L = 10.5 + d, d uniform +/- 0.1 k: the rod cannot reach the guide at q = 90 deg when
    # L < r = 10, so yield = (0.1 k + 0.5) / (0.2 k) -> 0.1 k = 0.5 / (2 target - 1)
    mech = load(FILE, {"L": 10.5})
    tol = ToleranceSet("L", (Tolerance("L", -0.1, 0.1),))
    target, n = 0.9, 4000
    a = AL.allocate(mech, tol, "stroke_mm", target, upper=100.0, n=n, seed=4)
    k_true = 0.5 / (2 * target - 1) / 0.1
    # the crossing is the sample's (1 - target) quantile of d / (0.1 k): sd sqrt(p (1-p) / n)
    # in u, i.e. 2 sqrt(p (1 - p) / n) / (2 (1 - target)) relative to the distance -0.5
    u_sd = np.sqrt(target * (1 - target) / n)
    assert abs(a.scale / k_true - 1) < 4 * 2 * u_sd / (2 * target - 1)
    over = a.trials[a.trials["scale"] > a.scale]
    assert (over["cannot_close"] > 0).all() and (over["out_of_limits"] == 0).all()
    assert (over["ok"] + over["cannot_close"] == n).all()


def test_allocation_normal_scale_matches_closed_form(mech):
    # r normal with sigma 0.01 k: P(|2 sigma k z| <= 0.02) = target -> k = 1 / z_{(1+t)/2}
    target, n = 0.9, 4000
    a = AL.allocate(mech, mech.tolerance_sets["normal"], "stroke_mm", target, upper=20.02,
                    lower=19.98, n=n, seed=1)
    k_true = 1.0 / stats.norm.ppf(0.5 + target / 2)
    # quantile of |z| at p: sd sqrt(p (1 - p) / n) / (2 phi(q)) relative to q
    q = stats.norm.ppf(0.5 + target / 2)
    rel_sd = np.sqrt(target * (1 - target) / n) / (2 * stats.norm.pdf(q)) / q
    assert abs(a.scale / k_true - 1) < 4 * rel_sd


def test_report_same_seed_same_tables(mech, tmp_path):
    tol = mech.tolerance_sets["normal"]
    for d in ("a", "b"):
        GR.write(GR.build(mech, tol, n=100, seed=9, limit_output="stroke_mm", upper=20.03),
                 tmp_path / d)
    for name in ("machines.csv", "scan.csv", "worst_case.csv", "yield.csv", "index.md",
                 "report.html", "hist_stroke_mm.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_report_words_tables_and_histograms(mech, tmp_path):
    rep = GR.build(mech, mech.tolerance_sets["uniform"], n=400, seed=3,
                   limit_output="stroke_mm", upper=20.05, lower=19.95)
    words = "\n".join(rep.words())
    assert "Centred crank-slider (stroke = 2 r)" in words
    assert "the slider's extreme positions are L + r and L - r" in words
    assert "the guide passes through the crank centre" in words
    # stroke changes only with r: +/- 0.03 mm -> 0.06 mm, the whole share
    assert "- stroke_mm: r (0.06 mm, 100 %), L (0 mm, 0 %)" in words
    assert "- J_x_max_mm: L (0.1 mm, 77 %), r (0.03 mm, 23 %)" in words
    # yield: |2 d_r| <= 0.05 with d_r uniform +/-0.03, the same uniforms as the Monte-Carlo
    d = rep.machines["r"].to_numpy()
    assert rep.yield_row["ok"] == int(np.sum(np.abs(2 * d) <= 0.05 + 1e-12))
    assert rep.yield_row["ok"] + rep.yield_row["out_of_limits"] == 400
    wc = rep.worst_case.set_index(["output", "extreme"])["value"]
    assert wc[("stroke_mm", "max")] == pytest.approx(20.06, abs=1e-9)
    assert wc[("J_x_max_mm", "min")] == pytest.approx(50 - 0.13, abs=1e-9)
    GR.write(rep, tmp_path)
    for name in ("nominal", "scan", "worst_case", "montecarlo_summary", "dominance", "yield"):
        assert (tmp_path / f"{name}.csv").exists() and (tmp_path / f"{name}.md").exists()
    index = (tmp_path / "index.md").read_text()
    assert index.startswith("# Centred crank-slider") and "hist_stroke_mm.png" in index
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 2
    assert "http" not in page and "<script" not in page and "src=\"hist" not in page
    # legend counts add up to n
    fig, ax = plt.subplots()
    GR.histogram(rep, "stroke_mm", ax)
    counts = [int(t.get_text().split()[0]) for t in ax.get_legend().get_texts()[:3]]
    plt.close(fig)
    assert sum(counts) == 400


def test_cli_ppm_allocation_report(tmp_path):
    code, out, err = run("run", FILE, "ppm", "--tolerances", "normal", "--limit", "20.07",
                         "--method", "mc", "--n", "5000", "--seed", "2",
                         "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    truth = stats.norm.sf((20.07 / 2 - R0) / SIGMA_R)
    assert obj["ci95"][0] <= truth <= obj["ci95"][1]
    assert obj["pass_condition"] == "stroke_mm <= 20.07 mm" and obj["budget"] == 5000
    assert obj["method"] == "montecarlo" and obj["model_calls"] == 5000
    code, out, err = run("run", FILE, "allocation", "--tolerances", "uniform", "--limit",
                         "20.02", "--lower-limit", "19.98", "--n", "2000", "--shape", "set",
                         "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    k = _order_statistic_scale(2000, 0, 0.9973, 0.01, 0.03)
    assert k * (1 - 2 * AL.SCALE_RTOL) <= obj["scale"] <= k * (1 + 1e-9)
    # the default shapes by cost: r's half-width is the crossing, L (unseen) keeps its limits
    code, out, err = run("run", FILE, "allocation", "--tolerances", "uniform", "--limit",
                         "20.02", "--lower-limit", "19.98", "--n", "2000", "--format", "json")
    assert code == 0, err
    rows = {r["param"]: r for r in strict_loads(out)["rows"]}
    k = _order_statistic_scale(2000, 0, 0.9973, 0.01, 1.0)
    assert k * (1 - 2 * AL.SCALE_RTOL) <= rows["r"]["upper"] <= k * (1 + 1e-9)
    assert rows["L"]["held_at_reference"] and rows["L"]["upper"] == 0.1
    # a limit the nominal itself misses: no scale reaches the target, said as a null yield
    code, out, err = run("run", FILE, "allocation", "--tolerances", "uniform", "--limit",
                         "19.9", "--n", "50", "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert obj["scale"] == 0.0 and obj["yield"] is None and obj["yield_ci95"] == [None, None]
    code, out, err = run("run", FILE, "report", "--tolerances", "uniform", "--n", "200",
                         "--limit", "20.05", "--out", str(tmp_path / "rep"))
    assert code == 0, err
    assert "yield" in out and (tmp_path / "rep" / "report.html").exists()
    run_json = json.loads((tmp_path / "rep" / "run.json").read_text())
    assert run_json["inputs"]["study"] == "run report"
    assert run_json["inputs"]["limit"] == 20.05 and run_json["inputs"]["n"] == 200


@pytest.mark.parametrize("argv, flag", [
    (("allocation",), "--limit"),
    (("ppm", "--limit", "20", "--lower-limit", "21"), "--lower-limit"),
    (("allocation", "--limit", "20.1", "--target", "1.5"), "--target"),
    (("ppm", "--limit", "20.1", "--weight", "r=2"), "--weight"),
    (("report",), "--out"),
    (("ppm", "--limit", "nan"), "--limit"),
    (("allocation", "--limit", "20.1", "--weight", "Q=2"), "--weight"),
    (("allocation", "--limit", "20.1", "--weight", "r=-1"), "--weight: r's weight"),
    (("allocation", "--limit", "20.1", "--shape", "set", "--weight", "r=-1"),
     "--weight: r's weight"),
    (("ppm", "--limit", "20.1", "--shape", "set"), "--shape"),
    (("ppm", "--limit", "20.1", "--adjust", "beta"), "--adjust"),
    (("ppm", "--limit", "20.1", "--n", "50"), "--n"),
])
def test_cli_bad_inputs_one_line_exit_2(argv, flag):
    code, out, err = run("run", FILE, *argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0], err


def test_histogram_axis_names_the_unit_once():
    from sewtol.reports.generic_report import axis_label

    assert axis_label("stroke_mm", "mm") == "stroke (mm)"
    assert axis_label("slider_speed_max_m_s", "m/s") == "slider_speed_max (m/s)"
    assert axis_label("acc_m_s2", "m/s^2") == "acc (m/s^2)"
    assert axis_label("SumDelta_um", "um") == "SumDelta (\u00b5m)"
    assert axis_label("loss", "deg") == "loss (deg)"
    assert axis_label("mm", "mm") == "mm (mm)"
    assert axis_label("count", "") == "count"

