"""Adjustment as a fitter can do it: each compensator's resolution and setting error, the
compensators set one by one in the fitting order (sewtol.studies.strategies.set_in_order), the
strategies table stating both, and the yield-vs-setting-error curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cli_helpers import run, strict_loads
from sewtol import setting_error as se
from sewtol.errors import ParameterError
from sewtol.law import STREAM
from sewtol.mechanism import loads
from sewtol.mechanisms import mechanism_file
from sewtol.mechanisms.needle_208 import compensators as C
from sewtol.protocol import input_law, machines
from sewtol.setting_error import SettingError
from sewtol.studies import strategies as ST
from sewtol.studies.adjusting import adjusted
from sewtol.tables.needle_208 import as_mechanism, needle_set, strategies_table

ROOT = Path(__file__).resolve().parents[1]
T = C.NEEDLE_COMPENSATORS
OUT = "SumDelta_um"


@pytest.fixture(scope="module")
def mech(nominal):
    return as_mechanism(nominal)


def _machines(mech, n, seed=2026, tolerances="base"):
    return machines(mech, input_law(mech, needle_set(tolerances)).draw(n, seed))


def _bsa(error=None, resolution=0.0, name="bsa"):
    angle = T["guide_angle"].with_changes(setting_error=error, resolution=resolution)
    return C.Strategy(name, (T["beta"], T["guide_shift_um"], angle))


# --- the law of one setting error --------------------------------------------------------------


def test_setting_error_laws_from_uniforms():
    u = np.array([0.5, 0.975, 0.025, 0.0, 1.0])
    np.testing.assert_allclose(SettingError("uniform", 0.02).from_unit(u),
                               [0.0, 0.019, -0.019, -0.02, 0.02], atol=1e-15)
    z = SettingError("normal", 0.01).from_unit(u[:3])
    np.testing.assert_allclose(z, [0.0, 0.01 * 1.959963984540054, -0.01 * 1.959963984540054],
                               rtol=1e-12)
    assert SettingError("uniform", 0.03).sd == pytest.approx(0.03 / np.sqrt(3))
    for bad in (SettingError, ):
        with pytest.raises(ParameterError, match="setting_error.dist"):
            bad("gauss", 0.1)
        with pytest.raises(ParameterError, match="setting_error.sd: must be a finite number"):
            bad("normal", -0.1)


def test_draws_are_a_stream_of_their_own_and_any_window_draws_the_same():
    full = se.unit_draws(7, "guide_angle", 0, 3 * STREAM)
    np.testing.assert_array_equal(full[STREAM - 3: 2 * STREAM + 5],
                                  se.unit_draws(7, "guide_angle", STREAM - 3, 2 * STREAM + 5))
    np.testing.assert_array_equal(full, se.unit_draws(7, "guide_angle", 0, 3 * STREAM))
    assert not np.array_equal(full, se.unit_draws(7, "beta", 0, 3 * STREAM))
    assert not np.array_equal(full, se.unit_draws(8, "guide_angle", 0, 3 * STREAM))
    # not the machines' own uniforms (children of the same seed)
    from sewtol.law import draw_units, unit_streams
    assert not np.array_equal(full[:STREAM], draw_units(unit_streams(7, STREAM), 1)[:, 0])
    assert 0.0 < full.min() and full.max() < 1.0 and abs(full.mean() - 0.5) < 0.03


def test_snap_rounds_to_the_resolution():
    np.testing.assert_allclose(se.snap([0.013, -0.027, 0.006, 0.004], 0.01), [0.01, -0.03, 0.01, 0.0])
    np.testing.assert_array_equal(se.snap([0.013], 0.0), [0.013])


# --- the sequential setting on the needle -------------------------------------------------------


def test_exact_compensators_are_the_joint_optimum_bit_for_bit(mech):
    """Setting error 0: one joint optimum, today's numbers."""
    vals = _machines(mech, 40)
    a = ST.set_in_order(mech, vals, _bsa(), OUT, {}, limit_um=10.0)
    b = adjusted(mech, vals, _bsa().compensators, OUT, limit_um=10.0)
    np.testing.assert_array_equal(a.value, b.value)
    for k in b.settings:
        np.testing.assert_array_equal(a.settings[k], b.settings[k])


def test_the_exact_row_reproduces_the_committed_strategies_report(nominal):
    """Machines 0..59 of the committed report (base set, seed 2026): the exact beta + shift +
    angle row gives its per-machine SumDelta (written to 9 significant digits)."""
    path = ROOT / "reports" / "needle_208" / "strategies_base_machines_beta_shift_angle_exact.csv"
    ref = pd.read_csv(path).iloc[:60]
    rows = [r for r in C.default_strategies() if r.name == "beta+shift+angle exact"]
    res = strategies_table(nominal, "base", 60, 2026, rows)
    got = res.machines("beta+shift+angle exact")
    np.testing.assert_allclose(got["total_after_um"], ref["total_after_um"], rtol=2e-9,
                               atol=1e-9)
    assert res.to_dataframe().loc[0, "setting_error"] == "none"


def test_a_setting_error_is_added_to_the_rounded_optimum_and_the_rest_re_set(mech):
    """The angle set first: the setting made is the exact optimum rounded to the resolution
    plus the drawn error; beta and the shift are then the joint optimum given that angle."""
    n, err = 30, SettingError("uniform", 0.02)
    vals = _machines(mech, n)
    u = se.unit_draws(2026, "guide_angle", 0, n)
    ideal = adjusted(mech, vals, _bsa().compensators, OUT, limit_um=10.0)
    a = ST.set_in_order(mech, vals, _bsa(err, resolution=0.005), OUT, {"guide_angle": u},
                        limit_um=10.0)
    want = np.clip(se.snap(ideal.settings["guide_angle"], 0.005) + err.from_unit(u), -0.1, 0.1)
    np.testing.assert_allclose(a.settings["guide_angle"], want, rtol=0, atol=1e-12)
    fixed = dict(vals, guide_angle=mech.nominal_values()["guide_angle"] + want)  # an offset
    rest = adjusted(mech, fixed, (T["beta"], T["guide_shift_um"]), OUT, limit_um=10.0)
    np.testing.assert_array_equal(a.value, rest.value)
    np.testing.assert_array_equal(a.settings["beta"], rest.settings["beta"])
    # a setting error never helps the machine beyond the joint optimum
    assert np.all(a.value >= ideal.value - 2e-3)


def test_resolution_alone_rounds_the_setting(mech):
    n = 25
    vals = _machines(mech, n)
    ideal = adjusted(mech, vals, _bsa().compensators, OUT, limit_um=10.0)
    a = ST.set_in_order(mech, vals, _bsa(resolution=0.02), OUT, {}, limit_um=10.0)
    x = a.settings["guide_angle"]
    np.testing.assert_allclose(x / 0.02, np.round(x / 0.02), atol=1e-9)
    assert np.all(np.abs(x - ideal.settings["guide_angle"]) <= 0.01 + 1e-12)


def test_a_huge_setting_error_drives_the_yield_to_the_end_stops(mech):
    """Analytic limit: an error far beyond the range puts the angle on an end stop, -0.1 deg
    where the draw is below 1/2 and +0.1 deg above; beta and the shift are re-set there."""
    n = 60
    vals = _machines(mech, n)
    u = se.unit_draws(2026, "guide_angle", 0, n)
    for err in (SettingError("normal", 1e6), SettingError("uniform", 1e6)):
        a = ST.set_in_order(mech, vals, _bsa(err), OUT, {"guide_angle": u}, limit_um=10.0)
        stop = np.where(u < 0.5, -0.1, 0.1)
        np.testing.assert_array_equal(a.settings["guide_angle"], stop)
        turned = mech.nominal_values()["guide_angle"] + stop  # the angle is an offset
        ref = adjusted(mech, dict(vals, guide_angle=turned), (T["beta"], T["guide_shift_um"]),
                       OUT, limit_um=10.0)
        np.testing.assert_array_equal(a.value, ref.value)


def test_the_fitting_order_sets_the_guide_first_and_beta_last():
    s = C.strategy_of(("beta", "guide_shift_um", "guide_angle", "CD"))
    assert [c.name for c in s.fitting_order] == ["guide_angle", "guide_shift_um", "CD", "beta"]
    assert [c.name for c in C.strategy_of(("CD", "beta")).fitting_order] == ["CD", "beta"]


# --- the strategies study: the table states it, the same seed gives the same table ------------


def test_rows_state_resolution_and_setting_error_and_the_realistic_row_is_below_100(nominal):
    res = strategies_table(nominal, "base", 40, 2026)
    t = res.to_dataframe().set_index("strategy")
    assert t.loc["beta+shift+angle", "setting_error"] == "guide_angle normal sd 0.01 deg"
    assert t.loc["beta+shift+angle exact", "setting_error"] == "none"
    assert (t["resolution"] == "none").all()
    assert t.loc["beta+shift+angle exact", "yield"] == 1.0
    assert t.loc["beta+shift+angle", "yield"] < 1.0
    # the same machines: the exact row is never worse than the one set with an error
    assert np.all(res.get("beta+shift+angle exact").value
                  <= res.get("beta+shift+angle").value + 2e-3)


def test_same_seed_same_table_for_any_chunking(mech, monkeypatch):
    rows = {"bsa": _bsa(SettingError("normal", 0.01)), "b": C.strategy_of(("beta",))}
    a = ST.strategies(mech, "base", 14, 3, rows, OUT, limit_um=10.0)
    b = ST.strategies(mech, "base", 14, 3, rows, OUT, limit_um=10.0)
    monkeypatch.setattr(ST, "CHUNK", 5)  # three chunks, each drawing its own window
    c = ST.strategies(mech, "base", 14, 3, rows, OUT, progress=lambda *_: None, limit_um=10.0)
    for other in (b, c):
        pd.testing.assert_frame_equal(a.to_dataframe(), other.to_dataframe())
        np.testing.assert_array_equal(a.get("bsa").value, other.get("bsa").value)
    d = ST.strategies(mech, "base", 14, 4, rows, OUT, limit_um=10.0)
    assert not np.array_equal(a.get("bsa").settings["guide_angle"],
                              d.get("bsa").settings["guide_angle"])


def test_yield_curve_starts_at_the_exact_row_and_falls(mech):
    widths = [0.0, 0.01, 1e6]
    curve = ST.yield_curve(mech, "base", 30, 2026, _bsa(), "guide_angle", widths,
                           limit_um=10.0)
    f = curve.to_dataframe()
    assert list(f["sd_deg"]) == widths
    assert (f[["ok", "out_of_spec", "cannot_close", "dead_point"]].sum(axis=1) == 30).all()
    exact = ST.strategies(mech, "base", 30, 2026, {"x": _bsa()}, OUT, limit_um=10.0)
    assert f.loc[0, "ok"] == exact.row(0)["ok"]
    assert f.loc[0, "yield"] >= f.loc[1, "yield"] >= f.loc[2, "yield"]
    import matplotlib.pyplot as plt

    from sewtol.reports import plots
    fig, ax = plt.subplots()
    assert plots.yield_vs_setting_error(curve, ax) is ax
    assert ax.lines[0].get_ydata()[0] == pytest.approx(100 * f.loc[0, "yield"])
    plt.close(fig)
    with pytest.raises(ParameterError, match="compensator"):
        ST.yield_curve(mech, "base", 4, 1, _bsa(), "CD", [0.0], limit_um=10.0)


# --- a mechanism file declares it ----------------------------------------------------------------


def _needle_text(extra: str) -> str:
    text = mechanism_file("needle_208").read_text()
    anchor = 'high = 100\nmode = "offset"\n'
    assert anchor in text
    return text.replace(anchor, anchor + extra)


def test_a_file_declares_setting_errors_and_the_generic_study_uses_them():
    m = loads(_needle_text('setting_error = {dist = "normal", sd = 3.0}\nresolution = 2\n'))
    g = m.compensators["guide_shift"]
    assert (g.setting_error, g.resolution) == (SettingError("normal", 3.0), 2.0)
    assert loads(_needle_text("setting_error = 0.5\n")).compensators["guide_shift"] \
        .setting_error == SettingError("uniform", 0.5)
    assert loads(_needle_text("setting_error = 0\n")).compensators["guide_shift"] \
        .setting_error is None
    res = ST.strategies(m, "base", 12, 5, {"s": ("guide_shift",)}, fast=False)
    row = res.to_dataframe().iloc[0]
    assert (row["resolution"], row["setting_error"]) == ("guide_shift 2 um",
                                                         "guide_shift normal sd 3 um")
    # the shift made: the optimum rounded to 2 um plus 3 um * z, z the stream's normal scores
    z = SettingError("normal", 3.0).from_unit(se.unit_draws(5, "guide_shift", 0, 12))
    made = res.get("s").settings["guide_shift_um"]  # absolute (the nominal's shift is 0)
    resid = made - z
    np.testing.assert_allclose(resid / 2.0, np.round(resid / 2.0), atol=1e-6)


@pytest.mark.parametrize("value,field,rule", [
    ('{dist = "gauss", sd = 1}', "setting_error.dist", "must be one of normal, uniform"),
    ('{dist = "normal", sd = -1}', "setting_error.sd", "must be a finite number >= 0"),
    ('{dist = "normal", half_width = 1}', "setting_error", "takes dist and sd only"),
    ('{dist = "uniform"}', "setting_error.half_width", "is required"),
    ('"x"', "setting_error", "must be a finite number")])
def test_bad_setting_errors_in_a_file_are_one_line(value, field, rule):
    with pytest.raises(ParameterError) as e:
        loads(_needle_text(f"setting_error = {value}\n"))
    assert field in e.value.field and rule in e.value.rule
    assert "\n" not in str(e.value)


# --- the command line ---------------------------------------------------------------------------


def test_cli_setting_error_adds_a_row_stating_it():
    code, out, err = run("needle", "strategies", "--n", "4", "--adjust",
                         "beta,guide_shift_um,guide_angle", "--setting-error",
                         "guide_angle=uniform:0.02", "--format", "json")
    assert code == 0, err
    rows = {r["strategy"]: r for r in strict_loads(out)["rows"]}
    assert rows["beta+guide_shift_um+guide_angle"]["setting_error"] == \
        "guide_angle uniform +-0.02 deg"
    assert rows["beta+shift+angle"]["setting_error"] == "guide_angle normal sd 0.01 deg"


@pytest.mark.parametrize("argv,message", [
    (("strategies", "--adjust", "guide_angle", "--setting-error", "guide_angle=x"),
     "--setting-error guide_angle: must be a number"),
    (("strategies", "--adjust", "guide_angle", "--setting-error", "guide_angle=-0.1"),
     "--setting-error guide_angle: must be a finite number >= 0"),
    (("strategies", "--adjust", "guide_angle", "--setting-error", "guide_angle=gauss:1"),
     "must be SD, normal:SD or uniform:HALF_WIDTH"),
    (("strategies", "--adjust", "beta", "--setting-error", "CD=0.1"),
     "--setting-error: names 'CD', which --adjust does not list"),
    (("strategies", "--setting-error", "beta=0.1"), "--setting-error: needs --adjust"),
    (("strategies", "--adjust", "beta", "--setting-error", "beta=1",
      "--setting-error", "beta=2"), "--setting-error: gives the same name twice"),
    (("montecarlo", "--adjust", "beta", "--setting-error", "beta=0.1"),
     "--setting-error: is applied by the strategies study only")])
def test_cli_setting_error_refusals_are_one_line(argv, message):
    code, out, err = run("needle", *argv, "--n", "4")
    assert code == 2 and out == ""
    assert message in err and err.count("\n") == 1


# --- housing tolerances --------------------------------------------------------------------------


def test_base_housing_is_the_base_set_plus_the_housing_bores():
    from sewtol.mechanism import load
    from sewtol.tolerances import NEEDLE_208_SETS, needle_set

    in_file = load(mechanism_file("needle_208")).tolerance_sets["base_housing"]
    shipped = needle_set(str(ROOT / "examples" / "tolerances" / "needle_208_housing.toml")
                         + ":base_housing")
    assert in_file.as_dict() == shipped.as_dict()
    items = {t.param: (t.lower, t.upper, t.dist) for t in in_file.items}
    base = {t.param: (t.lower, t.upper, t.dist) for t in NEEDLE_208_SETS["base"].items}
    assert {k: items[k] for k in base} == base
    housing = {k: v for k, v in items.items() if k not in base}
    assert housing == {**{k: (-0.02, 0.02, "uniform") for k in
                          ("Ax", "Ay", "Dx", "Dy", "guide_x", "guide_y")},
                       "guide_angle": (-0.0229, 0.0229, "uniform")}
    # 0.02 mm over the 50 mm guide
    assert np.degrees(np.arctan(0.02 / 50)) == pytest.approx(0.0229, abs=1e-4)
    # the default sets (and the committed reports) do not include it
    assert "base_housing" not in NEEDLE_208_SETS
