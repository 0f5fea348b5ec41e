"""The loaded mode of joint clearances: joint forces from the pair parameters (virtual work)
against the M6 needle's own Newton-Euler kinetostatics, a load of constant direction (the
loaded deviation is c J . u), and a load that reverses with the motion (the journals cross
their clearance where, and only where, the force's direction reverses)."""

import dataclasses

import numpy as np
import pytest

from sewtol import mechanisms as M
from sewtol.errors import ParameterError
from sewtol.mechanism import loads
from sewtol.mechanism.clearance import pair_joints
from sewtol.mechanism.kinetostatics import PointLoad, joint_forces
from sewtol.mechanisms.m6_needle import model as m6
from sewtol.studies import clearance as K
from test_clearance_model import CLEARANCES, FOUR_BAR, RADII

FOUR_BAR_FINE = FOUR_BAR.replace("samples = 12", "samples = 720")


def four_bar():
    return loads(FOUR_BAR_FINE + CLEARANCES, "four_bar.toml")


def m6_with_pins():
    text = M.mechanism_file("m6_needle").read_text()
    joints = sorted(pair_joints(loads(text, "m6.toml").groups)["revolute"])
    pins = "".join(f'\n[[clearances]]\njoint = "{j}"\nradial_mm = 0.01\n' for j in joints)
    return loads(text + pins, "m6.toml")


def test_joint_forces_equal_the_m6_newton_euler_reactions():
    # the M6 drive with its needle bar's published mass and a 5 N needle force against the
    # bar's motion; lever and shaft massless (the file draws no lever centre of mass, and a
    # point load has no rotary inertia): every pair's force is the 8x8 solution's, to 1e-8 N
    mech = m6_with_pins()
    p = dataclasses.replace(m6.M6Needle(), lever_kg=0.0, lever_kgm2=0.0, shaft_kg=0.0)
    r = m6.reactions(p, samples=mech.samples, needle_force_N=5.0)
    jf = joint_forces(mech, None, [PointLoad("J", mass_kg=p.bar_kg, force_N=5.0,
                                             direction_deg=90.0, against_motion=True)])
    assert jf.rpm == pytest.approx(4000.0)
    q = mech.angles_rad()
    chain = m6.chain(m6.P.column(p, None), q)
    u_rod = (chain["B"].p - chain["J"].p) / np.abs(chain["B"].p - chain["J"].p)
    # each journal presses on its bearing with minus the bearing's force on it
    reference = {"O1": -r.F02, "A": -r.N, "O2": -r.F04, "B": -r.S * u_rod, "J": -r.S * u_rod}
    for j, ref in reference.items():
        np.testing.assert_allclose(jf.force_N[j][0], ref, rtol=0, atol=1e-6, err_msg=j)
    assert np.max(np.abs(r.S)) > 30  # a load worth checking (the bar's inertia at 4000 rpm)


def test_a_load_of_constant_direction_gives_c_j_u():
    # a constant force on the rod's journal at the crank pin L of a four-bar: the crank pin and
    # the frame pivot O carry all of it, the rest of the rod and the rocker nothing (with the
    # crank held, a load at L goes straight into the crank), so the journals at O and L sit at
    # c u with u the force's direction
    mech = four_bar()
    force = PointLoad("L", force_N=40.0, direction_deg=-60.0)
    res = K.loaded(mech, None, "P_y_mm", [force], rpm=1000.0)
    u = np.exp(-1j * np.radians(60.0))
    for j in "OL":
        np.testing.assert_allclose(res.force_N[j][0], 40.0 * u, rtol=1e-8)
    for j in "MD":
        assert np.max(np.abs(res.force_N[j])) < 1e-9
        assert not np.any(res.offsets_mm[j]) and not res.crossings_deg[j][0]
    jac = K.jacobian(mech, None, "P_y_mm")
    expected = sum(RADII[j] * (np.conj(jac[j][0]) * u).real for j in "OL")
    # u from the finite-difference forces, exact to ~1e-12
    np.testing.assert_allclose(res.total[0], expected, rtol=1e-9)
    assert res.crossings_deg["O"] == res.crossings_deg["L"] == [()]
    # the real model with the journals at c u moves the signal by the loaded deviation: first
    # order, to c/l ~ 1e-3 of the largest move
    s0 = K.signal(mech, mech.state(), "P_y_mm")[0]
    offsets = {}
    for j in "OL":
        offsets[f"{j}_dx_mm"], offsets[f"{j}_dy_mm"] = [RADII[j] * u.real], [RADII[j] * u.imag]
    s = K.signal(mech, mech.state(offsets), "P_y_mm")[0]
    np.testing.assert_allclose(s - s0, res.total[0], rtol=0,
                               atol=2e-3 * np.max(np.abs(res.total[0])))


def test_a_force_that_reverses_with_the_motion_makes_the_journals_cross():
    # 30 N on the coupler point P along y, against its motion: the same forces as a constant
    # 30 N along -y times the sign of P's speed. So a journal crosses where the constant
    # load's force passes through zero or where P turns (its top and bottom), not at both
    mech = four_bar()
    against = K.loaded(mech, None, "psi_deg",
                       [PointLoad("P", force_N=30.0, direction_deg=90.0, against_motion=True)],
                       rpm=1000.0)
    constant = K.loaded(mech, None, "psi_deg",
                        [PointLoad("P", force_N=30.0, direction_deg=-90.0)], rpm=1000.0)
    st = mech.state()
    vy = st.points["P"].dp[0].imag
    k = np.flatnonzero(np.sign(vy) != np.sign(np.roll(vy, -1)))
    step = 0.5
    turns = (against.q_deg[k] + step * vy[k] / (vy[k] - np.roll(vy, -1)[k])) % 360
    assert len(turns) == 2  # P's lowest and highest place
    for j in "OLMD":
        got = np.array(against.crossings_deg[j][0])
        expected = np.sort(np.concatenate([turns, constant.crossings_deg[j][0]]))
        assert got.size == expected.size, j
        # the force is sampled every 0.5 deg and the turn is interpolated: within a sample
        np.testing.assert_allclose(np.sort(got), expected, atol=step, err_msg=j)
        # between crossings the journal holds its side: the loaded offsets of the two loads
        # differ exactly by the sign of P's speed
        np.testing.assert_allclose(against.offsets_mm[j][0],
                                   np.sign(vy) * constant.offsets_mm[j][0], atol=1e-12)
    assert sum(len(v[0]) for v in against.crossings_deg.values()) >= 8


def test_loaded_refusals_name_field_rule_and_value():
    mech = four_bar()
    with pytest.raises(ParameterError, match="rpm"):
        K.loaded(mech, None, "psi_deg", [PointLoad("P", mass_kg=0.01)])
    with pytest.raises(ParameterError, match="point.*must name a point.*Q"):
        K.loaded(mech, None, "psi_deg", [PointLoad("Q", mass_kg=0.01)], rpm=100.0)
    with pytest.raises(ParameterError, match="mass_kg"):
        PointLoad("P", mass_kg=-1.0)
    with pytest.raises(ParameterError, match="loads"):
        joint_forces(mech, None, [], rpm=100.0)
