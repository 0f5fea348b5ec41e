"""Relational tolerances (sewtol.relations): the forms and refusals, the conditioned sampler
held to the candidates it filters and to closed forms, and the worst case over the polytope."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import optimize, spatial, stats

from sewtol.errors import ParameterError
from sewtol.law import STREAM, InputLaw, draw_units, unit_streams
from sewtol.mechanism import load
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.params import field_names
from sewtol.relations import Relation, polytope_vertices
from sewtol.tolerances import NEEDLE_208_SETS, load_toml

VALID = field_names(Needle208)
CRANK_SLIDER = Path(__file__).parent / "data" / "crank_slider.toml"
BAND = 'relations = [{ expr = "AB - BE", lower = -0.01, upper = 0.01 }]\n'


def one_set(tmp_path, text):
    p = tmp_path / "tol.toml"
    p.write_text("[sets.x]\nAB = 0.05\nBE = 0.05\nLF = 0.05\n" + text)
    return load_toml(p, VALID)["x"]


def test_a_relation_is_read_recorded_and_its_linearity_read_from_the_tree(tmp_path):
    ts = one_set(tmp_path, BAND)
    assert ts.relations == (Relation("AB - BE", -0.01, 0.01),)
    assert ts.relations[0].where == "x.relations[0]"
    assert ts.as_record()["relations"] == [{"expr": "AB - BE", "lower": -0.01, "upper": 0.01}]
    assert ts.active().relations == ts.relations and ts.scaled({"AB": 2}).relations == ts.relations
    assert "relations" not in NEEDLE_208_SETS["base"].as_record()  # records as before
    assert Relation("2*(AB - BE/4) + pi", upper=9).linear == ({"AB": 2.0, "BE": -0.5}, np.pi)
    assert Relation("-(AB)/sqrt(4)", upper=1).linear == ({"AB": -0.5}, 0.0)
    for text in ("AB * BE", "hypot(AB, BE)", "AB**2", "1 / AB"):
        assert Relation(text, upper=1).linear is None, text
    r = Relation("hypot(AB, BE)", upper=0.05)
    np.testing.assert_array_equal(r.holds({"AB": np.array([0.03, 0.04]),
                                           "BE": np.array([0.04, 0.04])}, 2), [True, False])


@pytest.mark.parametrize("text, message", [
    ('relations = [{ expr = "AB - CD", upper = 0.01 }]\n',
     "x.relations[0].expr: names 'CD', which is not a toleranced parameter of the set "
     "(AB, BE, LF) (got 'AB - CD')"),
    ('relations = [{ expr = "AB.real", upper = 0.01 }]\n',
     "x.relations[0].expr: Attribute is not allowed (got 'AB.real')"),
    ('relations = [{ expr = "__import__(AB)", upper = 0.01 }]\n',
     "x.relations[0].expr: __import__(...) is not an allowed function (got '__import__(AB)')"),
    ('relations = [{ expr = "AB - BE" }]\n',
     "x.relations[0]: needs a lower or an upper limit (or both) (got 'AB - BE')"),
    ('relations = [{ expr = "AB - BE", lower = 0.01, upper = 0.01 }]\n',
     "x.relations[0].lower: must be below upper (an equality leaves no machine to draw; to make "
     "parts equal, tie them with setup share 1) (got (0.01, 0.01))"),
    ('relations = [{ expr = "AB - BE", upper = "0.01" }]\n',
     "x.relations[0].upper: must be a number (got '0.01')"),
    ('relations = [{ expr = "AB - BE", upper = 0.01, tol = 1 }]\n',
     "x.relations[0]: unknown keys ['tol']; allowed: ['expr', 'lower', 'upper'] "
     "(got {'expr': 'AB - BE', 'upper': 0.01, 'tol': 1})"),
    ('relations = [{ expr = "2 * pi", upper = 0.01 }]\n',
     "x.relations[0].expr: must name at least one parameter (got '2 * pi')"),
    ('relations = { expr = "AB - BE", upper = 0.01 }\n',
     "x.relations: must be a list of { expr = \"...\", lower = x, upper = y } "
     "(got {'expr': 'AB - BE', 'upper': 0.01})"),
])
def test_bad_relations_are_refused_in_one_line(tmp_path, text, message):
    with pytest.raises(ParameterError) as exc:
        one_set(tmp_path, text)
    assert str(exc.value) == message
    assert "\n" not in str(exc.value)


def test_mechanism_files_declare_relations_too():
    text = CRANK_SLIDER.read_text().replace(
        "[tolerances.uniform]\nr = 0.03\nL = 0.1\n",
        '[tolerances.uniform]\nr = 0.03\nL = 0.1\nrelations = [{ expr = "L - r", upper = 0.02 }]\n')
    from sewtol.mechanism import loads

    mech = loads(text, "m.toml")
    assert mech.tolerance_sets["uniform"].relations == (Relation("L - r", upper=0.02),)


def test_the_sampler_keeps_the_candidates_of_each_stream_that_pass(tmp_path):
    """Machine k is the (k % STREAM)-th passing candidate of stream k // STREAM, the candidates
    being that stream's rows in batches of STREAM; any window draws the same machines; the
    acceptance is the band's share of the square, 1 - 0.09^2 / 0.1^2 = 0.19."""
    ts = one_set(tmp_path, BAND)
    law = InputLaw.of(ts)
    n, seed = 1700, 5
    dev = law.draw(n, seed)
    streams = unit_streams(seed, n)
    want = []
    for j, ss in enumerate(streams):
        gen = np.random.default_rng(ss)
        need, kept = min(STREAM, n - j * STREAM), []
        while sum(map(len, kept)) < need:
            u = gen.random((STREAM, 3))
            d = u * 0.1 - 0.05  # AB, BE, LF uniform +/-0.05
            kept.append(u[np.abs(d[:, 0] - d[:, 1]) <= 0.01])
        want.append(np.concatenate(kept)[:need])
    want = np.concatenate(want) * 0.1 - 0.05
    for i, p in enumerate(("AB", "BE", "LF")):
        np.testing.assert_allclose(dev[p], want[:, i], rtol=0, atol=1e-15)
    win = law.window(streams, 480, 1210)
    for p in dev:
        np.testing.assert_array_equal(win[p], dev[p][480:1210])
    built, drawn = law.acceptance(20000, 2)
    # binomial standard error of the rate at ~105,000 candidates: 0.0012
    assert built / drawn == pytest.approx(0.19, abs=0.005)
    # the conditioned law: AB - BE has the triangle density (0.1 - |d|) cut to |d| <= 0.01
    d = law.draw(4000, 3)
    diff = d["AB"] - d["BE"]

    def cdf(x):
        x = np.clip(x, -0.01, 0.01)
        area = lambda a: 0.1 * a - np.sign(a) * a**2 / 2  # noqa: E731
        return (area(x) - area(-0.01)) / (area(0.01) - area(-0.01))

    assert stats.kstest(diff, cdf).pvalue > 1e-3
    # LF is not in a relation: its marginal stays uniform
    assert stats.kstest(d["LF"], stats.uniform(-0.05, 0.1).cdf).pvalue > 1e-3


def test_a_law_without_relations_draws_what_it_drew_before():
    law = InputLaw.of(NEEDLE_208_SETS["base"])
    u = draw_units(unit_streams(7, 1234), law.dim, 0, 1234)
    want = law.of_uniforms(u)
    got = law.draw(1234, 7)
    for p in want:
        np.testing.assert_array_equal(got[p], want[p])
    assert law.acceptance(1234, 7) == (1234, 1234)


def test_relations_and_a_copula_together():
    """rho 0.9 on AB, BE puts more machines in the band |AB - BE| <= 0.01 than independence;
    the rate equals the copula's own share of the band, found from 200,000 copula draws."""
    tied = replace(NEEDLE_208_SETS["base"], name="t",
                   dependence=InputLaw.of(load_toml(
                       Path(__file__).parents[1] / "examples/tolerances/needle_208_tied.toml",
                       VALID)["tied"]).dependence,
                   relations=(Relation("AB - BE", -0.01, 0.01),))
    law = InputLaw.of(tied)
    dev = law.draw(3000, 1)
    assert np.all(np.abs(dev["AB"] - dev["BE"]) <= 0.01)
    built, drawn = law.acceptance(3000, 1)
    free = InputLaw.of(replace(tied, relations=())).sample(np.random.default_rng(9), 200000)
    share = np.mean(np.abs(free["AB"] - free["BE"]) <= 0.01)
    # binomial standard error at 3000 / 0.5 candidates: 0.0065
    assert built / drawn == pytest.approx(share, abs=0.03) and share > 0.4


def test_monte_carlo_builds_only_machines_that_keep_the_relation_and_counts_the_rest():
    """The crank-slider's J_x_max = 50 + L + r: with L + r kept within +/-0.05 every machine
    meets 50.05, where without the relation P(L + r > 0.05) = 0.25 fail (L + r has the
    trapezoid density 5 on |s| <= 0.07 falling to 0 at 0.13: 0.02 * 5 + 0.06^2 / 0.024); the
    relation passes P(|L + r| <= 0.05) = 0.1 * 5 = 0.5 of the candidates."""
    from sewtol.studies.montecarlo import montecarlo

    mech = load(CRANK_SLIDER)
    free = mech.tolerance_sets["uniform"]
    held = replace(free, name="held", relations=(Relation("L + r", -0.05, 0.05),))
    n = 4000
    a = montecarlo(mech, free, n, 4, outputs=["J_x_max_mm"], limit=50.05)
    b = montecarlo(mech, held, n, 4, outputs=["J_x_max_mm"], limit=50.05)
    # binomial standard error at n 4000: 0.0068
    assert a.yield_of("fixed") == pytest.approx(0.75, abs=0.021)
    assert b.yield_of("fixed") == 1.0 and a.candidates is None
    assert np.all(np.abs(b.machines["L"] + b.machines["r"]) <= 0.05)
    ins = b.to_dict()["inspection"]
    assert ins["built"] == n and ins["rejected"] == ins["candidates"] - n
    assert ins["acceptance"] == pytest.approx(0.5, abs=0.02)  # standard error 0.0056
    assert "inspection" not in a.to_dict()


def test_strategies_see_the_conditioned_machines():
    from sewtol.studies.strategies import strategies

    mech = load(CRANK_SLIDER)
    held = replace(mech.tolerance_sets["uniform"], name="held",
                   relations=(Relation("L + r", -0.05, 0.05),))
    s = strategies(mech, held, 900, 2, output="J_x_max_mm", upper=50.05)
    want = InputLaw.of(held).draw(900, 2)
    for k in want:
        np.testing.assert_array_equal(s.deviations[k], want[k])
    assert np.all(np.abs(s.deviations["L"] + s.deviations["r"]) <= 0.05)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_polytope_vertices_equal_qhulls(seed):
    rng = np.random.default_rng(seed)
    d, m = 4, 2
    lo, hi = -rng.uniform(0.5, 1, d), rng.uniform(0.5, 1, d)
    a = rng.normal(size=(m, d))
    lower, upper = -rng.uniform(0.2, 0.6, m), rng.uniform(0.2, 0.6, m)
    v = polytope_vertices(lo, hi, a, lower, upper)
    # qhull's halfspace intersection from the origin (inside: every limit straddles 0)
    hs = np.vstack([np.hstack([np.eye(d), -hi[:, None]]), np.hstack([-np.eye(d), lo[:, None]]),
                    np.hstack([a, -upper[:, None]]), np.hstack([-a, lower[:, None]])])
    ref = spatial.HalfspaceIntersection(hs, np.zeros(d)).intersections
    ref = np.unique(np.round(ref, 9), axis=0)
    assert len(v) == len(ref)
    assert np.allclose(np.sort(np.round(v, 9), axis=0), np.sort(ref, axis=0), atol=1e-9)


def test_worst_case_searches_the_polytope_the_relations_leave():
    """max and min of J_x_max = 50 + L + r with |L - r| <= 0.02 (r +/-0.03, L +/-0.1) are
    50 +/- 0.08 at r = +/-0.03, L = +/-0.05 (linprog gives the same); without it 50 +/- 0.13."""
    from sewtol.studies.worst_case import worst_case

    mech = load(CRANK_SLIDER)
    free = mech.tolerance_sets["uniform"]
    held = replace(free, name="held", relations=(Relation("L - r", -0.02, 0.02),))
    lp = optimize.linprog([-1, -1], A_ub=[[-1, 1], [1, -1]], b_ub=[0.02, 0.02],
                          bounds=[(-0.03, 0.03), (-0.1, 0.1)])
    assert -lp.fun == pytest.approx(0.08, abs=1e-12)
    r = worst_case(mech, held, "J_x_max_mm", axes=False).rows.set_index("extreme")
    assert r.loc["max", "value"] == pytest.approx(50.08, abs=1e-9)
    assert r.loc["min", "value"] == pytest.approx(49.92, abs=1e-9)
    assert (r.loc["max", "r_dev"], r.loc["max", "L_dev"]) == pytest.approx((0.03, 0.05), abs=1e-12)
    assert worst_case(mech, held, "J_x_max_mm", axes=False).corners == 4  # the band's vertices
    free_r = worst_case(mech, free, "J_x_max_mm", axes=False).rows.set_index("extreme")
    assert free_r.loc["max", "value"] == pytest.approx(50.13, abs=1e-9)
    bent = replace(free, relations=(Relation("L * r", upper=0.001),))
    with pytest.raises(ParameterError, match=r"^relations\.expr: must be linear"):
        worst_case(mech, bent, "J_x_max_mm")


def test_needle_worst_case_with_ab_minus_be_limited_is_lower_and_keeps_the_relation():
    """Fixed beta: 123.5 um over the base box; with |AB - BE| <= 0.01 the worst machine keeps
    the relation and no machine of the conditioned law (4000 drawn) is worse."""
    from sewtol.protocol import machines
    from sewtol.studies.adjusting import evaluated
    from sewtol.tables import needle_208 as T

    nominal = Needle208.nominal()
    held = replace(NEEDLE_208_SETS["base"], name="held",
                   relations=(Relation("AB - BE", -0.01, 0.01),))
    free = T.worst_case(nominal, "base", adjust=False)
    r = T.worst_case(nominal, held, adjust=False)
    assert free["total_um"] == pytest.approx(123.507, abs=1e-3)
    assert r["total_um"] < 0.5 * free["total_um"]
    # SLSQP's point keeps the relation to the worst case's feasibility tolerance, 1e-9 relative
    assert abs(r["AB_mm"] - r["BE_mm"]) <= 0.01 + 1e-9 * (1 + 0.1)
    mech = T.as_mechanism(nominal)
    sampled = evaluated(mech, machines(mech, InputLaw.of(held).draw(4000, 0)), "SumDelta_um",
                        fast=True)
    assert np.nanmax(sampled) <= r["total_um"] + 1e-9


def test_studies_that_cannot_condition_refuse_in_one_line():
    from sewtol.studies import allocation, rare_event, shapley, sobol

    mech = load(CRANK_SLIDER)
    held = replace(mech.tolerance_sets["uniform"], name="held",
                   relations=(Relation("L + r", -0.05, 0.05, "held.relations[0]"),))
    for call in (lambda: allocation.allocate(mech, held, "J_x_max_mm", 0.9, upper=50.05),
                 lambda: rare_event.limit_state(mech, held, "J_x_max_mm", upper=50.05),
                 lambda: shapley.shapley(mech, held, "J_x_max_mm", 10, 1),
                 lambda: sobol.check_independent(held)):
        with pytest.raises(ParameterError) as exc:
            call()
        assert str(exc.value).startswith("held.relations[0]") and "\n" not in str(exc.value)


def test_the_example_file_declares_a_relation_and_a_matching():
    sets = load_toml(Path(__file__).parents[1] / "examples/tolerances/needle_208_paired.toml",
                     VALID)
    assert sets["paired"].relations == (Relation("AB - BE", -0.01, 0.01),)
    assert sets["matched"].selective.as_dict() == {"params": ["AB", "BE"], "groups": 8,
                                                   "by": "count"}
    base = NEEDLE_208_SETS["base"]
    for ts in sets.values():
        assert ts.as_dict() == base.as_dict()


def test_the_generic_report_says_what_the_set_declares_and_searches_the_polytope():
    """`run FILE report` on a set with a relation: the worst J_x_max is 50.05 (L + r <= 0.05),
    the words name the relation and the inspection (candidates from the one sampler); an
    independent set's report says nothing more than before."""
    from sewtol.reports import generic_report as R

    mech = load(CRANK_SLIDER)
    free = mech.tolerance_sets["uniform"]
    held = replace(free, relations=(Relation("L + r", -0.05, 0.05),))
    rep = R.build(mech, held, n=300, seed=2)
    wc = rep.worst_case.set_index(["output", "extreme"])
    assert wc.loc[("J_x_max_mm", "max"), "value"] == pytest.approx(50.05, abs=1e-9)
    cand = InputLaw.of(held).acceptance(300, 2)[1]
    assert rep.notes == [
        "relation L + r within [-0.05, 0.05]: machines that break it are rejected at "
        "inspection; the worst case searches what it leaves of the box",
        f"inspection: 300 machines built from {cand} candidates ({100 * 300 / cand:.1f} %); the "
        "others broke a relation or were left unmatched"]
    assert R.law_notes(free, None) == []
