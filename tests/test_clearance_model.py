"""Joint clearances in the model: each revolute pair's journal offset (a pair parameter), the
clearance Jacobian (finite differences of the real model against the loop's closed-form
linearisation), the first-order worst case against a brute-force enumeration of contact
directions, and Ting, Zhu & Watkins' bound."""

from pathlib import Path

import numpy as np
import pytest

from sewtol.errors import ParameterError
from sewtol.mechanism import loads
from sewtol.studies import clearance as K

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

FOUR_BAR = """
format = "sewtol-mechanism/1"

[mechanism]
name = "four_bar"
title = "crank-rocker O-L-M-D with a coupler point P on the rod"
samples = 12

[parameters]
a = { nominal = 10.0, unit = "mm", rule = "positive" }
b = { nominal = 35.0, unit = "mm", rule = "positive" }
c = { nominal = 30.0, unit = "mm", rule = "positive" }
Dx = { nominal = 30.0, unit = "mm", rule = "finite" }

[[groups]]
type = "point"
name = "O"
x = 0.0
y = 0.0

[[groups]]
type = "point"
name = "D"
x = "Dx"
y = 0.0

[[groups]]
type = "crank"
name = "L"
center = "O"
radius = "a"

[[groups]]
type = "rrr"
name = "M"
p1 = "L"
r1 = "b"
p2 = "D"
r2 = "c"
branch = 1

[[groups]]
type = "on_body"
name = "P"
origin = "L"
direction = ["L", "M"]
u = 20.0
v = 8.0

[[outputs]]
name = "P_y_mm"
unit = "mm"
type = "coordinate"
point = "P"
axis = "y"
measure = "max"

[[outputs]]
name = "L_x_mm"
unit = "mm"
type = "coordinate"
point = "L"
axis = "x"
measure = "max"

[[outputs]]
name = "psi_deg"
unit = "deg"
type = "angle"
direction = ["D", "M"]
measure = "max"
"""
RADII = {"O": 0.01, "L": 0.02, "M": 0.005, "D": 0.015}
CLEARANCES = "".join(f'\n[[clearances]]\njoint = "{j}"\nradial_mm = {c}\n'
                     for j, c in RADII.items())
AB, UV = 35.0, 20.0 + 8.0j


def four_bar():
    return loads(FOUR_BAR + CLEARANCES, "four_bar.toml")


def needle_with_pins():
    text = (EXAMPLES / "needle_208.toml").read_text()
    pins = "".join(f'\n[[clearances]]\njoint = "{j}"\nfit = "H7/g6"\ndiameter_mm = 8\n'
                   for j in "FLMABCD")
    return loads(text, "n.toml"), loads(text + pins, "n.toml")


def loop(mech):
    """The four-bar's closed-form linearisation: with R = r_O + r_L + r_M - r_D the loop
    O + a e^iq + b e^itheta = D + c e^ipsi gives  i b e^itheta dtheta - i c e^ipsi dpsi = -R;
    P = L + r_O + r_L + (u + iv) e^itheta. Returns per angle the gradients of theta, psi (rad)
    and P (mm) with respect to R (as complex dq/dRx + i dq/dRy) and the geometry."""
    st = mech.state()
    L, M, P = (st.points[k].p[0] for k in "LMP")
    theta, psi = np.angle(M - L), np.angle(M - 30.0)
    u, v = 1j * AB * np.exp(1j * theta), -1j * 30.0 * np.exp(1j * psi)

    def solve(w):  # real dtheta, dpsi of u dtheta + v dpsi = w
        return ((np.conj(v) * w).imag / (np.conj(v) * u).imag,
                (np.conj(u) * w).imag / (np.conj(u) * v).imag)

    tx, px = solve(-1.0 + 0j)
    ty, py = solve(-1j)
    return {"theta": tx + 1j * ty, "psi": px + 1j * py, "P": P, "L": L, "theta_rad": theta}


def test_zero_offsets_give_todays_answers_exactly():
    for name in ("needle_208", "m6_needle"):
        text = (EXAMPLES / f"{name}.toml").read_text()
        bare = loads(text, "x.toml")
        joints = {"needle_208": "FLMABCD", "m6_needle": ["O1", "A", "O2", "J", "B"]}[name]
        pins = "".join(f'\n[[clearances]]\njoint = "{j}"\nradial_mm = 0.01\n' for j in joints)
        clr = loads(text + pins, "x.toml")
        assert len(clr.pair_parameters) == 2 * len(joints)
        p = bare.parameters[0]
        values = {p.name: p.nominal * np.array([0.999, 1.0, 1.001])}
        a, b = clr.evaluate(values), bare.evaluate(values)
        for k in a.outputs:
            np.testing.assert_array_equal(a.outputs[k], b.outputs[k])
        zero = {n.name: np.zeros(3) for n in clr.pair_parameters}
        c = clr.evaluate({**values, **zero})
        for k in a.outputs:
            np.testing.assert_array_equal(c.outputs[k], b.outputs[k])
        np.testing.assert_array_equal(c.status, b.status)


def test_offsets_enter_where_the_pairs_are():
    mech = four_bar()
    r = 0.01 + 0.004j
    base = mech.state()
    for j in "OLMD":
        st = mech.state({f"{j}_dx_mm": r.real, f"{j}_dy_mm": r.imag})
        L, M, P = (st.points[k].p[0] for k in "LMP")
        # the loop closes with the journals r from their bearings: rod b from L, rocker c
        # from the pivot D (moved by r_D), the rocker's journal r_M from the rod's end
        rod_end = M - (r if j == "M" else 0)
        pivot = 30.0 + (r if j == "D" else 0)
        np.testing.assert_allclose(np.abs(rod_end - L), AB, rtol=1e-13)
        np.testing.assert_allclose(np.abs(M - pivot), 30.0, rtol=1e-13)
        crank_pin = L - (r if j == "L" else 0) - (r if j == "O" else 0)
        np.testing.assert_allclose(np.abs(crank_pin), 10.0, rtol=1e-13)
        # P is on the rod: fixed in the rod's frame L -> rod's end
        np.testing.assert_allclose((P - L) / ((rod_end - L) / AB), UV, atol=1e-12)
        assert not np.allclose(M, base.points["M"].p[0], atol=1e-6)


def test_the_jacobian_by_finite_differences_is_the_loops_closed_form():
    mech = four_bar()
    lin = loop(mech)
    for axis in ("P_y_mm", "psi_deg"):
        jac = K.jacobian(mech, None, axis)
        for j, sign in (("O", 1), ("L", 1), ("M", 1), ("D", -1)):
            if axis == "psi_deg":
                want = sign * lin["psi"] * 180.0 / np.pi
            else:
                # dP = r_O + r_L + i (u + iv) e^itheta dtheta; y-component of each
                rot = 1j * UV * np.exp(1j * lin["theta_rad"])
                want = sign * (rot.imag * lin["theta"].real + 1j * rot.imag * lin["theta"].imag)
                if j in "OL":
                    want = want + 1j  # dP_y/dr_y = 1
            # central differences, h = 1e-4 mm: truncation ~ h^2 |s'''| ~ 1e-8 relative
            np.testing.assert_allclose(jac[j][0], want, rtol=1e-6, atol=1e-9)


def test_worst_case_equals_brute_force_over_contact_directions():
    mech = four_bar()
    n_dir = 24  # grid on each circle: at most 1 - cos(7.5 deg) = 0.86 % below the true max
    t = 2 * np.pi * np.arange(n_dir) / n_dir
    grids = np.meshgrid(*[np.arange(n_dir)] * 4, indexing="ij")
    values = {}
    for g, (j, c) in zip(grids, RADII.items(), strict=True):
        values[f"{j}_dx_mm"] = c * np.cos(t[g.ravel()])
        values[f"{j}_dy_mm"] = c * np.sin(t[g.ravel()])
    for output in ("P_y_mm", "psi_deg"):
        s0 = K.signal(mech, mech.state(), output)[0]
        s = K.signal(mech, mech.state(values), output)
        brute = np.max(np.abs(s - s0), axis=0)
        wc = K.worst_case(mech, None, output).total[0]
        # the grid's max lies within 0.86 % below the true; second order adds ~ c/l ~ 1e-3
        assert np.all(brute <= wc * 1.01)
        assert np.all(brute >= wc * 0.99)


def test_ting_bound_holds_and_is_reached():
    mech = four_bar()
    lin = loop(mech)
    total_c = sum(RADII.values())
    # direction of a link: every pair of the loop weighs the same, W = (sum c) |dpsi/dR|
    jac = K.jacobian(mech, None, "psi_deg")
    norms = np.array([np.abs(jac[j][0]) for j in "OLMD"])
    np.testing.assert_allclose(norms, np.broadcast_to(norms[0], norms.shape), rtol=1e-6)
    wc = K.worst_case(mech, None, "psi_deg").total[0]
    np.testing.assert_allclose(wc, total_c * np.abs(lin["psi"]) * 180.0 / np.pi, rtol=1e-6)
    # a point of the rod, reached from the frame through O and L: |dP| <= c_O + c_L +
    # (sum c) |P - L| |dtheta/dR|
    bound = RADII["O"] + RADII["L"] + total_c * abs(UV) * np.abs(lin["theta"])
    wc = K.worst_case(mech, None, "P_y_mm").total[0]
    assert np.all(wc <= bound * (1 + 1e-9))
    assert np.any(wc < 0.9 * bound)  # a bound, not the answer, for a point of a turning link
    # a single link (the crank pin, no turn of its link): the bound is reached, c_O + c_L
    wc = K.worst_case(mech, None, "L_x_mm").total[0]
    np.testing.assert_allclose(wc, RADII["O"] + RADII["L"], rtol=1e-6)


def test_random_journals_lie_in_their_circles_and_repeat_with_the_seed():
    mech = four_bar()
    a = K.random_offsets(mech, 5000, np.random.default_rng(3))
    b = K.random_offsets(mech, 5000, np.random.default_rng(3))
    rim = K.random_offsets(mech, 5000, np.random.default_rng(3), rim=True)
    for j, c in RADII.items():
        r = np.hypot(a[f"{j}_dx_mm"], a[f"{j}_dy_mm"])
        np.testing.assert_array_equal(a[f"{j}_dx_mm"], b[f"{j}_dx_mm"])
        assert r.max() <= c and abs(np.median(r) - c / np.sqrt(2)) < 0.03 * c  # area-uniform
        np.testing.assert_allclose(np.hypot(rim[f"{j}_dx_mm"], rim[f"{j}_dy_mm"]), c)
    # the real model within the first-order worst case at every angle
    s0 = K.signal(mech, mech.state(), "P_y_mm")[0]
    s = K.signal(mech, mech.state(rim), "P_y_mm")
    assert np.all(np.abs(s - s0) <= K.worst_case(mech, None, "P_y_mm").total[0] * 1.001)


def test_bad_clearance_input_is_refused_in_one_line():
    with pytest.raises(ParameterError, match="declares no revolute"):
        K.worst_case(loads(FOUR_BAR, "f.toml"), None, "P_y_mm")
    with pytest.raises(ParameterError, match="must be an output of type"):
        K.jacobian(loads(FOUR_BAR.replace('type = "angle"', 'type = "transmission"\ngroup = "M"')
                         .replace('direction = ["D", "M"]\nmeasure = "max"', 'measure = "min"')
                         + CLEARANCES, "f.toml"), None, "psi_deg")
    clash = FOUR_BAR.replace("[parameters]", '[parameters]\nM_dx_mm = { nominal = 0, unit = "mm" }')
    with pytest.raises(ParameterError, match="M_dx_mm is a name of"):
        loads(clash + CLEARANCES, "f.toml")
    with pytest.raises(ParameterError, match="unknown parameter"):
        four_bar().evaluate({"Q_dx_mm": 0.0})
