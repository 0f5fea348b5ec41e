"""Each seed mechanism's file against its Python module, and against exact figures.

The generic path of a file samples the turn (720 points); the modules compute the same outputs
their own way (the spatial rocker's batch module, the M6 module's chain and its closed-form
travel), so equality here checks the loader's groups and outputs against independent code.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import spatial_rocker_reference as scr
from sewtol import engine
from sewtol.mechanism import load
from sewtol.mechanisms.m6_needle import model as m6

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _batch(nominal: dict, rng, m: int, scale: dict) -> dict:
    return {k: nominal[k] + scale.get(k, 0.0) * rng.standard_normal(m) for k in nominal}


def test_spatial_file_equals_the_batch_module_and_the_exact_extremes():
    mech = load(EXAMPLES / "spatial_crank_rocker.toml")
    rng = np.random.default_rng(5)
    values = _batch(scr.nominal(), rng, 50, {"a": 0.05, "b": 0.1, "c": 0.05, "e": 0.1,
                                              "f": 0.2, "g": 0.2, "alpha": 0.5})
    ours = mech.evaluate(values)
    theirs = scr.evaluate(values)
    assert list(ours.status) == list(theirs.status) == ["ok"] * 50
    for name in ("rocker_swing_deg", "rocker_max_deg", "rocker_min_deg",
                 "rocker_tip_speed_max_m_s", "transmission_min_deg"):
        np.testing.assert_allclose(ours.outputs[name], theirs.outputs[name], rtol=1e-12,
                                   atol=1e-9, err_msg=name)
    # the sampled extremes sit inside the exact ones, within the sampling error of 0.5 deg steps
    x = engine.rocker_extremes(*(values[k] for k in "abcefg"), np.radians(values["alpha"]), 1.0)
    gap_max = np.degrees(x.psi_max) - ours.outputs["rocker_max_deg"]
    gap_min = ours.outputs["rocker_min_deg"] - np.degrees(x.psi_min)
    for gap in (gap_max, gap_min):
        assert np.all(gap >= -1e-9) and np.all(gap < 2e-3)


def test_m6_file_equals_the_module():
    mech = load(EXAMPLES / "m6_needle.toml")
    rng = np.random.default_rng(6)
    base = m6.M6Needle()
    names = [p.name for p in mech.parameters]
    nominal = {k: float(getattr(base, k)) for k in names if hasattr(base, k)}
    values = _batch(nominal, rng, 40, {"crank_mm": 0.02, "pivot_mm": 0.05, "arm_mm": 0.05,
                                        "rod_mm": 0.05})
    ours = mech.evaluate(values)
    theirs = m6.evaluate(base.override(**values), samples=mech.header.samples)
    assert list(ours.status) == list(theirs.status)
    np.testing.assert_allclose(ours.outputs["speed_max_m_s"], theirs.speed_max_m_s, rtol=1e-12)
    np.testing.assert_allclose(ours.outputs["accel_max_m_s2"], theirs.accel_max_m_s2,
                               rtol=1e-12)
    # the file samples the travel; the module's is exact (the lever's closed-form extremes)
    gap = theirs.travel_mm - ours.outputs["travel_mm"]
    assert np.all(gap >= -1e-9) and np.all(gap < 1e-3)


@pytest.mark.parametrize("name", ["spatial_crank_rocker", "m6_needle", "khujand_feed",
                                  "presser_foot"])
def test_every_seed_file_runs_a_tolerance_study_with_counts_that_add_up(name):
    from sewtol.studies import montecarlo as MC

    mech = load(EXAMPLES / f"{name}.toml")
    tol = next(iter(mech.tolerance_sets.values()))
    res = MC.montecarlo(mech, tol, n=300, seed=11)
    table = res.summary_frame()
    assert len(res.to_dataframe()) == 300
    for _, row in table.iterrows():
        assert row["ok"] + row["out_of_spec"] + row["cannot_close"] + row["dead_point"] == 300


FOOT_NAMES = {"r": "crank_mm", "L": "rod_mm", "a": "offset_mm", "omega_rad_s": "speed_rad_s",
              "phase": "phase_deg", "y_m": "material_mm", "m_kg": "mass_kg",
              "k_n_per_mm": "stiffness_n_per_mm", "F_n": "preload_n", "zeta": "damping_ratio"}


def test_presser_file_equals_the_module_and_counts_machines_that_never_lose_contact():
    from sewtol.mechanisms.presser_foot import model as pf
    from sewtol.studies import montecarlo as MC

    mech = load(EXAMPLES / "presser_foot.toml")
    nominal = {p.name: p.nominal for p in mech.parameters}
    assert set(nominal) == set(FOOT_NAMES)
    rng = np.random.default_rng(8)
    values = _batch(nominal, rng, 30, {"r": 0.05, "L": 0.1, "a": 0.1, "y_m": 0.3})
    values["y_m"][:3] = 70.0  # above the seat's lowest point (67.5): contact is never lost
    ours = mech.evaluate(values)
    theirs = pf.evaluate(pf.PresserFoot(**{FOOT_NAMES[k]: v for k, v in values.items()}))
    assert list(theirs.status[:3]) == ["never_lost"] * 3
    for name in ("loss_deg", "regain_deg"):
        np.testing.assert_allclose(ours.outputs[name], getattr(theirs, name), rtol=1e-12)
    np.testing.assert_allclose(ours.outputs["separation_mm"][3:], theirs.separation_mm[3:],
                               rtol=1e-12)
    assert np.all(ours.outputs["separation_mm"][:3] == 0.0)
    # a Monte-Carlo counts the machines whose loss angle has no value, never drops them
    tol = mech.tolerance_sets["assumed"] if "assumed" in mech.tolerance_sets else next(
        iter(mech.tolerance_sets.values()))
    res = MC.montecarlo(mech, tol, n=200, seed=3)
    row = res.summary_frame().set_index("output").loc["loss_deg"]
    defined = res.machines["loss_deg"].notna().sum()
    assert row["undefined"] + defined + row["cannot_close"] + row["dead_point"] == 200


@pytest.mark.parametrize("name", ["spatial_crank_rocker", "spatial_crank_slider",
                                  "khujand_feed"])
def test_committed_file_reports_regenerate_at_their_printed_precision(tmp_path, name):
    """`make report` writes these with `sewtol run NAME report --seed 2026`; every CSV comes
    back within one unit of its last printed place (on any CPU: CI repeats this narrowed)."""
    from cli_helpers import run
    from test_report_reproducible import compare_printed

    committed = EXAMPLES.parent / "reports" / name
    code, _, err = run("run", name, "report", "--seed", "2026", "--out", str(tmp_path / name))
    assert code == 0, err
    names = sorted(p.name for p in committed.glob("*.csv"))
    assert names and names == sorted(p.name for p in (tmp_path / name).glob("*.csv"))
    for csv in names:
        new = (tmp_path / name / csv).read_text().replace(str(EXAMPLES.parent) + "/", "")
        assert compare_printed(new, (committed / csv).read_text()) == [], csv
