"""Nominal refinement (sewtol.studies.refine, `sewtol run FILE refine`).

The refined designs of studies/needle_208_refine.py (tests/data/refined_needle_208.json, the
JSON parameters as `sewtol needle nominal --set` takes them) are re-evaluated three ways: the
fused kernel (the path the search used), the generic sampled path of the mechanism file
(examples/needle_208.toml with the refined nominals) and an independent numpy model written from
the description (tests/refine_reference.py). Small searches check the study's invariants:
below the start, constraints hold, same seed same answer, influence equals its definition.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run
from refine_reference import figures, figures_root
from sewtol.errors import ParameterError
from sewtol.mechanism import load
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.model import Needle208, check_assembly, transmission_extremes
from sewtol.protocol import plugins
from sewtol.studies import refine as RF
from sewtol.studies import robust as RB
from sewtol.studies.adjusting import adjusted

ROOT = Path(__file__).resolve().parents[1]
FILE = ROOT / "examples" / "needle_208.toml"
DESIGNS_FILE = Path(__file__).parent / "data" / "refined_needle_208.json"
# the designs the study wrote (housing kept, guide refitted, the smallest set of links)
NAMES = tuple(json.loads(DESIGNS_FILE.read_text())["designs"]) if DESIGNS_FILE.exists() else ()
TODAY_UM = 4.59  # the figure of today's design (sewtol needle nominal: 4.587)
ADJUSTER_TOL_UM = 1e-3  # the exact adjuster's plateau tolerance (adjust.PLATEAU_TOL_UM)


@pytest.fixture(scope="module")
def mech():
    return load(FILE)


def _design(name):
    d = json.loads(DESIGNS_FILE.read_text())["designs"][name]
    return d, load(FILE, d["parameters"])


@pytest.mark.parametrize("name", NAMES)
def test_refined_design_is_reevaluated_by_the_generic_path(name):
    # (the file holds at least the housing-kept design: test_the_study_wrote_its_designs)
    """The JSON parameters, loaded as the file's nominals: the generic (sampled) SumDelta lies
    within the kernel's derived bound below the fused one, which is the claimed figure."""
    d, refined = _design(name)
    ev = refined.evaluate(None, ["SumDelta_um", "stroke_um", "transmission_LMA_deg",
                                 "transmission_BCD_deg"])
    assert ev.status[0] == "ok"
    pl = plugins(refined)
    fused = float(pl.kernel(refined, {})["SumDelta_um"][0])
    bound = float(pl.kernel_bound(refined, {})["SumDelta_um"][0])
    generic = float(ev.outputs["SumDelta_um"][0])
    assert 0.0 <= fused - generic <= bound
    # the claim is the adjuster's value at these settings: the fused figure there
    assert fused == pytest.approx(d["refined"]["SumDelta_um"], abs=ADJUSTER_TOL_UM)
    # at least threefold below today's, every constraint as claimed
    assert d["refined"]["SumDelta_um"] <= TODAY_UM / 3
    for c in d["constraints"]:
        y = float(ev.outputs[c["output"]][0])
        assert y == pytest.approx(d["refined"][c["output"]], abs=1e-6)
        assert c["lower"] is None or y >= c["lower"]
        assert c["upper"] is None or y <= c["upper"]


@pytest.mark.parametrize("name", NAMES)
def test_refined_design_checked_by_the_independent_model(name):
    """An independent numpy model (72000 crank angles, no sewtol code) gives the same SumDelta,
    a stroke inside the +-0.1 mm band and transmission angles >= 40 deg; the built-in model's
    exact figures (rocker interval, closed-form transmission extremes) agree."""
    d, refined = _design(name)
    values = refined.nominal_values()
    ind = figures(values)
    assert ind["closes"]
    # dense sampling lies below the exact extremes by < 1e-6 um here (h^2 |d''| / 8)
    assert ind["SumDelta_um"] == pytest.approx(d["refined"]["SumDelta_um"], abs=ADJUSTER_TOL_UM)
    stroke = next(c for c in d["constraints"] if c["output"] == "stroke_um")
    # the sampled stroke of the file lies below the exact one; the band holds for both
    assert stroke["lower"] <= ind["stroke_mm"] * 1e3 <= stroke["upper"]
    assert min(ind["transmission_LMA_deg"], ind["transmission_BCD_deg"]) >= 40.0
    machine = Needle208(**{k: values[k] for k in P.field_names(Needle208)})
    check_assembly(machine)  # assemblable over the whole turn, no dead point
    c, _ = nm.columns(machine)
    feas = nm.feasibility(c)
    g1, _, g2, _ = transmission_extremes(c, feas.lo.reshape(-1, 1), feas.hi.reshape(-1, 1))
    assert float(np.min(g1)) == pytest.approx(ind["transmission_LMA_deg"], abs=1e-3)
    assert float(np.min(g2)) == pytest.approx(ind["transmission_BCD_deg"], abs=1e-3)
    assert float(nm.stroke_mm(c)[0]) == pytest.approx(ind["stroke_mm"], abs=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_refined_settings_are_the_adjusters_optimum(name):
    """beta (and the guide shift) in the JSON are the exact adjuster's optimum of the refined
    links: re-adjusting them gives the same SumDelta."""
    d, refined = _design(name)
    boxes = {k: tuple(v) for k, v in d["adjust"].items()}
    a = adjusted(refined, {}, boxes, "SumDelta_um")
    assert float(a.value[0]) == pytest.approx(d["refined"]["SumDelta_um"], abs=ADJUSTER_TOL_UM)


def test_the_study_wrote_its_designs():
    assert "housing_kept" in NAMES


def _small(mech, seed=3):
    cons = RF.default_constraints(mech) + [RF.keep(mech, "stroke_um", 100.0, ["beta"])]
    return RF.refine(mech, ["AB", "BE"], adjust=["beta"], constraints=cons, seed=seed,
                     restarts=2, popsize=8, maxiter=25, polish_evaluations=120,
                     local_search=False, tolerances=mech.tolerance_sets["base"])


def test_small_refinement_beats_today_keeps_constraints_and_repeats(mech):
    r = _small(mech)
    assert r.objective_before == pytest.approx(4.5871, abs=1e-3)
    assert r.objective_after < r.objective_before
    # the constraints hold on the refined design, re-evaluated from its values alone
    ev = mech.evaluate({k: np.array([v]) for k, v in r.refined.items()},
                       [c.output for c in r.constraints])
    assert ev.status[0] == "ok"
    for c in r.constraints:
        assert c.violation(ev.outputs[c.output][0]) == 0
    assert r.outputs_frame()["holds"].all()
    # the objective is the adjusted SumDelta of those values (beta at the adjuster's optimum)
    a = adjusted(mech, {k: np.array([r.refined[k]]) for k in ("AB", "BE")}, ["beta"],
                 "SumDelta_um")
    assert float(a.value[0]) == pytest.approx(r.objective_after, abs=1e-9)
    assert float(a.settings["beta"][0]) == pytest.approx(r.refined["beta"], abs=1e-9)
    # only AB, BE and beta changed
    assert set(r.changed) == {"AB", "BE", "beta"}
    # same seed, same answer
    again = _small(mech)
    assert again.refined == r.refined
    assert again.restarts.drop(columns="seconds").equals(r.restarts.drop(columns="seconds"))


def test_influence_is_slope_times_step(mech):
    """Degree of influence: the central-difference slope (re-adjusted) times the tolerance."""
    design = mech.nominal_values()
    f = RF.influence(mech, design, ["AB", "CD", "Ax"], "SumDelta_um", ["beta"],
                     mech.tolerance_sets["base"])
    rows = f.set_index("parameter")
    assert rows.loc["AB", "step"] == pytest.approx(0.05)  # base tolerance of AB
    assert rows.loc["CD", "step"] == pytest.approx(0.30)  # CD untoleranced: 1 % of 30 mm
    assert rows.loc["Ax", "step"] == pytest.approx(0.04)  # a frame coordinate: 1 % of 4 mm
    for p, r in rows.iterrows():
        h = 0.1 * r["step"]
        vals = {p: np.array([design[p] + h, design[p] - h, design[p] + r["step"], design[p]])}
        a = adjusted(mech, vals, ["beta"], "SumDelta_um").value
        assert r["slope_per_unit"] == pytest.approx((a[0] - a[1]) / (2 * h), rel=1e-9)
        assert r["influence"] == pytest.approx(r["slope_per_unit"] * r["step"], rel=1e-12)
        assert r["change_up"] == pytest.approx(a[2] - a[3], abs=1e-9)


def test_bad_inputs_name_field_rule_value(mech):
    with pytest.raises(ParameterError, match="parameters: must name parameters"):
        RF.refine(mech, ["XX"])
    with pytest.raises(ParameterError, match="branch_M: a branch"):
        RF.refine(mech, ["branch_M"])
    with pytest.raises(ParameterError, match="AB: box must have low < high"):
        RF.refine(mech, {"AB": (10.0, 9.0)})
    with pytest.raises(ParameterError, match="lower: must be <= upper"):
        RF.Constraint("stroke_um", 2.0, 1.0)
    with pytest.raises(ParameterError, match="restarts: must be an integer >= 1"):
        RF.refine(mech, ["AB"], restarts=0)
    code, out, err = run("run", "needle_208", "refine", "--vary", "XX")
    assert code == 2 and err.count("\n") == 1 and "--vary" in err and "XX" in err
    code, out, err = run("run", "needle_208", "refine", "--keep", "stroke_um")
    assert code == 2 and err.count("\n") == 1 and "--keep" in err
    code, out, err = run("run", "needle_208", "refine", "--require", "stroke_um=3")
    assert code == 2 and err.count("\n") == 1 and "--require" in err
    code, out, err = run("run", "needle_208", "nominal", "--restarts", "2")
    assert code == 2 and "--restarts" in err


def test_cli_refine_json_contract():
    code, out, err = run("run", "needle_208", "refine", "--vary", "AB,BE", "--adjust", "beta",
                         "--keep", "stroke_um=100", "--restarts", "1", "--popsize", "6",
                         "--maxiter", "5", "--seed", "2", "--format", "json")
    assert code == 0, err
    obj = json.loads(out)
    assert set(obj["parameters"]) <= {"AB", "BE", "beta"}
    assert obj["today"]["SumDelta_um"] == pytest.approx(4.5871, abs=1e-3)
    assert obj["refined"]["SumDelta_um"] <= obj["today"]["SumDelta_um"]
    assert {"stroke_um", "transmission_LMA_deg", "transmission_BCD_deg"} <= set(obj["refined"])
    assert obj["context"]["path"] == "needle_208"
    # the parameters go straight back in as --set
    sets = [f"--set={k}={v!r}" for k, v in obj["parameters"].items()]
    code, out2, _ = run("run", "needle_208", "nominal", *sets, "--format", "json")
    assert code == 0
    outputs = json.loads(out2)["outputs"]
    assert outputs["stroke_um"] == pytest.approx(obj["refined"]["stroke_um"], abs=1e-9)


ROBUST = tuple(json.loads(DESIGNS_FILE.read_text()).get("robust", {})) if DESIGNS_FILE.exists() \
    else ()


@pytest.mark.parametrize("name", NAMES)
def test_refined_design_checked_by_root_based_positions(name):
    """A second plain route (scipy.optimize.root on the loop closures, extremes refined in the
    crank angle): the claimed SumDelta within the adjuster's plateau tolerance, the stroke in
    its band, and the same figures as the circle-intersection model to 1e-6."""
    d, refined = _design(name)
    values = refined.nominal_values()
    r = figures_root(values)
    assert r["closes"]
    assert r["SumDelta_um"] == pytest.approx(d["refined"]["SumDelta_um"], abs=ADJUSTER_TOL_UM)
    stroke = next(c for c in d["constraints"] if c["output"] == "stroke_um")
    assert stroke["lower"] <= r["stroke_mm"] * 1e3 <= stroke["upper"]
    dense = figures(values)
    # the dense sampling lies below the refined extremes, by at most h^2 |d''| / 8
    assert 0.0 <= r["SumDelta_um"] - dense["SumDelta_um"] <= 1e-6
    assert r["stroke_mm"] == pytest.approx(dense["stroke_mm"], abs=1e-6)


@pytest.mark.parametrize("name", ROBUST)
def test_robust_design_checked_by_both_independent_models(name):
    """The robust designs' nominal SumDelta (beta set) and stroke error, as the study claims
    them, re-evaluated by the two independent models."""
    d = json.loads(DESIGNS_FILE.read_text())["robust"][name]
    refined = load(FILE, d["parameters"])
    values = refined.nominal_values()
    today = figures(load(FILE).nominal_values())
    for model in (figures, figures_root):
        r = model(values)
        assert r["closes"]
        assert r["SumDelta_um"] == pytest.approx(d["nominal_SumDelta_um"], abs=ADJUSTER_TOL_UM)
        # the claim is the file's stroke (720 samples): each sampled extreme lies below the
        # exact one by at most h^2 |x''| / 8 = 0.11 um (h = 0.5 deg, |x''| <= 12 mm/rad^2,
        # half the stroke), so a difference of two strokes within 0.25 um
        assert (r["stroke_mm"] - today["stroke_mm"]) * 1e3 == pytest.approx(
            d["stroke_error_um"], abs=0.25)


def _two_links(mech, seed, polish):
    cons = RF.default_constraints(mech) + [RF.keep(mech, "stroke_um", 100.0, ["beta"])]
    return RF.refine(mech, ["AB", "BE"], adjust=["beta"], constraints=cons, seed=seed,
                     restarts=2, popsize=6, maxiter=8, polish=polish, local_search=True)


def test_minimax_polish_restarts_agree_and_match_a_brute_force(mech):
    """AB and BE alone (housing kept, stroke held): short restarts disagree; the minimax polish
    of each (and of today's design) lands on one optimum, and a dense grid over the box (beta
    exact at every point, the constraints applied) finds nothing lower."""
    r = _two_links(mech, 5, "minimax")
    assert r.polished is not None and len(r.polished) == 3  # two restarts and today's
    assert r.polished_spread <= 2e-3
    assert r.objective_after <= r.restarts["objective"].min() + 1e-12
    assert r.outputs_frame()["holds"].all()
    prob = RF.DesignProblem(mech, "SumDelta_um", r.bounds, ["beta"], r.constraints, True)
    (lo_a, hi_a), (lo_b, hi_b) = r.bounds["AB"], r.bounds["BE"]
    # the optimum lies on a narrow valley (stroke held): the grid is dense around it
    a = np.linspace(max(lo_a, r.refined["AB"] - 0.05), min(hi_a, r.refined["AB"] + 0.05), 41)
    b = np.linspace(max(lo_b, r.refined["BE"] - 0.2), min(hi_b, r.refined["BE"] + 0.2), 81)
    A, B = np.meshgrid(a, b)
    f = prob(np.vstack([A.ravel(), B.ravel()]))
    assert f.min() >= r.objective_after - 2e-3


def test_minimax_polish_refuses_other_objectives(mech):
    with pytest.raises(ParameterError, match="objective: must be a line_deviation"):
        RF.minimax_polish(mech, "stroke_um", mech.nominal_values(), {"AB": (9.0, 11.0)},
                          {"beta": (10.0, 35.0)})
    with pytest.raises(ParameterError, match="polish: must be"):
        RF.refine(mech, ["AB"], polish="newton")


def test_robust_yield_is_common_random_numbers_and_never_below_today(mech):
    """The search's yield of today's design is the fresh count on the same machines (same n,
    same seed); the best design found is at least as good (today's design rides in the first
    population); same seed, same answer; the front is non-dominated."""
    base = mech.tolerance_sets["base"]
    cons = RF.default_constraints(mech) + [RF.keep(mech, "stroke_um", 100.0, ["beta"])]
    bounds = RF.default_bounds(mech, ["AB", "BE", "CD"])
    kw = dict(adjust=["beta"], constraints=cons, n=60, seed=4, restarts=1, popsize=3,
              maxiter=3, error_of=("stroke_um", 23885.55))
    r = RB.robust(mech, bounds, base, **kw)
    today = r.figures.set_index("design").loc["today"]
    check = RB.yield_check(mech, mech.nominal_values(), base, ["beta"], "SumDelta_um", 10.0,
                           60, 4)
    assert today["yield"] == pytest.approx(check["yield"], abs=1e-12)
    assert check["ok"] + check["out_of_spec"] + check["failed"] == 60
    assert check["yield_ci_low"] <= check["yield"] <= check["yield_ci_high"]
    best = r.figures.set_index("design").loc["robust"]
    assert best["yield"] >= today["yield"]
    again = RB.robust(mech, bounds, base, **kw)
    assert again.best == r.best
    obj = np.column_stack([r.front["nominal"], -r.front["yield"], np.abs(r.front["error"])])
    for i in range(len(obj)):
        assert not np.any(np.all(obj <= obj[i], axis=1) & np.any(obj < obj[i], axis=1))
    allp = np.column_stack([r.archive["nominal"], -r.archive["yield"],
                            np.abs(r.archive["error"])])
    for row in allp:  # every archived design is dominated by or equal to a front member
        assert np.any(np.all(obj <= row, axis=1))
