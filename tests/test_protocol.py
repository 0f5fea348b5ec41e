"""Every built-in mechanism and example file passes the protocol suite (sewtol.checks), and the
suite fails a mechanism that breaks the contract, naming the check."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from sewtol import checks, protocol
from sewtol.law import InputLaw
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file, names

EXAMPLES = sorted(p for p in (Path(__file__).parent.parent / "examples").glob("*.toml")
                  if not p.is_symlink())
# the kernel against the generic path is held to a derived bound: repeat it under the narrowed
# CPU dispatch (make test-narrowed)
pytestmark = pytest.mark.numerics

MECHANISMS = [mechanism_file(n) for n in names()] + EXAMPLES


@pytest.fixture(scope="module", params=MECHANISMS, ids=lambda p: p.stem if p.name != "mechanism.toml"
                else p.parent.name)
def mech(request):
    return load(request.param)


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
def test_every_mechanism_passes_the_protocol_suite(mech, check):
    check(mech)


def test_all_seven_built_ins_are_checked():
    assert len(names()) == 7


def test_the_needle_and_the_m6_earn_their_plug_ins_and_the_others_none():
    """The needle's kernel and exact adjuster; the M6 needle's exact travel kernel."""
    got = {n: protocol.plugins(load(mechanism_file(n))).name for n in names()}
    assert got == {n: (n if n in ("needle_208", "m6_needle") else "") for n in names()}


def test_the_needle_kernel_is_exact_and_the_generic_path_lies_below_it_within_the_bound():
    mech = load(mechanism_file("needle_208"))
    pl = protocol.plugins(mech)
    vals = protocol.machines(mech, protocol.input_law(mech, "base").sample(
        np.random.default_rng(7), 6))
    exact = pl.kernel(mech, vals)["SumDelta_um"]
    sampled = mech.evaluate(vals, ["SumDelta_um"]).outputs["SumDelta_um"]
    bound = pl.kernel_bound(mech, vals)["SumDelta_um"]
    # sampled extremes never exceed the exact ones (to the 1e-6 um the positions agree to)
    assert np.all(exact - sampled >= -1e-6)
    assert np.all(exact - sampled <= bound)
    # the bound is the sampling error's order at 720 samples: below 2e-3 um, not a loose catch-all
    assert np.all(bound < 2e-3)


def test_the_law_draws_what_the_tolerance_set_draws():
    mech = load(mechanism_file("needle_208"))
    ts = mech.tolerance_sets["recommended"]
    law = InputLaw.of(ts)
    a = law.sample(np.random.default_rng(3), 50)
    b = ts.active().sample(np.random.default_rng(3), 50)
    assert law.independent and law.params == ts.active().params
    assert all(np.array_equal(a[k], b[k]) for k in b)


def _broken(mech, **changes):
    return dataclasses.replace(mech, **changes)


def test_the_suite_names_what_a_broken_mechanism_breaks():
    mech = load(mechanism_file("needle_208"))
    beta = mech.compensators["beta"]
    bad = _broken(mech, compensators={"beta": dataclasses.replace(beta, low=23.0, high=35.0)})
    with pytest.raises(AssertionError, match="check_compensators: beta: box"):
        checks.check_compensators(bad)
    off = _broken(mech, compensators={"beta": dataclasses.replace(beta, parameter="gamma")})
    with pytest.raises(AssertionError, match="sets 'gamma', not a parameter"):
        checks.check_compensators(off)
    with pytest.raises(AssertionError, match="check_protocol"):
        checks.check_protocol(object())


def test_the_law_draws_the_machines_of_every_study():
    from sewtol.studies.montecarlo import draw_deviations

    mech = load(mechanism_file("needle_208"))
    ts = mech.tolerance_sets["recommended"]
    got = protocol.input_law(mech, ts).draw(1234, 2026)
    want = draw_deviations(ts, 1234, 2026)
    assert list(got) == list(want) and all(np.array_equal(got[k], want[k]) for k in want)


def test_the_suite_holds_a_failure_table_to_the_protocols_words(monkeypatch):
    """The needle's failure naming calls its machine at 3x every length a failure (it does not
    close); a plug-in that calls such a machine "ok" fails the suite, naming the check."""
    mech = load(mechanism_file("needle_208"))
    pl = protocol.plugins(mech)
    big = {p.name: np.array([p.nominal * (3.0 if p.rule == "positive" else 1.0)])
           for p in mech.parameters}
    assert mech.evaluate(big).status[0] == "cannot_close"
    assert pl.failure_table(mech, big)["status"][0] == "cannot_close"
    checks.check_failures_counted(mech)
    liar = dataclasses.replace(pl, failure_table=lambda m, v: {
        "status": np.full(len(next(iter(v.values()))), "ok", object)})
    monkeypatch.setattr(protocol, "plugins", lambda m: liar)
    with pytest.raises(AssertionError, match="check_failures_counted: the plug-in's failure"):
        checks.check_failures_counted(mech)


def test_a_column_of_words_points_at_one_str_per_word():
    """protocol.words_of: the statuses of the needle's adjuster, the Monte-Carlo's adjusted
    statuses and Sobol's outcomes are 8-byte pointers at the vocabulary's own str objects."""
    from sewtol.mechanisms.needle_208.adjustment import WORDS, status_of

    total = np.array([3.0, 12.0, np.nan, np.nan, 9.5])
    got = status_of(total, 10.0, np.array([False, False, True, False, False]))
    assert got.dtype == object and got.tolist() == ["ok", "out of spec", "dead point",
                                                    "cannot assemble", "ok"]
    assert all(g is WORDS[i] for g, i in zip(got, [0, 1, 2, 3, 0], strict=True))
    column = protocol.words_of([""], np.zeros((2, 3), np.uint8))
    assert column.shape == (2, 3) and len({id(w) for w in column.ravel()}) == 1
