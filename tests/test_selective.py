"""Selective assembly (sewtol.selective, studies/selective_assembly.py): the form and refusals,
the matching held to its invariants and to the closed-form variance of a matched sum, and the
needle's yield against k beside the tightening that gives it."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sewtol.errors import ParameterError
from sewtol.law import STREAM, InputLaw, unit_streams
from sewtol.mechanism import load
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.params import field_names
from sewtol.selective import Selective, classes, match
from sewtol.tolerances import NEEDLE_208_SETS, load_toml

VALID = field_names(Needle208)
CRANK_SLIDER = Path(__file__).parent / "data" / "crank_slider.toml"


def one_set(tmp_path, text):
    p = tmp_path / "tol.toml"
    p.write_text("[sets.x]\nAB = 0.05\nBE = 0.05\nLF = 0.05\n" + text)
    return load_toml(p, VALID)["x"]


def test_the_form_is_read_and_recorded(tmp_path):
    ts = one_set(tmp_path, 'selective = { params = ["AB", "BE"], groups = 4, by = "width" }\n')
    assert ts.selective == Selective(("AB", "BE"), 4, "width", "x.selective")
    assert ts.as_record()["selective"] == {"params": ["AB", "BE"], "groups": 4, "by": "width"}
    assert InputLaw.of(ts).selective == ts.selective and not InputLaw.of(ts).independent
    # a part of zero width needs no sorting
    flat = replace(ts, items=tuple(t if t.param != "BE" else replace(t, lower=0.0, upper=0.0)
                                   for t in ts.items))
    assert flat.active().selective is None


@pytest.mark.parametrize("text, message", [
    ('selective = { params = ["AB", "CD"], groups = 4 }\n',
     "x.selective.params: names 'CD', not a parameter of the set (AB, BE, LF) (got 'CD')"),
    ('selective = { params = ["AB", "AB"], groups = 4 }\n',
     "x.selective.params: must name two different parameters (the parts matched) "
     "(got ['AB', 'AB'])"),
    ('selective = { params = ["AB", "BE"], groups = 0 }\n',
     "x.selective.groups: must be a whole number of classes from 1 to 100 (got 0)"),
    ('selective = { params = ["AB", "BE"], groups = 4, by = "size" }\n',
     "x.selective.by: must be one of count, width (got 'size')"),
    ('selective = { params = ["AB", "BE"] }\n',
     "x.selective: must be a table { params = [\"A\", \"B\"], groups = k, by = \"count\" or "
     "\"width\" } (got {'params': ['AB', 'BE']})"),
])
def test_bad_selective_assembly_is_refused_in_one_line(tmp_path, text, message):
    with pytest.raises(ParameterError) as exc:
        one_set(tmp_path, text)
    assert str(exc.value) == message


def test_matching_pairs_parts_of_one_class_and_leaves_the_surplus():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-1, 1, 500), rng.uniform(-1, 1, 500)
    for by in ("count", "width"):
        ca, cb = classes(a, 8, by, (-1, 1)), classes(b, 8, by, (-1, 1))
        ia, ib = match(ca, cb, 8)
        assert np.array_equal(ca[ia], cb[ib]) and len(set(ia)) == len(ia) == len(set(ib))
        # every class matches min(count of a, count of b): the surplus is unmatched
        want = sum(min(np.sum(ca == c), np.sum(cb == c)) for c in range(8))
        assert len(ia) == want
        if by == "count":  # equal counts: 500 = 8 x 62.5, the same runs for both parts
            assert len(ia) == 500
    assert np.array_equal(classes(np.array([-2.0, -1, 0.999, 5]), 4, "width", (-1, 1)),
                          [0, 0, 3, 3])


def test_the_sampler_matches_within_lots_and_keeps_the_window_property():
    ts = replace(NEEDLE_208_SETS["base"], selective=Selective(("AB", "BE"), 5, "width"))
    law = InputLaw.of(ts)
    dev = law.draw(1300, 4)
    # same width class: |AB - BE| < 0.1 / 5
    ca = classes(dev["AB"], 5, "width", (-0.05, 0.05))
    assert np.array_equal(ca, classes(dev["BE"], 5, "width", (-0.05, 0.05)))
    win = law.window(unit_streams(4, 1300), 333, 1111)
    for p in dev:
        np.testing.assert_array_equal(win[p], dev[p][333:1111])
    # equal count: a lot's matched BE parts are that lot's BE parts, rearranged
    law = InputLaw.of(replace(ts, selective=Selective(("AB", "BE"), 5, "count")))
    first = law.draw(STREAM, 4)
    lot = law.deviations(law.ranks(np.random.default_rng(unit_streams(4, STREAM)[0]).random(
        (STREAM, law.dim))))
    np.testing.assert_array_equal(np.sort(first["BE"]), np.sort(lot["BE"]))
    np.testing.assert_array_equal(first["AB"], lot["AB"])  # in the order the AB parts were made


@pytest.mark.parametrize("k", [2, 4])
def test_matched_sum_has_the_closed_form_variance(k):
    """r and L uniform (0.03, 0.1 mm) matched in k equal-count classes: their ranks share the
    class, Cov(u_r, u_L) = Var(class / k) = (1 - 1/k^2) / 12, so Var(L + r) = (0.06^2 + 0.2^2)
    / 12 + 2 * 0.06 * 0.2 * (1 - 1/k^2) / 12 (the limit of large lots; a lot of 500 is within
    a per cent). 6,000 machines: the sample variance's standard error is about 1.3 %."""
    mech = load(CRANK_SLIDER)
    ts = replace(mech.tolerance_sets["uniform"], selective=Selective(("r", "L"), k, "count"))
    d = InputLaw.of(ts).draw(6000, 8)
    want = (0.06**2 + 0.2**2) / 12 + 2 * 0.06 * 0.2 * (1 - 1 / k**2) / 12
    assert np.var(d["L"] + d["r"]) == pytest.approx(want, rel=0.05)


def test_needle_selective_assembly_against_tightening():
    """Matching AB with BE in k equal-count classes raises the beta-only yield with k; k = 1 is
    the plain Monte-Carlo; the tightening factor f on AB and BE alone reaches that yield
    unmatched (same machines) and f + 2^-12 does not. Measured (n 2000, seed 1): 9.3, 15.9,
    27.7 % at k 1, 2, 4; AB, BE +/-0.027 and +/-0.014 mm give the same."""
    from sewtol.protocol import machines
    from sewtol.studies.rare_event import output_of
    from sewtol.studies.selective_assembly import FACTOR_STEPS, selective_assembly
    from sewtol.tables import needle_208 as T

    mech = T.as_mechanism(Needle208.nominal())
    beta = {"beta": (10.0, 35.0)}
    base = NEEDLE_208_SETS["base"]
    r = selective_assembly(mech, base, "SumDelta_um", ("AB", "BE"), (1, 2, 4), "count",
                           n=2000, seed=1, adjust=beta)
    t = r.to_dataframe().set_index("groups")
    assert list(t["yield"]) == sorted(t["yield"]) and t.loc[4, "yield"] > 2 * t.loc[1, "yield"]
    assert (t[["ok", "out_of_spec", "cannot_close", "dead_point"]].sum(axis=1) == 2000).all()
    assert (t["unmatched_each"] == 0).all()

    def plain(f):
        dev = InputLaw.of(base.scaled({"AB": f, "BE": f})).draw(2000, 1)
        y = output_of(mech, machines(mech, dev), "SumDelta_um", beta)
        return float(np.mean(y <= 10.0))

    assert plain(1.0) == t.loc[1, "yield"]
    f = t.loc[4, "tightening_factor"]
    assert t.loc[4, "AB_pm_unmatched"] == pytest.approx(0.05 * f, rel=1e-12)
    assert plain(f) >= t.loc[4, "yield"] > plain(f + 2.0**-FACTOR_STEPS)


def test_studies_that_cannot_match_refuse_in_one_line():
    from sewtol.studies import allocation, rare_event, shapley, sobol, worst_case

    mech = load(CRANK_SLIDER)
    ts = replace(mech.tolerance_sets["uniform"], name="m",
                 selective=Selective(("r", "L"), 4, "count", "m.selective"))
    for call in (lambda: allocation.allocate(mech, ts, "J_x_max_mm", 0.9, upper=50.05),
                 lambda: rare_event.limit_state(mech, ts, "J_x_max_mm", upper=50.05),
                 lambda: shapley.shapley(mech, ts, "J_x_max_mm", 10, 1),
                 lambda: sobol.check_independent(ts),
                 lambda: worst_case.worst_case(mech, ts, "J_x_max_mm")):
        with pytest.raises(ParameterError) as exc:
            call()
        assert str(exc.value).startswith("m.selective") and "\n" not in str(exc.value)


def test_sample_from_a_generator_matches_too():
    """law.sample(rng, n) (the protocol checks' draw) matches within its lots as draw does."""
    ts = replace(NEEDLE_208_SETS["base"], selective=Selective(("AB", "BE"), 4, "width"))
    law = InputLaw.of(ts)
    a = law.sample(np.random.default_rng(5), 700)
    b = law.sample(np.random.default_rng(5), 700)
    assert len(a["AB"]) == 700 and all(np.array_equal(a[k], b[k]) for k in a)
    assert np.array_equal(classes(a["AB"], 4, "width", (-0.05, 0.05)),
                          classes(a["BE"], 4, "width", (-0.05, 0.05)))
