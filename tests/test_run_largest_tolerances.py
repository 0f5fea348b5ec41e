"""`sewtol run NAME|FILE largest-tolerances` (and `sewtol needle largest-tolerances`, its alias)
on any mechanism (sewtol.studies.scan.largest_tolerances): the closed form of a centred
crank-slider, the needle API's numbers on the needle file, and one-line refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanism import load

ROOT = Path(__file__).resolve().parents[1]
SLIDER = str(ROOT / "tests" / "data" / "crank_slider.toml")
# the bisection stops within 1e-5 of the crossing (studies.scan.largest_tolerances' xtol)
XTOL = 1e-5


def _rows(*argv):
    code, out, err = run("run", *argv, "--format", "json")
    assert code == 0 and err == "", err
    obj = strict_loads(out)
    return obj, {(r["param"], r["side"]): r for r in obj["rows"]}


def test_the_centred_crank_slider_keeps_its_closed_form():
    """stroke = 2 r exactly, whatever L: with stroke <= 20.02 mm the crank may grow by 0.01 mm
    and shrink by as much as the search goes (half its 10 mm, capped at 1 mm); the rod never
    matters. The set's own limits (normal set: +-0.03 mm, +-0.1 mm) stand beside them."""
    obj, rows = _rows(SLIDER, "largest-tolerances", "--output", "stroke_mm", "--limit", "20.02")
    assert obj["output"] == "stroke_mm" and obj["limit"] == 20.02 and obj["nominal"] == 20.0
    assert abs(rows["r", "upper"]["largest_deviation"] - 0.01) <= XTOL
    assert not rows["r", "upper"]["reaches_max"]
    for key in (("r", "lower"), ("L", "upper"), ("L", "lower")):
        assert rows[key]["reaches_max"]
        assert abs(rows[key]["largest_deviation"]) == rows[key]["max_deviation"] == 1.0
    assert [rows[k]["set_deviation"] for k in (("r", "upper"), ("r", "lower"), ("L", "upper"))] \
        == [0.03, -0.03, 0.1]
    # the found deviation sits on the limit: just inside keeps it, just beyond breaks it
    mech = load(SLIDER)
    r = 10.0 + rows["r", "upper"]["largest_deviation"] + np.array([-XTOL, XTOL])
    stroke = mech.evaluate({"r": r}, ["stroke_mm"]).outputs["stroke_mm"]
    assert stroke[0] <= 20.02 < stroke[1]
    assert obj["context"]["spec_source"] == "command line" and obj["context"]["path"] == "generic"


def test_the_needle_file_gives_the_apis_numbers(tmp_path):
    """On the needle file, beta adjusted by default (the file's [defaults] adjust, by its exact
    plug-in), the rows are those of the API (tables.needle_208.largest_tolerances: beta*
    re-optimised per machine) for the same parts, to the two searches' bisection tolerances;
    the limit is the file's spec (SumDelta <= 10 um). `needle largest-tolerances` is this
    command (tests/test_needle_run_forms.py)."""
    from sewtol import Needle208
    from sewtol.tables.needle_208 import largest_tolerances

    small = tmp_path / "small.toml"
    small.write_text("[sets.small]\nAB = 0.05\nLF = 0.05\nCD = 0.05\n")
    obj, rows = _rows("needle_208", "largest-tolerances", "--tolerances", f"{small}:small")
    assert obj["limit"] == 10.0 and obj["context"]["spec_source"] == "file"
    assert obj["context"]["path"] == "needle_208" and obj["context"]["strategy"] == "beta"
    api = largest_tolerances(Needle208.nominal(), ["AB", "LF", "CD"]).to_dict("records")
    assert len(api) == len(rows) == 6
    for r in api:
        mine = rows[r["param"], r["side"]]
        assert abs(mine["largest_deviation"] - r["largest_delta_mm"]) <= 2 * XTOL, r
        assert mine["reaches_max"] == r["reaches_max"]
    # AB alone breaks 10 um near 7.5 um of deviation, LF's lower side never (within 1 mm); the
    # tightest side, CD's lower, as the report quotes it (-0.0066 mm)
    assert 0.007 < rows["AB", "upper"]["largest_deviation"] < 0.008
    assert rows["LF", "lower"]["reaches_max"]
    assert round(rows["CD", "lower"]["largest_deviation"], 4) == -0.0066
    # --adjust none holds beta at the file's value: no side gets wider
    _, fixed = _rows("needle_208", "largest-tolerances", "--tolerances", f"{small}:small",
                     "--adjust", "none")
    assert all(abs(fixed[k]["largest_deviation"]) <= abs(rows[k]["largest_deviation"]) + XTOL
               for k in rows)


@pytest.mark.parametrize("argv,where,rule", [
    (("spatial_crank_rocker", "largest-tolerances"), "--limit", "must be given"),
    (("spatial_crank_rocker", "largest-tolerances", "--limit", "48", "--lower-limit", "3"),
     "--lower-limit", "is not used by `run largest-tolerances`"),
    ((SLIDER, "largest-tolerances", "--output", "stroke_mm", "--limit", "19.9"), "--limit",
     "must be at or above the nominal machine's stroke_mm (20)"),
    ((SLIDER, "largest-tolerances", "--output", "stroke_mm", "--limit", "inf"), "--limit",
     "must be a finite number"),
    ((SLIDER, "largest-tolerances", "--n", "10", "--limit", "20.02"), "--n", "is not used"),
    (("needle_208", "largest-tolerances", "--beta-range", "10", "30"), "--beta-range",
     "is not used by `run largest-tolerances`"),
])
def test_bad_flags_are_one_line_naming_the_flag_and_the_rule(argv, where, rule):
    code, out, err = run("run", *argv)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert err.startswith(f"sewtol: error: {where}: {rule}"), err


def test_a_file_spec_with_a_lower_limit_is_refused_and_limit_replaces_it(tmp_path):
    """The search holds an upper limit: a two-sided spec of the file is refused in one line
    naming the spec, and --limit alone replaces it (as in every yield study)."""
    path = tmp_path / "slider.toml"
    path.write_text(Path(SLIDER).read_text() + '\n[[specs]]\noutput = "stroke_mm"\nlower = 19.9'
                    '\nupper = 20.1\n')
    code, out, err = run("run", str(path), "largest-tolerances")
    assert code == 2 and err.startswith("sewtol: error: [[specs]] stroke_mm: must have no lower "
                                        "limit") and "(got 19.9)" in err
    obj, rows = _rows(str(path), "largest-tolerances", "--limit", "20.1")
    assert abs(rows["r", "upper"]["largest_deviation"] - 0.05) <= XTOL
