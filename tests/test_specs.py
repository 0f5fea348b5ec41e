"""Specs as data ([[specs]] in a mechanism file): checked at load, used by default by every
generic yield study, overridden by --limit/--lower-limit; and one Monte-Carlo JSON shape on the
needle's two paths.

The analytic case is tests/data/crank_slider.toml (stroke = 2 r exactly), as in
test_generic_studies.py; the needle's spec is the source's 10 um."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_helpers import run, strict_loads
from sewtol.errors import ParameterError
from sewtol.mechanism import load, loads
from sewtol.mechanism.spec import Spec
from sewtol.studies import montecarlo as MC
from sewtol.studies import rare_event as PPM

DATA = Path(__file__).parent / "data" / "crank_slider.toml"
TEXT = DATA.read_text()
NEEDLE = str(Path(__file__).resolve().parents[1] / "examples" / "needle_208.toml")
SPEC = '\n[[specs]]\noutput = "stroke_mm"\nupper = 20.02\nlower = 19.98\ndoc = "2 r +/- 0.02"\n'


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "crank_slider_spec.toml"
    path.write_text(TEXT + SPEC)
    return path


def test_spec_passes_and_excess_are_vectorised_and_nan_fails():
    s = Spec("y", upper=2.0, lower=-1.0)
    y = np.array([-2.0, -1.0, 0.5, 2.0, 3.5, np.nan])
    np.testing.assert_array_equal(s.passes(y), [False, True, True, True, False, False])
    np.testing.assert_array_equal(s.excess(y), [1.0, 0.0, -1.5, 0.0, 1.5, np.nan])
    np.testing.assert_array_equal(Spec("y", lower=0.0).excess([2.0, -3.0]), [-2.0, 3.0])
    assert Spec("y", upper=10).upper == 10.0 and isinstance(Spec("y", upper=10).upper, float)


@pytest.mark.parametrize("body, where, rule", [
    ('output = "stroke"\nupper = 1.0', "[[specs]] #1.output", "must name an output of the file"),
    ('output = "stroke_mm"', "[[specs]] stroke_mm.upper", "give an upper and/or a lower limit"),
    ('output = "stroke_mm"\nupper = nan', "[[specs]] stroke_mm.upper", "must be a finite number"),
    ('output = "stroke_mm"\nupper = "20"', "[[specs]] stroke_mm.upper", "must be a finite number"),
    ('output = "stroke_mm"\nupper = 19.0\nlower = 19.0', "[[specs]] stroke_mm.lower",
     "must be below the upper limit 19"),
    ('output = "stroke_mm"\nupper = 1.0\nlimit = 2.0', "[[specs]] #1.limit", "unknown key"),
])
def test_a_bad_spec_is_refused_at_load_naming_line_field_rule_and_value(body, where, rule):
    text = TEXT + "\n[[specs]]\n" + body + "\n"
    line = TEXT.count("\n") + 2  # the [[specs]] header, or the key that breaks the rule
    with pytest.raises(ParameterError) as exc:
        loads(text, "m.toml")
    assert exc.value.field.startswith("m.toml:") and exc.value.field.endswith(where)
    assert line <= int(exc.value.field.split(":")[1]) <= text.count("\n")
    assert exc.value.rule.startswith(rule)


def test_one_spec_per_output():
    with pytest.raises(ParameterError, match=r"stroke_mm\.output: has a spec already"):
        loads(TEXT + SPEC + SPEC, "m.toml")


def test_the_needle_file_states_the_source_criterion():
    mech = load(NEEDLE)
    (spec,) = mech.specs
    assert (spec.output, spec.upper, spec.lower) == ("SumDelta_um", 10.0, None)
    assert "source" in spec.doc and mech.resolve_spec() == ("SumDelta_um", spec, "file")
    # the command line replaces the file's spec of that output, both limits together
    out, given, source = mech.resolve_spec(None, None, 2.0)
    assert (out, given.upper, given.lower, source) == ("SumDelta_um", None, 2.0, "command line")


def test_montecarlo_counts_by_the_file_spec_or_the_flags(spec_file):
    """out_of_spec = the machines whose 2 r lies outside the limits, counted from the table;
    the flags replace the file's spec; counts add up to n."""
    code, out, err = run("run", str(spec_file), "montecarlo", "--tolerances", "normal",
                         "--n", "500", "--seed", "1", "--format", "json")
    assert code == 0, err
    d = strict_loads(out)
    mech = load(spec_file)
    res = MC.montecarlo(mech, mech.tolerance_sets["normal"], 500, 1)
    r2 = res.machines["stroke_mm"].to_numpy()
    inside = int(np.sum((r2 >= 19.98) & (r2 <= 20.02)))
    assert 0 < inside < 500
    assert d["output"] == "stroke_mm" and d["cases"] == ["fixed"]
    assert d["counts"]["fixed"] == {"ok": inside, "out_of_spec": 500 - inside, "cannot_close": 0,
                                    "dead_point": 0, "unexplained": 0, "failed": 0, "n": 500}
    assert d["yields"]["fixed"] == inside / 500
    assert d["spec"] == {"output": "stroke_mm", "upper": 20.02, "lower": 19.98,
                         "doc": "2 r +/- 0.02"}
    assert d["context"]["spec_source"] == "file"
    code, out, err = run("run", str(spec_file), "montecarlo", "--tolerances", "normal",
                         "--n", "500", "--seed", "1", "--lower-limit", "20.0", "--format", "json")
    d = strict_loads(out)
    assert d["context"]["spec_source"] == "command line"
    assert d["spec"]["upper"] is None and d["spec"]["lower"] == 20.0
    assert d["counts"]["fixed"]["ok"] == int(np.sum(r2 >= 20.0))
    assert sum(d["counts"]["fixed"][k] for k in ("ok", "out_of_spec", "failed")) == 500


def test_yield_studies_take_the_file_spec_by_default(spec_file):
    """ppm, allocation and report without flags give what the flags give."""
    flags = ("--limit", "20.02", "--lower-limit", "19.98")
    for argv in (("ppm", "--tolerances", "normal", "--method", "mc", "--n", "2000"),
                 ("allocation", "--tolerances", "uniform", "--n", "500")):
        _, a, err = run("run", str(spec_file), *argv, "--format", "json")
        _, b, _ = run("run", str(DATA), *argv, *flags, "--format", "json")
        da, db = strict_loads(a), strict_loads(b)
        assert da["context"]["spec_source"] == "file", err
        assert db["context"]["spec_source"] == "command line"
        keys = ("probability", "ci95", "pass_condition") if argv[0] == "ppm" else \
            ("scale", "yield", "trials")
        for key in keys:
            assert da[key] == db[key], key
        assert da.get("probability", 1) > 0 and da.get("scale", 1) > 0
    mech = load(spec_file)
    assert PPM.limits_of(mech, "stroke_mm", None, None) == (20.02, 19.98)
    assert PPM.limits_of(mech, "stroke_mm", 21.0, None) == (21.0, None)
    with pytest.raises(ParameterError, match="limit: give an upper limit"):
        PPM.limits_of(mech, "J_x_max_mm", None, None)  # no spec for that output


def test_report_yield_uses_the_file_spec(spec_file, tmp_path):
    from sewtol.reports import generic_report as GR

    mech = load(spec_file)
    rep = GR.build(mech, mech.tolerance_sets["normal"], 200, 3)
    flags = GR.build(load(DATA), mech.tolerance_sets["normal"], 200, 3, "stroke_mm", 20.02, 19.98)
    assert rep.yield_row == flags.yield_row and rep.yield_row["condition"] == \
        "19.98 mm <= stroke_mm <= 20.02 mm"
    r = rep.yield_row
    assert r["ok"] + r["out_of_limits"] + r["cannot_close"] + r["dead_point"] == r["n"] == 200


def test_montecarlo_json_is_one_shape_on_both_needle_paths(tmp_path):
    """`run needle_208 montecarlo` (beta adjusted: the file's [defaults] adjust) on the fast
    path (exact SumDelta, beta* searched by the needle's optimiser) and on the generic path
    (SumDelta over 720 sampled crank angles, beta by optimise_compensator): the same keys,
    counts, yields and intervals.
    SumDelta differs by at most ~1e-3 um between the paths (sampling, and the fixed case's beta:
    the file's nominal 22.58488 against the nominal's beta* 22.58471), so equal counts need no
    machine within that of 10 um: at seed 3, n 400 the nearest sits 0.197 um away (checked
    below on the generic path's machines)."""
    # (an explicit --adjust on the fast path is the needle's, with the strategy's rows)
    argv = ("run", "needle_208", "montecarlo", "--n", "400", "--seed", "3", "--format", "json")
    code, a, err = run(*argv)
    assert code == 0, err
    code, b, err = run(*argv, "--path", "generic", "--out", str(tmp_path / "g"))
    assert code == 0, err
    fast, generic = strict_loads(a), strict_loads(b)
    assert fast["context"]["path"] == "needle_208" and generic["context"]["path"] == "generic"
    assert set(fast) == set(generic)
    for key in ("n", "seed", "tolerances", "output", "unit", "cases", "failed", "counts",
                "yields", "yield_ci"):
        assert fast[key] == generic[key], key
    assert fast["cases"] == ["fixed_beta", "adjusted_beta"]
    assert {k: v for k, v in fast["spec"].items() if k != "doc"} == \
        {k: v for k, v in generic["spec"].items() if k != "doc"}
    assert fast["quantiles"]["definition"] == generic["quantiles"]["definition"]
    for case in fast["cases"]:
        c = fast["counts"][case]
        assert c["ok"] + c["out_of_spec"] + c["failed"] == 400 and 0 < c["ok"] < 400
        for q, v in fast["quantiles"][case].items():
            assert abs(v - generic["quantiles"][case][q]) <= 1e-3
    m = pd.read_csv(tmp_path / "g" / "machines.csv", comment="#")
    for col in ("SumDelta_um", "SumDelta_um_adjusted"):
        assert np.min(np.abs(m[col] - 10.0)) > 0.1
    assert {"capability", "beta_at_bound"} <= set(fast["extra"])
    assert {"summary", "failed_groups"} <= set(generic["extra"])
