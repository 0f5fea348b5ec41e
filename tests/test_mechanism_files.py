"""Mechanism files: loader refusals (with lines), the expression whitelist, equality with the
built-in chains, the needle fast path, statuses, reproducibility and transfer functions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run, strict_loads
from sewtol.adjuster import adjust
from sewtol.errors import ParameterError
from sewtol.mechanism import ExpressionError, load, loads, parse_expression
from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131.model import Feed131, chains
from sewtol.mechanisms.needle_208.fast_path import needle_perturbations, needle_positions_residual
from sewtol.studies import montecarlo as MC
from sewtol.studies import scan as S
from sewtol.studies import sobol as so
from sewtol.studies import worst_case as W

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NEEDLE = EXAMPLES / "needle_208.toml"
FEED = EXAMPLES / "feed_131.toml"
KHUJAND = EXAMPLES / "khujand_feed.toml"

FOUR_BAR = """format = "sewtol-mechanism/1"

[mechanism]
name = "four_bar"
samples = 360
rpm = 600

[parameters]
a = { nominal = 10.0, unit = "mm", rule = "positive", doc = "crank" }
b = { nominal = 40.0, unit = "mm", rule = "positive" }
c = { nominal = 30.0, unit = "mm", rule = "positive" }
d = { nominal = 35.0, unit = "mm", rule = "positive" }
s = { nominal = 1, unit = "1", rule = "branch" }

[[groups]]
type = "point"
name = "A"
x = 0.0
y = 0.0

[[groups]]
type = "point"
name = "D"
x = "d"
y = 0.0

[[groups]]
type = "crank"
name = "B"
center = "A"
radius = "a"

[[groups]]
type = "rrr"
name = "C"
p1 = "B"
r1 = "b"
p2 = "D"
r2 = "c"
branch = "s"

[[outputs]]
name = "B_y_range_mm"
unit = "mm"
type = "coordinate"
point = "B"
axis = "y"
measure = "range"

[[outputs]]
name = "B_speed_m_s"
unit = "m/s"
type = "speed"
point = "B"

[[outputs]]
name = "transmission_deg"
unit = "deg"
type = "transmission"
group = "C"

[tolerances.wide]
b = 3.0
"""


def refusal(text: str) -> str:
    with pytest.raises(ParameterError) as info:
        loads(text, "m.toml")
    return str(info.value)


def line_of(text: str, snippet: str, after: str = "") -> int:
    start = text.index(after) if after else 0
    return text[: text.index(snippet, start)].count("\n") + 1


# --- loader refusals --------------------------------------------------------------------------

def test_unknown_key_names_file_line_and_field():
    text = FOUR_BAR.replace('r2 = "c"', 'r2 = "c"\nradius = 3')
    msg = refusal(text)
    assert msg.startswith(f"m.toml:{line_of(text, 'radius = 3')}: [[groups]] C.radius: unknown key")
    assert "allowed: type, name, p1, r1, p2, r2, branch" in msg


def test_reference_to_undefined_point_and_parameter():
    text = FOUR_BAR.replace('p2 = "D"', 'p2 = "Q"')
    msg = refusal(text)
    assert msg.startswith(f"m.toml:{line_of(text, 'p2 = ')}: [[groups]] C.p2: must name a point")
    text = FOUR_BAR.replace('r1 = "b"', 'r1 = "bb * 2"')
    msg = refusal(text)
    assert f"m.toml:{line_of(text, 'r1 = ')}: [[groups]] C.r1" in msg
    assert "'bb', which is not a parameter" in msg


def test_branch_rule_value_and_format():
    assert "must be +1 (left) or -1 (right)" in refusal(FOUR_BAR.replace('branch = "s"',
                                                                        "branch = 2"))
    assert "rule = \"branch\"" in refusal(FOUR_BAR.replace('branch = "s"', 'branch = "a"'))
    text = FOUR_BAR.replace("c = { nominal = 30.0", "c = { nominal = -30.0")
    msg = refusal(text)
    assert msg.startswith(f"m.toml:{line_of(text, 'c = { nominal')}: [parameters] c.nominal")
    assert "must be a positive length" in msg
    assert 'must be "sewtol-mechanism/1"' in refusal(FOUR_BAR.replace("/1", "/2", 1))
    assert "is not valid TOML" in refusal(FOUR_BAR + "\nbroken = [\n")
    assert "must be one of" in refusal(FOUR_BAR.replace('type = "speed"', 'type = "sped"'))
    assert "is already defined" in refusal(FOUR_BAR.replace('name = "D"', 'name = "A"'))
    msg = refusal(FOUR_BAR.replace('[tolerances.wide]\nb = 3.0', '[tolerances.wide]\ns = 1'))
    assert msg.startswith(f"m.toml:{line_of(FOUR_BAR, 'b = 3.0')}:")
    assert "never toleranced" in msg


def test_cli_refuses_bad_file_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(FOUR_BAR.replace('radius = "a"', 'radius = "__import__(\'os\')"'))
    code, out, err = run("run", str(bad), "nominal")
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert f"bad.toml:{line_of(FOUR_BAR, 'radius = ')}: [[groups]] B.radius" in err


# --- expressions --------------------------------------------------------------------------------

@pytest.mark.parametrize("text", [
    "__import__('os')", "a.real", "(lambda: 1)()", "a[0]", "sqrt(x=a)", "open('f')",
    "a if a else 1", "a < 1", "'s'", "[a]", "True",
])
def test_expression_whitelist_refuses(text):
    with pytest.raises(ExpressionError):
        parse_expression(text, {"a"})


def test_expression_values():
    e = parse_expression("2 * sin(radians(30)) + a ** 2 - -b / 4", {"a", "b"})
    assert e.names == ("a", "b")
    got = e({"a": np.array([1.0, 3.0]), "b": 8.0})
    np.testing.assert_allclose(got, [1.0 + 1.0 + 2.0, 1.0 + 9.0 + 2.0], rtol=0, atol=1e-15)
    assert parse_expression("degrees(atan2(1, 1)) + pi * 0")({}) == pytest.approx(45.0, abs=1e-13)


# --- equality with the built-in chains ----------------------------------------------------------

def test_needle_file_equals_builtin_chain_positions():
    mech = load(NEEDLE)
    values = needle_perturbations(mech)
    assert len(next(iter(values.values()))) == 5  # nominal + 4 perturbed machines
    worst, _ = needle_positions_residual(mech, values)
    assert worst <= 1e-9


def test_feed_file_equals_builtin_chain_positions():
    mech = load(FEED)
    rng = np.random.default_rng(3)
    names = ["O1F", "FK", "O4K", "DB", "A1B", "b", "O3C", "CR", "SV", "XL", "O7H", "IJ", "RS"]
    nominal = mech.nominal_values()
    values = {k: nominal[k] + np.concatenate([[0.0], rng.uniform(-0.05, 0.05, 3)]) for k in names}
    q = mech.angles_rad()
    state = mech.state(values, q)
    built = chains(P.column(Feed131().override(**values), 4), q[None, :])
    for name in ("F", "K", "M", "B", "C", "E", "N", "Q1", "R", "S", "V", "W", "L", "H", "J", "Y",
                 "Q2"):
        diff = np.abs(np.broadcast_to(built[name].p, state.shape) - state.points[name].p)
        assert np.max(diff) <= 1e-9, name
    assert np.max(np.abs(built["holder_angle"].a - state.angles["f"].a)) <= 1e-12


def test_feed_file_dog_bar_program_is_the_builtin_arithmetic():
    """dog_bar_program = 1 in the file moves Q1 as the built-in program arithmetic does: about
    2.3 um along the bar, equal to 1e-9 mm."""
    mech = load(FEED).override(dog_bar_program=1.0)
    q = mech.angles_rad()
    state = mech.state(None, q)
    built = chains(P.column(Feed131(dog_bar_program=1.0), None), q)
    exact = load(FEED).state(None, q).points["Q1"].p[0]
    assert np.max(np.abs(built["Q1"].p - state.points["Q1"].p[0])) <= 1e-9
    assert 2.0e-3 < np.min(np.abs(state.points["Q1"].p[0] - exact)) < 2.6e-3


def test_needle_sumdelta_matches_exact_figure():
    """The file samples 720 crank angles; the built-in finds the extremes exactly."""
    from sewtol.mechanisms.needle_208 import metrics as nm
    from sewtol.mechanisms.needle_208.model import Needle208

    exact = float(nm.deviation_figures(nm.columns(Needle208.nominal())[0]).total_um[0])
    generic = float(load(NEEDLE).evaluate(outputs=["SumDelta_um"]).outputs["SumDelta_um"][0])
    assert exact == pytest.approx(4.587047, abs=1e-6)
    assert abs(generic - exact) < 1e-3 and generic <= exact


# --- the fast path ------------------------------------------------------------------------------

def test_fast_path_refused_when_the_file_differs(tmp_path):
    text = NEEDLE.read_text().replace('offset_deg = "CBE"', 'offset_deg = "CBE + 0.001"')
    with pytest.raises(ParameterError) as info:
        loads(text, "n.toml")
    msg = str(info.value)
    assert "[mechanism] fast_path" in msg and "does not reproduce the built-in needle_208" in msg
    assert "E differs by" in msg
    assert msg.startswith(f"n.toml:{line_of(text, 'fast_path = ')}:")
    # without fast_path the same file loads and runs the generic study
    # the file's SumDelta must be the built-in's too (same guide, same figure)
    for old, new in (('angle_deg = "guide_angle"', 'angle_deg = "guide_angle + 0.01"'),
                     ("samples = 720", "samples = 36")):
        with pytest.raises(ParameterError, match="output SumDelta_um differs from the built-in "
                           r"SumDelta by \d"):
            loads(NEEDLE.read_text().replace(old, new), "n.toml")
    plain = text.replace('fast_path = "needle_208"\n', "")
    assert loads(plain, "n.toml").header.fast_path is None
    f = tmp_path / "n.toml"
    f.write_text(plain)
    code, out, err = run("run", str(f), "montecarlo", "--n", "50", "--seed", "7", "--format",
                         "csv")
    assert code == 0, err
    assert out.startswith("output,n,ok,") and "adjusted_beta" not in out


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_run_montecarlo_is_byte_identical_to_needle_montecarlo(fmt):
    a = run("run", str(NEEDLE), "montecarlo", "--n", "2000", "--seed", "7", "--format", fmt)
    b = run("needle", "montecarlo", "--n", "2000", "--seed", "7", "--format", fmt)
    assert a[0] == 0 and b[0] == 0
    assert a[1] == b[1]
    assert "adjusted_beta" in a[1]


# --- statuses, reproducibility ------------------------------------------------------------------

def test_status_counts_add_up_and_name_the_group():
    # b + c must reach a + d = 45 (B farthest from D at q = 180): b in [11, 17] around 14 fails
    # below b = 15, sits near the stretched dead point just above it, and runs beyond
    mech = loads(FOUR_BAR, "m.toml").override(b=14.0)
    res = MC.montecarlo(mech, mech.tolerance_sets["wide"], 400, 11, limit=20.0)
    c = res.counts("B_y_range_mm")
    assert c["ok"] + c["out_of_spec"] + c["cannot_close"] + c["dead_point"] == c["n"] == 400
    b = res.machines["b"].to_numpy() + 14.0
    status = res.machines["status"].to_numpy()
    assert c["cannot_close"] == int(np.sum(b < 15.0)) > 100
    assert c["dead_point"] > 0 and c["ok"] > 100
    assert np.all(status[b > 15.5] == "ok") and np.all(status[b < 15.0] == "cannot_close")
    assert set(res.machines.loc[status != "ok", "failed_group"]) == {"C"}
    assert res.machines.loc[status != "ok", "B_y_range_mm"].isna().all()
    assert res.failed_groups() == {"C": c["cannot_close"] + c["dead_point"]}


def test_dead_point_is_counted():
    mech = loads(FOUR_BAR, "m.toml")
    # b + c = a + d + eps: the dyad is almost stretched at q = 0 (transmission ~ 0)
    ev = mech.evaluate({"b": np.array([40.0, 15.0 + 1e-4, 15.0 - 1e-4])})
    assert list(ev.status) == ["ok", "dead_point", "cannot_close"]
    assert ev.counts() == {"ok": 1, "cannot_close": 1, "dead_point": 1, "n": 3}


def test_same_seed_same_table_and_counts_in_cli():
    mech = load(KHUJAND)
    ts = mech.tolerance_sets["illustrative"]
    a = MC.montecarlo(mech, ts, 300, 5)
    b = MC.montecarlo(mech, ts, 300, 5)
    c = MC.montecarlo(mech, ts, 300, 6)
    assert a.machines.equals(b.machines)
    assert not a.machines["E_x_range_mm"].equals(c.machines["E_x_range_mm"])
    code, out, err = run("run", str(KHUJAND), "montecarlo", "--n", "300", "--seed", "5",
                         "--format", "csv")
    assert code == 0, err
    assert out == run("run", str(KHUJAND), "montecarlo", "--n", "300", "--seed", "5",
                      "--format", "csv")[1]
    assert out.splitlines()[1].startswith("E_x_range_mm,300,300,0,0,0,")


def test_khujand_template_runs_nominal():
    code, out, err = run("run", str(KHUJAND), "nominal", "--format", "json")
    assert code == 0, err
    import json

    vals = json.loads(out)["outputs"]
    assert vals["E_x_range_mm"] == pytest.approx(6.5011, abs=1e-4)
    assert vals["transmission_BCD_deg"] > 60 and vals["transmission_NMH_deg"] > 50


# --- analytic outputs and transfer functions ----------------------------------------------------

def test_crank_pin_outputs_are_analytic():
    mech = loads(FOUR_BAR, "m.toml")
    ev = mech.evaluate({"a": np.array([5.0, 10.0])}, ["B_y_range_mm", "B_speed_m_s"])
    np.testing.assert_allclose(ev.outputs["B_y_range_mm"], [10.0, 20.0], atol=1e-12)
    omega = 600 * 2 * np.pi / 60
    np.testing.assert_allclose(ev.outputs["B_speed_m_s"], [5e-3 * omega, 10e-3 * omega],
                               rtol=1e-12)


@pytest.mark.parametrize("path", [FEED, KHUJAND])
def test_transfer_functions_match_finite_differences(path):
    mech = load(path)
    q = np.radians(np.arange(3.0, 360.0, 37.0))
    h = 1e-5
    s0, sp, sm = (mech.state(None, q + dq) for dq in (0.0, h, -h))
    for name, m0 in s0.points.items():
        fd1 = (sp.points[name].p - sm.points[name].p) / (2 * h)
        fd2 = (sp.points[name].p - 2 * m0.p + sm.points[name].p) / h**2
        np.testing.assert_allclose(m0.dp, fd1, atol=1e-6 * (1 + np.abs(m0.dp).max()), err_msg=name)
        np.testing.assert_allclose(m0.ddp, fd2, atol=2e-3 * (1 + np.abs(m0.ddp).max()),
                                   err_msg=name)
    for name, a0 in s0.angles.items():
        fd1 = (sp.angles[name].a - sm.angles[name].a) / (2 * h)
        np.testing.assert_allclose(a0.da, fd1, atol=1e-7, err_msg=name)


def test_worst_case_bounds_the_monte_carlo_sample():
    mech = load(KHUJAND)
    ts = mech.tolerance_sets["illustrative"]
    wc = W.worst_case(mech, ts, "E_x_range_mm").rows.set_index("extreme")["value"]
    sample = MC.montecarlo(mech, ts, 500, 2, outputs=["E_x_range_mm"]).machines["E_x_range_mm"]
    assert wc["min"] <= sample.min() and sample.max() <= wc["max"]
    assert wc["max"] - wc["min"] == pytest.approx(0.3038, abs=1e-3)


# --- the generic studies against the built-in needle model --------------------------------------

def test_transmission_outputs_match_the_exact_extremes():
    from sewtol.mechanisms.needle_208 import model as nd

    c = P.column(nd.Needle208.nominal(), None)
    lo, hi, _, _ = nd.rocker_interval(c)
    g1, _, g2, _ = nd.transmission_extremes(c, lo, hi)
    ev = load(NEEDLE).evaluate(outputs=["transmission_LMA_deg", "transmission_BCD_deg"])
    for name, exact in (("transmission_LMA_deg", g1), ("transmission_BCD_deg", g2)):
        sampled = float(ev.outputs[name][0])
        assert float(exact) <= sampled < float(exact) + 1e-2, name


def test_generic_worst_case_equals_builtin_fixed_beta_worst_case(nominal):
    from sewtol.tables.needle_208 import worst_case
    from sewtol.tolerances import NEEDLE_208_SETS

    built = worst_case(nominal, NEEDLE_208_SETS["base"], adjust=False)
    mech = load(NEEDLE)
    assert mech.nominal_values()["beta"] == built["beta_deg"]  # both keep the nominal beta
    rows = W.worst_case(mech, mech.tolerance_sets["base"], "SumDelta_um", fast=False).rows
    top = rows.set_index("extreme").loc["max"]
    assert top["value"] == pytest.approx(built["total_um"], abs=1e-3)  # 720 samples vs exact
    params = NEEDLE_208_SETS["base"].active().params
    assert {k: top[f"{k}_dev"] for k in params} == {k: built[f"{k}_mm"] for k in params}


def test_tolerances_breaking_a_rule_are_refused_before_running():
    text = FOUR_BAR.replace("[tolerances.wide]\nb = 3.0", "[tolerances.wide]\na = 11.0")
    mech = loads(text, "m.toml")
    with pytest.raises(ParameterError, match=r"wide\.a\.lower: .*a = -1.*must be a positive"):
        MC.montecarlo(mech, mech.tolerance_sets["wide"], 10, 0)


def test_missing_engine_module_is_refused_at_load():
    from sewtol.mechanism import GROUPS

    if GROUPS["spatial_rocker"].requires:
        import importlib.util

        if importlib.util.find_spec(GROUPS["spatial_rocker"].requires) is not None:
            pytest.skip("engine.spatial is present in this build")
    text = FOUR_BAR.replace('[[groups]]\ntype = "rrr"', '[[groups]]\ntype = "spatial_rocker"\n'
                            'name = "psi"\na = 1\nb = 1\nc = 1\ne = 1\nf = 1\ng = 1\n'
                            'alpha_deg = 90\n\n[[groups]]\ntype = "rrr"')
    msg = refusal(text)
    assert "needs sewtol.engine.spatial" in msg and "[[groups]] #4.type" in msg


def test_refusals_in_every_section_point_at_their_line():
    cases = [
        (FOUR_BAR.replace("rpm = 600", "rpm = 600\nspeed = 3"), "speed = 3",
         "[mechanism] speed: unknown key"),
        (FOUR_BAR.replace('axis = "y"', 'axis = "z"'), 'axis = "z"',
         "[[outputs]] B_y_range_mm.axis: must be one of x, y"),
        (FOUR_BAR.replace('group = "C"', 'group = "B"'), 'group = "B"',
         "[[outputs]] transmission_deg.group: must name a group with a transmission angle, "
         "an rrr, spatial_rocker or spatial_slider group (C)"),
        (FOUR_BAR.replace("rpm = 600\n", ""), 'type = "speed"',
         "[[outputs]] B_speed_m_s.type: needs rpm in [mechanism]"),
        (FOUR_BAR + '\n[compensators.k]\nparameter = "kk"\nlow = 0\nhigh = 1\n',
         'parameter = "kk"', "[compensators.k] parameter: must name a parameter"),
        (FOUR_BAR.replace("b = 3.0", "b = [1.0, -1.0]"), "b = [1.0, -1.0]",
         "[tolerances.wide] b: must not be above the upper limit"),
    ]
    for text, snippet, expected in cases:
        msg = refusal(text)
        assert msg.startswith(f"m.toml:{line_of(text, snippet)}: {expected}"), msg


def test_run_flags_tolerance_files_and_out(tmp_path):
    code, _, err = run("run", str(KHUJAND), "nominal", "--seed", "3")
    assert code == 2 and "--seed: is not used by `run nominal`" in err
    code, _, err = run("run", str(KHUJAND), "scan", "--output", "nope")
    assert code == 2 and "--output: must name an output of the file" in err
    code, _, err = run("run", str(KHUJAND), "scan", "--tolerances", "nope")
    assert code == 2 and "must be a set of the file (illustrative)" in err
    tol = tmp_path / "t.toml"
    tol.write_text("[sets.ab]\nAB = 0.1\n")
    code, out, err = run("run", str(KHUJAND), "scan", "--tolerances", str(tol), "--output",
                         "E_x_range_mm", "--format", "csv", "--out", str(tmp_path / "o"))
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == 3 and lines[1].startswith("AB,upper,0.1,E_x_range_mm,")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["run.json", "scan.csv",
                                                                 "scan.json"]


# --- [defaults] adjust: the compensators `run` adjusts when --adjust is not given ------------------

def test_defaults_adjust_is_checked_at_load():
    base = FOUR_BAR + '\n[compensators.k]\nparameter = "c"\nlow = 25\nhigh = 35\n'
    assert loads(base, "m.toml").default_adjust == ()
    assert loads(base + '\n[defaults]\nadjust = ["k"]\n', "m.toml").default_adjust == ("k",)
    cases = [
        ('adjust = ["q"]', "[defaults] adjust: must name compensators of the file (k) (got 'q')"),
        ('adjust = "k"', "[defaults] adjust: must be a list of one or more [compensators.NAME] "
                         "names (got 'k')"),
        ("adjust = []", "[defaults] adjust: must be a list of one or more"),
        ('adjust = ["k", "k"]', "[defaults] adjust: names a compensator twice"),
        ('output = "x"', "[defaults] output: unknown key; allowed: adjust"),
    ]
    for body, expected in cases:
        text = base + "\n[defaults]\n" + body + "\n"
        msg = refusal(text)
        assert msg.startswith(f"m.toml:{line_of(text, body, '[defaults]')}: {expected}"), msg


def test_only_the_needle_declares_a_default_adjustment():
    from sewtol.mechanisms import mechanism_file, names

    assert {n: load(mechanism_file(n)).default_adjust for n in names()
            if load(mechanism_file(n)).default_adjust} == {"needle_208": ("beta",)}


def test_run_takes_the_default_adjustment_unless_told_none(tmp_path):
    """A file's [defaults] adjust is --adjust when none is given; --adjust none is the file
    without it (the same bytes, on a file mechanism's generic path)."""
    base = FOUR_BAR + '\n[compensators.k]\nparameter = "c"\nlow = 25\nhigh = 35\n'
    plain, dflt = tmp_path / "plain.toml", tmp_path / "dflt.toml"
    plain.write_text(base)
    dflt.write_text(base + '\n[defaults]\nadjust = ["k"]\n')
    for study, argv in (("scan", ()), ("montecarlo", ("--n", "20", "--seed", "1"))):
        argv = (*argv, "--output", "transmission_deg", "--format", "json")

        def ctx_free(out):  # the file's name is in the context; nothing else may differ
            obj = strict_loads(out)
            obj["context"].pop("mechanism_file")
            return obj

        told = run("run", str(plain), study, *argv, "--adjust", "k")
        given = run("run", str(dflt), study, *argv)
        assert told[0] == given[0] == 0, told[2] + given[2]
        assert ctx_free(told[1]) == ctx_free(given[1])
        assert ctx_free(given[1])["context"]["strategy"] == "k"
        off = run("run", str(dflt), study, *argv, "--adjust", "none")
        bare = run("run", str(plain), study, *argv)
        assert ctx_free(off[1]) == ctx_free(bare[1])
        assert ctx_free(off[1])["context"]["strategy"] == "none"
    # studies outside scan, worst-case, montecarlo, ppm and allocation keep their own default
    code, out, err = run("run", str(dflt), "sobol", "--n", "16", "--output", "transmission_deg",
                         "--format", "json")
    assert code == 0 and strict_loads(out)["context"]["strategy"] == "none", err


# --- adjustment over a compensator ---------------------------------------------------------------

def test_adjusted_case_matches_the_builtin_beta_optimum(nominal):
    from cli_helpers import beta_adjusted
    from sewtol.tolerances import NEEDLE_208_SETS

    mech = load(NEEDLE)
    dev = NEEDLE_208_SETS["base"].sample(np.random.default_rng(1), 30)
    got = adjust(mech, {k: mech.nominal_values()[k] + v for k, v in dev.items()},
                 "SumDelta_um", "beta")
    exact = beta_adjusted(nominal, dev, (10.0, 35.0)).total_um
    d = got.value - exact
    # sampled extremes sit at most ~1 nm inside the exact ones (docs/mechanism_files.md)
    assert d.min() > -2e-3 and d.max() < 2e-3
    assert np.median(np.abs(d)) < 2e-3
    beta = got.settings["beta"]
    assert np.all((beta >= 10.0) & (beta <= 35.0)) and set(got.status) == {"ok"}


def test_adjusted_scan_equals_the_builtin_scan(nominal):
    from sewtol.tables.needle_208 import scan
    from sewtol.tolerances import NEEDLE_208_SETS

    mech = load(NEEDLE)
    rows = S.scan(mech, mech.tolerance_sets["base"], ["SumDelta_um"], adjust="beta", fast=False).rows
    rows = rows[rows["output"] == "SumDelta_um_adjusted"].reset_index(drop=True)
    built = scan(nominal, NEEDLE_208_SETS["base"]).to_dataframe()
    assert list(rows["param"]) == list(built["param"])
    np.testing.assert_allclose(rows["value"], built["total_um"], atol=2e-3)
    code, _, err = run("run", str(NEEDLE), "scan", "--adjust", "nope")
    assert code == 2 and "--adjust: must name a compensator of the file (beta, guide_shift)" in err


SLIDER_CRANK = """format = "sewtol-mechanism/1"

[mechanism]
name = "slider_crank"
samples = 360

[parameters]
r = { nominal = 12.0, unit = "mm", rule = "positive" }
l = { nominal = 50.0, unit = "mm", rule = "positive" }
e = { nominal = 3.0, unit = "mm", rule = "finite", doc = "offset of the slide line" }

[[groups]]
type = "point"
name = "A"
x = 0.0
y = 0.0

[[groups]]
type = "crank"
name = "B"
center = "A"
radius = "r"

[[groups]]
type = "rrp"
name = "J"
p1 = "B"
r = "l"
x = 0.0
y = "e"
angle_deg = 0.0
branch = 1

[[outputs]]
name = "stroke_mm"
unit = "mm"
type = "coordinate"
point = "J"
axis = "x"
measure = "range"

[[outputs]]
name = "custom_mm"
unit = "mm"
type = "custom"
kind = "test_twice_x_max"
point = "J"
"""


def test_slider_crank_file_is_analytic_and_closes():
    from sewtol.mechanism import OUTPUTS, register_output

    register_output("test_twice_x_max", lambda state, point: 2 * np.max(point.x, axis=-1),
                    fields={"point": ("point", None, None)})
    try:
        mech = loads(SLIDER_CRANK, "s.toml")
        q = mech.angles_rad()
        st = mech.state({"r": np.array([12.0, 8.0])}, q)
        r = np.array([[12.0], [8.0]])
        x = r * np.cos(q) + np.sqrt(50.0**2 - (r * np.sin(q) - 3.0) ** 2)
        np.testing.assert_allclose(st.points["J"].x, x, atol=1e-12)
        np.testing.assert_allclose(st.points["J"].y, 3.0, atol=1e-12)
        np.testing.assert_allclose(np.abs(st.points["J"].p - st.points["B"].p), 50.0, atol=1e-12)
        ev = mech.evaluate({"r": np.array([12.0, 8.0])})
        np.testing.assert_allclose(ev.outputs["custom_mm"], 2 * x.max(axis=1), atol=1e-12)
        # the exact offset slider-crank stroke: sqrt((l + r)^2 - e^2) - sqrt((l - r)^2 - e^2),
        # reached between the 1-deg samples of this file (each end at most r (0.5 deg)^2 / 2 in)
        exact = np.sqrt(62.0**2 - 9) - np.sqrt(38.0**2 - 9)
        assert exact - 2 * 12.0 * np.radians(0.5) ** 2 / 2 < ev.outputs["stroke_mm"][0] <= exact
        # the rrp joint misses where the rod cannot reach the line
        bad = mech.evaluate({"l": np.array([50.0, 14.0])})
        assert list(bad.status) == ["ok", "cannot_close"] and bad.failed_group[1] == "J"
    finally:
        del OUTPUTS["test_twice_x_max"]
    assert "must name a registered output kind" in refusal(SLIDER_CRANK)


def test_rrr_links_keep_their_lengths_in_the_template():
    mech = load(KHUJAND)
    st = mech.state()
    v = mech.nominal_values()
    for a, b, length in (("B", "C", "BC"), ("D", "C", "CD"), ("N", "M", "NM"), ("H", "M", "HM")):
        np.testing.assert_allclose(np.abs(st.points[a].p - st.points[b].p), v[length],
                                   atol=1e-11)


def test_sobol_of_a_file_output_that_depends_on_one_parameter():
    text = FOUR_BAR.replace("[tolerances.wide]\nb = 3.0", "[tolerances.wide]\na = 0.5\nb = 0.5")
    mech = loads(text, "m.toml")
    res = so.sobol(mech, mech.tolerance_sets["wide"], "B_y_range_mm", 64, 3)
    ix = res.to_dataframe().set_index("param")
    # B_y_range = 2a exactly: b has no effect at all, a explains everything
    assert ix.loc["b", "ST"] == 0.0 and ix.loc["b", "S1"] == 0.0
    assert ix.loc["a", "ST"] == pytest.approx(1.0, abs=0.05)
    assert ix.loc["a", "S1"] == pytest.approx(1.0, abs=0.1)
    # a box where some machines cannot close: counted per outcome and group (studies.sobol
    # POLICY), never refused, never dropped
    wide = loads(text.replace("a = 0.5", "a = [-5.0, 19.0]"), "m.toml")
    c = so.sobol(wide, wide.tolerance_sets["wide"], "B_y_range_mm", 64, 3).counts()
    c = c["B_y_range_mm"]
    failed = c["cannot_close"] + c["dead_point"]
    assert c["rows"] == 256 == c["assembled"] + failed and failed > 0
    assert sum(c["failed_groups"].values()) == failed


def test_a_nominal_that_cannot_run_names_group_angle_and_gap():
    code, out, err = run("run", str(NEEDLE), "nominal", "--set", "CD=5")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith("sewtol: error: dyad C cannot close at angle ")
    assert "the nominal machine cannot make a full turn" in err
    # the largest gap on the sampled cycle: the built-in's exact worst gap is 17.1984 mm
    gap = float(err.split("misses by ")[1].split(" mm")[0])
    assert 17.0 < gap <= 17.1984


def test_spatial_rocker_group_is_wired_to_engine_spatial(monkeypatch):
    """The group calls engine.spatial.spatial_rocker(phi, a, b, c, e, f, g, alpha_rad, branch)
    (H2's contract); a stand-in module checks the wiring until the real one is merged."""
    import sys
    import types

    from sewtol import engine

    calls = []

    def spatial_rocker(phi, a, b, c, e, f, g, alpha_rad, branch):
        calls.append((float(np.ravel(a)[0]), float(np.ravel(alpha_rad)[0]), float(branch)))
        psi = engine.Angle(0.5 * phi.a + a, 0.5 * phi.da, 0.5 * phi.dda)
        return psi, engine.Closure(np.zeros(np.broadcast(phi.a, a).shape),
                                   np.full(np.broadcast(phi.a, a).shape, 45.0))

    stub = types.ModuleType("sewtol.engine.spatial")
    stub.spatial_rocker = spatial_rocker
    monkeypatch.setitem(sys.modules, "sewtol.engine.spatial", stub)
    monkeypatch.setattr(engine, "spatial", stub, raising=False)
    text = FOUR_BAR.replace('[[groups]]\ntype = "rrr"', '[[groups]]\ntype = "spatial_rocker"\n'
                            'name = "psi"\na = 0.25\nb = 1\nc = 1\ne = 1\nf = 1\ng = 1\n'
                            'alpha_deg = 90\nbranch = -1\n\n[[groups]]\ntype = "rrr"')
    text += ('\n[[outputs]]\nname = "psi_range_deg"\nunit = "deg"\ntype = "angle"\n'
             'angle = "psi"\nmeasure = "range"\n')
    mech = loads(text, "m.toml")
    ev = mech.evaluate(outputs=["psi_range_deg"])
    assert calls[-1] == (0.25, pytest.approx(np.pi / 2), -1.0)
    assert ev.outputs["psi_range_deg"][0] == pytest.approx(0.5 * 359.0)  # half of q's span
