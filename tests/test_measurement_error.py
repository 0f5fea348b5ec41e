"""The needle's compensators set from a measured deviation (sewtol.measurement_error,
needle_208.measurement): sd 0 is the rows without the option, a small case by hand, the
analytic limit (many positions, no error: the exact optimum), the yield never above the exact
row's, the draws' own stream, and the command line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cli_helpers import run, strict_loads
from sewtol import measurement_error as me
from sewtol.errors import ParameterError
from sewtol.law import STREAM
from sewtol.measurement_error import MeasurementError
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd
from sewtol.mechanisms.needle_208.adjust import PLATEAU_TOL_UM
from sewtol.mechanisms.needle_208.adjustment import adjust, columns_of
from sewtol.mechanisms.needle_208.compensators import Strategy, exact, strategy_of
from sewtol.mechanisms.needle_208.measurement import adjust_measured
from sewtol.protocol import input_law
from sewtol.studies import strategies as ST
from sewtol.tables.needle_208 import as_mechanism, needle_set, strategies_table

SEED = 2026


def _columns(nominal, n, seed=SEED, tolerances="base"):
    dev = input_law(as_mechanism(nominal), needle_set(tolerances)).draw(n, seed)
    return columns_of(nominal, dev)


def test_sd_zero_gives_exactly_the_rows_without_the_option(nominal):
    rows = [strategy_of(("beta", "guide_shift_um"), name="beta+shift"),
            strategy_of(("beta", "guide_shift_um", "guide_angle"), name="bsa")]
    plain = strategies_table(nominal, "base", 8, SEED, rows)
    zero = strategies_table(nominal, "base", 8, SEED, rows, measurement=MeasurementError(0.0))
    pd.testing.assert_frame_equal(plain.to_dataframe(), zero.to_dataframe())
    for r in rows:
        pd.testing.assert_frame_equal(plain.machines(r.name), zero.machines(r.name))
    assert (plain.to_dataframe()["measurement_error"] == "none").all()
    assert me.parse_cli("0") is None and me.parse_cli(None) is None


def test_the_shift_set_from_a_reading_by_hand(nominal):
    """Only the guide shift, read at 12 positions with sd 3 um: the shift is the centre of the
    READ band (the band inside the +-100 um range), computed here from the engine's own chain
    (not the position kernel the study uses) and the study's own draws; the machine's figure is
    the true band's SumDelta at that shift (exact extremes)."""
    n, k, sd = 6, 12, 3.0
    mech = as_mechanism(nominal)
    shift = Strategy("shift", (strategy_of(("guide_shift_um",)).compensators[0],))
    r = ST.strategies(mech, "base", n, SEED, {"shift": shift}, "SumDelta_um",
                      measurement=MeasurementError(sd, k), limit_um=10.0)
    a = r.get("shift")
    c = _columns(nominal, n)
    phi = 2 * np.pi * np.arange(k) / k
    _, nvec, G = nd.guide_frame(c)  # the machines' own shift is 0
    E = nd.chain_from_crank(c, phi[None, :])["E"].p
    read = nd.project(nvec, E - G) * 1e3 + sd * me.normal_draws(SEED, 0, n, k)
    hi, lo = read.max(axis=1), read.min(axis=1)
    assert np.all((hi < 100) & (lo > -100))  # the centre is inside the range
    t = 0.5 * (hi + lo)
    np.testing.assert_allclose(a.settings["guide_shift_um"], t, rtol=0, atol=1e-9)
    feas = nm.feasibility(c)
    ext = nm.projection_extremes(c, nvec, feas.lo, feas.hi)
    off = nd.project(nvec, G).ravel()
    F, Gm = (ext.fmax - off) * 1e3, (ext.fmin - off) * 1e3
    truth = np.maximum(0, F - t) + np.maximum(0, t - Gm)
    np.testing.assert_allclose(a.value, truth, rtol=0, atol=1e-6)
    # never below the true optimum, the band's width: any shift inside the true band gives it
    # (a plateau), so a reading fools the shift only where its centre leaves the true band
    assert np.all(a.value >= F - Gm - 1e-9)
    inside = (t >= Gm) & (t <= F)
    np.testing.assert_allclose(a.value[inside], (F - Gm)[inside], rtol=0, atol=1e-9)


def test_many_positions_and_no_error_give_the_exact_optimum(nominal):
    """The analytic limit: read at 720 positions (every 0.5 deg) with a vanishing error, the
    optimum of the reading is the exact joint optimum (the exact adjuster's plateau centre lies
    within PLATEAU_TOL_UM of the minimum, the 0.5-deg sampling misses an extreme by < 1e-3 um)."""
    c = _columns(nominal, 12)
    phi = 2 * np.pi * np.arange(720) / 720
    for names in (("beta",), ("beta", "guide_shift_um"),
                  ("beta", "guide_shift_um", "guide_angle")):
        s = exact(strategy_of(names))
        ref = adjust(c, s)
        got, read = adjust_measured(c, s, 10.0, phi, 0.0)
        d = got.total_um - ref.total_um
        assert np.all(np.isfinite(d)), names
        assert np.all(d >= -PLATEAU_TOL_UM - 1e-6) and np.all(d <= 5e-3), (names, d)
        # what the fitter read is the true figure there, up to the sampling
        assert np.all(np.abs(read - got.total_um) <= 2e-3), names
        np.testing.assert_array_equal(got.status, ref.status)


def test_a_reading_never_beats_the_exact_optimum_and_the_curve_falls(nominal):
    """Per machine, the true SumDelta at settings chosen from a reading is never below the
    exact joint optimum of beta + shift (global in its box): the yield at any sd is at most the
    exact row's. Monotone in sd is not a theorem (the same error pattern, scaled, may by chance
    move one machine's reading optimum closer to its true one), so the falling yield below is
    what this common-random-number sample shows, checked as such."""
    mech = as_mechanism(nominal)
    row = exact(strategy_of(("beta", "guide_shift_um"), name="beta+shift"))
    sds = (0.0, 1.0, 2.0, 4.0)
    curve = ST.measurement_curve(mech, "base", 40, SEED, row, sds, positions=36, limit_um=10.0)
    f = curve.to_dataframe()
    assert list(f["measurement_sd_um"]) == list(sds)
    assert (f[["ok", "out_of_spec", "cannot_close", "dead_point"]].sum(axis=1) == 40).all()
    y = curve.yields
    assert np.all(np.diff(y) <= 0) and y[-1] < y[0], y
    exact_row = ST.strategies(mech, "base", 40, SEED, {"r": row}, limit_um=10.0).get("r")
    for sd in sds[1:]:
        a = ST.strategies(mech, "base", 40, SEED, {"r": row}, measurement=MeasurementError(sd),
                          limit_um=10.0).get("r")
        assert np.all(a.value >= exact_row.value - PLATEAU_TOL_UM - 1e-9), sd


def test_reading_errors_come_from_their_own_stream_windowed_per_block():
    whole = me.normal_draws(7, 0, STREAM + 300, 24)
    np.testing.assert_array_equal(me.normal_draws(7, STREAM - 50, STREAM + 120, 24),
                                  whole[STREAM - 50:STREAM + 120])
    assert whole.shape == (STREAM + 300, 24)
    assert not np.array_equal(me.normal_draws(8, 0, 10, 24), whole[:10])
    # standard normals: mean ~0, sd ~1 over 19,200 draws
    assert abs(whole.mean()) < 0.03 and abs(whole.std() - 1) < 0.03


def test_measurement_error_validates_its_fields():
    for sd in (-1.0, float("nan"), True, "1"):
        with pytest.raises(ParameterError, match="sd_um"):
            MeasurementError(sd)
    for k in (2, 3601, 3.5):
        with pytest.raises(ParameterError, match="positions"):
            MeasurementError(1.0, k)
    m = MeasurementError(1.5, 24)
    assert m.label() == "normal sd 1.5 um at 24 positions"
    assert np.allclose(np.degrees(m.crank_angles_rad())[:3], [0, 15, 30])


def test_a_mechanism_without_a_measured_adjuster_refuses_the_option():
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    mech = load(mechanism_file("spatial_crank_rocker"))
    assert mech.compensators
    with pytest.raises(ParameterError, match="measurement_error"):
        ST.strategies(mech, next(iter(mech.tolerance_sets)), 4, 1,
                      {"all": tuple(mech.compensators)}, measurement=MeasurementError(1.0))


@pytest.mark.parametrize("argv, message", [
    (["--measurement-error", "-1"], "--measurement-error: must be a finite number >= 0"),
    (["--measurement-error", "x"], "--measurement-error: must be a number of um"),
    (["--measured-positions", "12"], "--measured-positions: needs --measurement-error"),
    (["--measurement-error", "1", "--measured-positions", "2"],
     "--measured-positions: must be a whole number in 3 .. 3600"),
])
def test_the_command_line_refuses_a_bad_reading_in_one_line(argv, message):
    code, out, err = run("needle", "strategies", "--n", "4", *argv)
    assert code == 2 and out == ""
    assert message in err and err.count("\n") == 1


def test_the_strategies_table_states_the_reading(tmp_path):
    code, out, err = run("needle", "strategies", "--n", "3", "--seed", "1", "--adjust",
                         "beta,guide_shift_um", "--measurement-error", "2",
                         "--measured-positions", "24", "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert obj["context"]["measurement_error"] == {"dist": "normal", "sd_um": 2.0,
                                                   "positions": 24}
    rows = {r["strategy"]: r for r in obj["rows"]}
    assert rows["none"]["measurement_error"] == "none"
    assert rows["beta+shift"]["measurement_error"] == "normal sd 2 um at 24 positions"
    for r in obj["rows"]:
        assert r["ok"] + r["out_of_spec"] + r["cannot_assemble"] + r["dead_point"] == r["n"] == 3
