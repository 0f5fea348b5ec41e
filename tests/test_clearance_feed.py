"""The feed's steps with its journals off centre: the feed's closed form does not see them, so
its figures are taken on the closed form's path moved by the file's own tooth displacement;
held to a brute-force crossing of the file's tooth path sampled 100 times finer."""

import numpy as np
import pytest

from sewtol import mechanisms as M
from sewtol.mechanism import loads
from sewtol.mechanism.clearance import pair_joints

K_FINE = 72000  # 0.005 deg: a linear crossing is exact to ~1e-10 mm here


@pytest.fixture(scope="module")
def feed():
    text = M.mechanism_file("feed_131").read_text()
    joints = sorted(pair_joints(loads(text, "f.toml").groups)["revolute"])
    pins = "".join(f'\n[[clearances]]\njoint = "{j}"\nfit = "H7/g6"\ndiameter_mm = 6\n'
                   for j in joints)
    return loads(text + pins, "f.toml")


def fine_step(mech, values, key, level, side):
    s = mech.state(values, q_rad=np.arange(K_FINE) * 2 * np.pi / K_FINE)
    p = s.points[key].p[0]
    y = (p.imag - level) * (1 if side == "above" else -1)
    work = y > 0
    i_in = np.flatnonzero(~work & np.roll(work, -1))
    i_out = np.flatnonzero(work & ~np.roll(work, -1))
    assert len(i_in) == len(i_out) == 1

    def cross(i):
        j = (i + 1) % K_FINE
        t = y[i] / (y[i] - y[j])
        return (p[i] + t * (p[j] - p[i])).real

    return cross(i_in[0]) - cross(i_out[0])


def test_the_steps_with_journals_off_centre_equal_a_brute_force_crossing(feed):
    rng = np.random.default_rng(7)
    values = {}
    for c in feed.clearances:
        r, t = c.radial_max_mm * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        values[f"{c.joint}_dx_mm"], values[f"{c.joint}_dy_mm"] = [r * np.cos(t)], [r * np.sin(t)]
    names = ["lower_step_mm", "upper_step_mm"]
    ideal = feed.evaluate(None, names).outputs
    pins = feed.evaluate(values, names).outputs
    nom = feed.nominal_values()
    for name, key, level, side in (("lower_step_mm", "Q1", nom["plate_mm"], "above"),
                                   ("upper_step_mm", "Q2", nom["plate_mm"] + nom["material_mm"],
                                    "below")):
        moved = pins[name][0] - ideal[name][0]
        brute = fine_step(feed, values, key, level, side) - fine_step(feed, None, key, level, side)
        assert abs(moved) > 1e-4  # the pins move the step by a few um, not by nothing
        # delta is interpolated linearly between the file's 0.5 deg samples: error <= h^2 / 8
        # max|delta''| ~ 1e-5 rad^2 x (a few 1e-2 mm / rad^2) ~ 1e-7 mm, 1e-3 of the move
        assert moved == pytest.approx(brute, abs=1e-7), name
    # the journals centred: the closed form itself, bit for bit
    bare = loads(M.mechanism_file("feed_131").read_text(), "f.toml").evaluate(None, names)
    for name in names:
        np.testing.assert_array_equal(ideal[name], bare.outputs[name])
