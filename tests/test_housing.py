"""Housing tolerances in every study: the built-in housing variants of the needle's sets (the
upper-shaft bore A, the rear-rocker pivot D and the guide bore, assumed), equal in the package,
the mechanism file and the example file, and taken by every needle study by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run, strict_loads
from sewtol.errors import ParameterError
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file
from sewtol.mechanisms.needle_208.compensators import strategy_of
from sewtol.tables.needle_208 import allocate
from sewtol.tolerances import (
    NEEDLE_208_HOUSING,
    NEEDLE_208_HOUSING_SETS,
    NEEDLE_208_SETS,
    Tolerance,
    ToleranceSet,
    needle_set,
    with_housing,
)

ROOT = Path(__file__).resolve().parents[1]
HOUSING = ("Ax", "Ay", "Dx", "Dy", "guide_x", "guide_y", "guide_angle")


def _items(ts):
    return {t.param: (t.lower, t.upper, t.dist) for t in ts.items}


@pytest.mark.parametrize("name", ["base", "recommended"])
def test_every_built_in_set_has_its_housing_variant_equal_in_package_file_and_example(name):
    built = NEEDLE_208_HOUSING_SETS[f"{name}_housing"]
    in_file = load(mechanism_file("needle_208")).tolerance_sets[f"{name}_housing"]
    example = needle_set(str(ROOT / "examples" / "tolerances" / "needle_208_housing.toml")
                         + f":{name}_housing")
    assert built.as_dict() == in_file.as_dict() == example.as_dict()
    assert built.description == in_file.description == example.description
    assert needle_set(f"{name}_housing") is built
    items = _items(built)
    assert {k: v for k, v in items.items() if k not in HOUSING} == _items(NEEDLE_208_SETS[name])
    assert {k: items[k] for k in HOUSING} == {
        **{k: (-0.02, 0.02, "uniform") for k in HOUSING[:-1]},
        "guide_angle": (-0.0229, 0.0229, "uniform")}
    # 0.02 mm over the 50 mm guide
    assert np.degrees(np.arctan(0.02 / 50)) == pytest.approx(0.0229, abs=1e-4)


def test_the_sets_the_committed_reports_rest_on_are_unchanged():
    assert list(NEEDLE_208_SETS) == ["base", "recommended"]
    assert _items(NEEDLE_208_SETS["base"]) == {
        "LF": (-0.05, 0.05, "uniform"), "LM": (-0.5, 0.5, "uniform"),
        "AM": (-0.1, 0.1, "uniform"), "AB": (-0.05, 0.05, "uniform"),
        "BC": (-0.05, 0.05, "uniform"), "BE": (-0.05, 0.05, "uniform")}
    assert _items(NEEDLE_208_SETS["recommended"]) == {
        "LF": (-0.8, 0.25, "uniform"), "LM": (-0.5, 0.5, "uniform"),
        "AM": (-0.5, 0.5, "uniform"), "AB": (-0.05, 0.05, "uniform"),
        "BC": (-0.05, 0.05, "uniform"), "BE": (-0.05, 0.05, "uniform"),
        "CD": (-0.01, 0.01, "uniform")}


def test_with_housing_refuses_a_set_that_tolerances_a_housing_feature_already():
    own = ToleranceSet("mine", (Tolerance("LF", -0.05, 0.05), Tolerance("Ay", -0.1, 0.1)))
    with pytest.raises(ParameterError) as e:
        with_housing(own)
    assert "Ay" in str(e.value) and "mine" in str(e.value)
    assert with_housing(NEEDLE_208_SETS["base"], name="x").name == "x"
    assert len(NEEDLE_208_HOUSING) == 7


# every needle study takes the housing sets by name: where its answer lists the parameters
# (scan, worst case, Sobol, allocation) the housing features are among them; where it does not
# (Monte-Carlo, strategies, failures per million) it differs from the base set's on the seed
LISTS = {
    "scan": (["scan"], lambda o: {r["param"] for r in o["rows"]}),
    "worst-case": (["worst-case"], lambda o: {k[:-3] for k in o["rows"][0] if k.endswith("_mm")}),
    "sobol": (["sobol", "--n", "16", "--seed", "1"],
              lambda o: {r["param"] for r in o["indices"]}),
    "allocation": (["allocation", "--n", "40", "--seed", "1"],
                   lambda o: {r["param"] for r in o["rows"]}),
}
ANSWERS = {
    "montecarlo": (["montecarlo", "--n", "40", "--seed", "1"], lambda o: o["quantiles"]),
    "strategies": (["strategies", "--n", "10", "--seed", "1"],
                   lambda o: [r["p50_um"] for r in o["rows"]]),
    "ppm": (["ppm", "--budget", "200", "--target", "0.1", "--seed", "1"],
            lambda o: o["probability"]),
}


def _json(*argv):
    code, out, err = run("needle", *argv, "--format", "json")
    assert code == 0, err
    return strict_loads(out)


@pytest.mark.parametrize("study", list(LISTS))
def test_every_needle_study_takes_the_housing_set_and_answers_for_its_features(study):
    argv, params = LISTS[study]
    obj = _json(*argv, "--tolerances", "base_housing")
    assert obj["context"]["tolerances"] == "base_housing"
    assert set(HOUSING) <= params(obj), (study, sorted(params(obj)))


@pytest.mark.parametrize("study", list(ANSWERS))
def test_the_housing_set_changes_the_answer_of_every_sampling_study(study):
    argv, answer = ANSWERS[study]
    housing = _json(*argv, "--tolerances", "base_housing")
    base = _json(*argv, "--tolerances", "base")
    assert housing["context"]["tolerances"] == "base_housing"
    assert answer(housing) != answer(base)


def test_allocation_holds_a_tolerance_the_strategy_cancels_alone_and_meets_the_target(nominal):
    """Under beta + guide shift the guide bore's position has no slope (the shift cancels it
    alone): it is held at its reference limits, the others are scaled, and the yield on the
    allocation's common random numbers still meets the target."""
    strat = strategy_of(("beta", "guide_shift_um"))
    a = allocate(nominal, "base_housing", target=0.9, n=60, seed=3, strategy=strat, steps=6)
    t = a.to_dataframe().set_index("param")
    assert t.loc[["guide_x", "guide_y"], "held_at_reference"].all()
    assert (t.loc[["guide_x", "guide_y"], "slope_um_per_mm"] * 0.02 < 1e-3).all()
    assert (t.loc[["guide_x", "guide_y"], "upper_mm"] == 0.02).all()
    assert not t.drop(index=["guide_x", "guide_y"])["held_at_reference"].any()
    assert a.yield_ >= 0.9
    # the others were scaled from their shapes, not collapsed to nothing (they fell to 1e-9 mm
    # when the held ones were scaled with them)
    assert (t.drop(index=["guide_x", "guide_y"])["upper_mm"] > 1e-3).all()


def test_the_housing_share_table_adds_up(tmp_path):
    """studies/needle_208_housing.py on a small run: the ST shares of each case add up to
    100 %, the two group rows are the sums of their members (7 housing features, 6 links), and
    the headline quotes the housing row."""
    import json

    import pandas as pd

    from cli_helpers import study_script

    script = study_script("needle_208_housing")
    assert script.main(["--out", str(tmp_path), "--n-sobol", "32", "--n", "60"]) == 0
    folder = tmp_path / "needle_208"
    t = pd.read_csv(folder / "housing_share.csv", comment="#")
    params, groups = t[~t.param.str.contains(r"\(all")], t[t.param.str.contains(r"\(all")]
    assert sorted(params[params.group == "housing"].param) == sorted(HOUSING)
    assert len(params[params.group == "link"]) == 6
    # the CSV prints 9 significant digits: 13 values of up to 100 % each round by <= 5e-7
    for col in ("ST_share_fixed_beta_pct", "ST_share_adjusted_beta_pct"):
        assert params[col].sum() == pytest.approx(100.0, abs=13 * 5e-7)
        assert groups[col].sum() == pytest.approx(100.0, abs=2 * 5e-7)
    for g, row in groups.set_index("group").iterrows():
        members = params[params.group == g]
        for col in ("ST_fixed_beta", "ST_adjusted_beta", "eta2_share_beta_shift_pct"):
            assert row[col] == pytest.approx(members[col].sum(), rel=1e-8, abs=7 * 5e-7), (g, col)
    obj = json.loads((folder / "housing_share.json").read_text())
    housing = groups.set_index("group").loc["housing"]
    assert f"{housing.ST_share_adjusted_beta_pct:.0f} % with beta adjusted" in obj["headline"]


def test_the_housing_flag_adds_the_housing_to_any_set_and_refuses_it_twice():
    """--housing on a user's file set: the scan answers for the housing features under the
    name SET_housing, and its rows equal those of the built-in base_housing for the base set;
    a set that tolerances a housing feature already is refused in one line."""
    flag = _json("scan", "--tolerances", "base", "--housing")
    named = _json("scan", "--tolerances", "base_housing")
    assert flag["context"]["tolerances"] == "base_housing"
    assert flag["rows"] == named["rows"]
    code, out, err = run("needle", "scan", "--tolerances", "base_housing", "--housing")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "Ax: is toleranced by set 'base_housing' already" in err
