"""Polukhin's spatial crank-rocker: the printed position function against the geometry, the
planar limit against engine.rrr, link lengths, finite differences, the extreme-position
condition against a dense sweep, the perpendicular-axes example and the batch module."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

import spatial_rocker_reference as scr
from sewtol import engine
from sewtol.errors import ParameterError

ROOT = Path(__file__).resolve().parents[1]
# illustrative perpendicular-axes machine (the example file's nominal)
PERP = dict(a=10.0, b=60.0, c=25.0, e=55.0, f=15.0, g=20.0, alpha_rad=np.pi / 2)
# a generic skew machine
SKEW = dict(a=8.0, b=47.0, c=21.0, e=40.0, f=-6.0, g=11.0, alpha_rad=np.radians(37.0))


def printed_F(phi, psi, a, b, c, e, f, g, alpha_rad):
    """The source's position function, typed as printed."""
    sa, ca = np.sin(alpha_rad), np.cos(alpha_rad)
    return (-2 * c * (f * sa + a * ca * np.sin(phi)) * np.sin(psi)
            + 2 * c * (e - a * np.cos(phi)) * np.cos(psi)
            + 2 * a * (g * sa * np.sin(phi) - e * np.cos(phi))
            + a**2 - b**2 + c**2 + e**2 + f**2 + g**2 - 2 * f * g * ca)


def joints_by_rotation(phi, psi, a, c, e, f, g, alpha_rad):
    """B and C built independently: rotate the arms about the axes (scipy Rotation)."""
    k = np.array([0.0, np.sin(alpha_rad), np.cos(alpha_rad)])
    rot_b = Rotation.from_rotvec(np.outer(np.atleast_1d(phi), k))
    b = f * k + rot_b.apply([a, 0.0, 0.0])
    rot_c = Rotation.from_rotvec(np.outer(np.atleast_1d(psi), [0.0, 0.0, 1.0]))
    c_pt = np.array([e, 0.0, g]) + rot_c.apply([c, 0.0, 0.0])
    return b, c_pt


def rocker(phi, params, branch):
    p = dict(params)
    return engine.spatial_rocker(engine.driving_angle(phi), p["a"], p["b"], p["c"], p["e"],
                                 p["f"], p["g"], p["alpha_rad"], branch)


def wrap(x):
    return np.angle(np.exp(1j * x))


def test_printed_position_function_is_the_coupler_length(rng):
    # the printed F equals |B - C|^2 - b^2 for the stated axes, at random angles and dimensions
    for _ in range(50):
        a, b, c, e = rng.uniform(1, 60, 4)
        f, g = rng.uniform(-40, 40, 2)
        alpha = rng.uniform(-np.pi, np.pi)
        phi, psi = rng.uniform(-np.pi, np.pi, 2)
        bp, cp = joints_by_rotation(phi, psi, a, c, e, f, g, alpha)
        truth = np.sum((bp - cp) ** 2) - b * b
        assert printed_F(phi, psi, a, b, c, e, f, g, alpha) == pytest.approx(truth, abs=1e-9)
        assert engine.position_function(phi, psi, a, b, c, e, f, g, alpha) == pytest.approx(
            truth, abs=1e-9)
        jb, jc = engine.spatial_joints(phi, psi, a, c, e, f, g, alpha)
        assert np.max(np.abs(jb - bp[0])) < 1e-12 and np.max(np.abs(jc - cp[0])) < 1e-12


@given(a=st.floats(1, 30), b=st.floats(5, 120), c=st.floats(1, 60), e=st.floats(0.5, 80),
       f=st.floats(-40, 40), g=st.floats(-40, 40), alpha=st.floats(-180, 180),
       branch=st.sampled_from([1.0, -1.0]))
@settings(max_examples=150, deadline=None)
def test_any_machine_closes_with_its_coupler_length_or_reports_the_miss(a, b, c, e, f, g, alpha,
                                                                       branch):
    q = np.linspace(0, 2 * np.pi, 64)
    psi, closure = engine.spatial_rocker(engine.driving_angle(q), a, b, c, e, f, g,
                                         np.radians(alpha), branch)
    closes = closure.miss_mm == 0
    assert np.array_equal(np.isnan(psi.a), ~closes)
    bp, cp = engine.spatial_joints(q, psi.a, a, c, e, f, g, np.radians(alpha))
    dist = np.linalg.norm(bp - cp, axis=-1)
    assert np.all(np.abs(dist[closes] - b) < 1e-9)
    # where it misses, b lies outside [nearest, farthest] distance of B to the rocker circle by
    # exactly the miss (the circle sampled finely; sampling can only shrink the interval)
    grid = np.linspace(-np.pi, np.pi, 4001)
    for i in np.flatnonzero(~closes)[:4]:
        bi, ci = engine.spatial_joints(q[i], grid, a, c, e, f, g, np.radians(alpha))
        if np.isinf(closure.miss_mm[i]):
            # B on the rocker's axis: no psi is defined (as for the dyad's coincident centres)
            assert np.max(np.hypot(bi[..., 0] - e, bi[..., 1])) < 1e-9
            continue
        d = np.linalg.norm(bi - ci, axis=-1)
        gap = max(d.min() - b, b - d.max())
        assert 0 < closure.miss_mm[i] <= gap + 1e-9
        assert gap - closure.miss_mm[i] < 1e-5 * (a + c + e + abs(f) + abs(g))


@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_planar_limit_is_the_rrr_dyad(branch):
    a, b, c, e = 12.0, 50.0, 30.0, 45.0
    q = np.linspace(0, 2 * np.pi, 721)
    psi, closure = engine.spatial_rocker(engine.driving_angle(q), a, b, c, e, 0.0, 0.0, 0.0,
                                         branch)
    pin = engine.crank(0.0, 0.0, a, q)
    frame = engine.fixed(e, 0.0)
    joint, dyad = engine.rrr(pin, b, frame, c, branch)
    ref = engine.direction(frame, joint)
    assert np.all(closure.ok) and np.all(dyad.ok)
    assert np.max(np.abs(wrap(psi.a - ref.a))) < 1e-9
    assert np.max(np.abs(psi.da - ref.da)) < 1e-9
    assert np.max(np.abs(psi.dda - ref.dda)) < 1e-9
    assert np.max(np.abs(closure.transmission_deg - dyad.transmission_deg)) < 1e-7


def test_planar_limit_misses_like_the_rrr_dyad():
    q = np.linspace(0, 2 * np.pi, 361)
    pin = engine.crank(0.0, 0.0, 12.0, q)
    # too short, b too long, c too long (never closes); c long enough on part of the turn
    for b, c, never in ((20.0, 10.0, True), (80.0, 10.0, True), (30.0, 100.0, True),
                        (30.0, 70.0, False)):
        psi, closure = engine.spatial_rocker(engine.driving_angle(q), 12.0, b, c, 45.0, 0.0, 0.0,
                                             0.0, 1.0)
        _, dyad = engine.rrr(pin, b, engine.fixed(45.0, 0.0), c, 1.0)
        assert np.all(dyad.miss_mm > 0) == never and np.any(dyad.miss_mm > 0)
        assert np.max(np.abs(closure.miss_mm - dyad.miss_mm)) < 1e-9
        assert np.array_equal(np.isnan(psi.a), dyad.miss_mm > 0)


@pytest.mark.parametrize("params", [PERP, SKEW], ids=["alpha90", "alpha37"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_coupler_keeps_its_length_and_transmission_is_the_pressure_angle(params, branch):
    q = np.linspace(0, 2 * np.pi, 1441)
    psi, closure = rocker(q, params, branch)
    assert np.all(closure.ok)
    p = params
    bp, cp = joints_by_rotation(q, psi.a, p["a"], p["c"], p["e"], p["f"], p["g"], p["alpha_rad"])
    assert np.max(np.abs(np.linalg.norm(cp - bp, axis=1) - p["b"])) < 1e-9
    # C's velocity direction t = Z x (C - D) / c; transmission = 90 - angle(BC, t) folded
    t = np.stack([-np.sin(psi.a), np.cos(psi.a), 0 * q], -1)
    cos_pressure = np.abs(np.sum((cp - bp) * t, axis=1)) / p["b"]
    pressure = np.degrees(np.arccos(np.minimum(cos_pressure, 1.0)))
    assert np.max(np.abs(closure.transmission_deg - (90.0 - pressure))) < 1e-7
    # branch +1 is sin(psi - delta) > 0 all round the turn (no flip)
    side = np.sign(engine.position_function(q, psi.a + 1e-6, p["a"], p["b"], p["c"], p["e"],
                                            p["f"], p["g"], p["alpha_rad"]))
    assert np.all(side == -branch)


@pytest.mark.parametrize("params", [PERP, SKEW], ids=["alpha90", "alpha37"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_transfer_functions_match_central_differences(params, branch):
    q = np.linspace(0, 2 * np.pi, 73)
    h = 1e-4
    p = params
    args = (p["a"], p["b"], p["c"], p["e"], p["f"], p["g"], p["alpha_rad"], branch)
    psi, _ = rocker(q, p, branch)
    lo, _ = rocker(q - h, p, branch)
    hi, _ = rocker(q + h, p, branch)
    d1 = wrap(hi.a - lo.a) / (2 * h)
    d2 = (wrap(hi.a - psi.a) - wrap(psi.a - lo.a)) / h**2
    assert np.max(np.abs(psi.da - d1)) < 1e-8
    assert np.max(np.abs(psi.dda - d2)) < 1e-5
    third = engine.spatial_rocker_third(q, *args)
    assert np.max(np.abs(third - (hi.dda - lo.dda) / (2 * h))) < 1e-7
    # psi'' from psi' as well, tighter
    assert np.max(np.abs(psi.dda - (hi.da - lo.da) / (2 * h))) < 1e-7


def test_transfer_functions_chain_through_a_driven_crank():
    # phi(q) = 0.3 + 1.2 q + 0.1 sin q: psi_q = psi_phi phi', psi_qq = psi_phiphi phi'^2 + psi_phi phi''
    q = np.linspace(0, 2 * np.pi, 61)
    phi = engine.Angle(0.3 + 1.2 * q + 0.1 * np.sin(q), 1.2 + 0.1 * np.cos(q), -0.1 * np.sin(q))
    p = SKEW
    args = (p["a"], p["b"], p["c"], p["e"], p["f"], p["g"], p["alpha_rad"], 1.0)
    psi, _ = engine.spatial_rocker(phi, *args)
    h = 1e-4

    def at(x):
        return engine.spatial_rocker(engine.driving_angle(0.3 + 1.2 * x + 0.1 * np.sin(x)),
                                     *args)[0].a

    assert np.max(np.abs(psi.da - wrap(at(q + h) - at(q - h)) / (2 * h))) < 1e-8
    d2 = (wrap(at(q + h) - at(q)) - wrap(at(q) - at(q - h))) / h**2
    assert np.max(np.abs(psi.dda - d2)) < 1e-5


@pytest.mark.parametrize("params", [PERP, SKEW], ids=["alpha90", "alpha37"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_extremes_satisfy_the_printed_condition_and_match_a_dense_sweep(params, branch):
    p = params
    args = (p["a"], p["b"], p["c"], p["e"], p["f"], p["g"], p["alpha_rad"])
    ext = engine.rocker_extremes(*args, branch)
    sa, ca = np.sin(p["alpha_rad"]), np.cos(p["alpha_rad"])
    for phi, psi in ((ext.phi_at_max, ext.psi_max), (ext.phi_at_min, ext.psi_min)):
        # tan(phi) = (c cos(alpha) sin(psi) - g sin(alpha)) / (c cos(psi) + e), cross-multiplied
        lhs = np.sin(phi) * (p["c"] * np.cos(psi) + p["e"])
        rhs = np.cos(phi) * (p["c"] * ca * np.sin(psi) - p["g"] * sa)
        assert abs(lhs - rhs) < 1e-9
        assert abs(engine.position_function(phi, psi, p["a"], p["b"], *args[2:])) < 1e-8
        on_branch, _ = rocker(phi, p, branch)
        assert abs(wrap(on_branch.a - psi)) < 1e-9 and abs(on_branch.da) < 1e-9
    q = np.linspace(0, 2 * np.pi, 1_000_000, endpoint=False)
    swept, _ = rocker(q, p, branch)
    turned = np.unwrap(swept.a)
    top, bottom = turned.max(), turned.min()
    assert abs(wrap(top - ext.psi_max)) < 1e-9
    assert abs(wrap(bottom - ext.psi_min)) < 1e-9
    assert abs(ext.swing - (top - bottom)) < 1e-9
    step = 2 * np.pi / q.size
    assert abs(wrap(q[np.argmax(turned)] - ext.phi_at_max)) <= step
    assert abs(wrap(q[np.argmin(turned)] - ext.phi_at_min)) <= step


@pytest.mark.parametrize("params", [PERP, SKEW], ids=["alpha90", "alpha37"])
def test_sensitivities_match_finite_differences_at_any_angle_and_at_the_extremes(params):
    q = np.linspace(0, 2 * np.pi, 37)
    ext = engine.rocker_extremes(**params, branch=1.0)
    at_q = engine.rocker_sensitivities(q, **params, branch=1.0)
    at_max = engine.rocker_sensitivities(ext.phi_at_max, **params, branch=1.0)
    at_min = engine.rocker_sensitivities(ext.phi_at_min, **params, branch=1.0)
    assert set(at_q) == set(engine.spatial.PARAMETERS)
    h = 1e-5
    for name in engine.spatial.PARAMETERS:
        up, lo = dict(params), dict(params)
        up[name] += h
        lo[name] -= h
        fd = wrap(rocker(q, up, 1.0)[0].a - rocker(q, lo, 1.0)[0].a) / (2 * h)
        assert np.max(np.abs(at_q[name] - fd)) < 1e-8, name
        # the envelope theorem: the extremes move as psi does at their own crank angle
        e_up = engine.rocker_extremes(**up, branch=1.0)
        e_lo = engine.rocker_extremes(**lo, branch=1.0)
        assert at_max[name] == pytest.approx((e_up.psi_max - e_lo.psi_max) / (2 * h), abs=1e-8)
        assert at_min[name] == pytest.approx((e_up.psi_min - e_lo.psi_min) / (2 * h), abs=1e-8)


def test_extremes_of_random_crank_rockers_match_their_sampled_turn(rng):
    # 1000 random spatial machines; those that close all round without a dead point and whose
    # rocker swings (does not turn fully) must have both extremes, within the sampling bound
    # (1/2) max|psi''| (pi/n)^2 of the sampled turn's max and min
    m, n = 1000, 2048
    a, c = rng.uniform(1, 30, m), rng.uniform(1, 60, m)
    b, e = rng.uniform(5, 120, m), rng.uniform(0.5, 80, m)
    f, g = rng.uniform(-40, 40, (2, m))
    alpha, branch = np.radians(rng.uniform(-180, 180, m)), rng.choice([1.0, -1.0], m)
    q = np.linspace(0, 2 * np.pi, n, endpoint=False)
    col = [v[:, None] for v in (a, b, c, e, f, g, alpha, branch)]
    psi, closure = engine.spatial_rocker(engine.driving_angle(q), *col)
    turned = np.unwrap(psi.a, axis=1)
    swings = (np.all(closure.ok, axis=1) & (np.min(closure.transmission_deg, axis=1) > 1.0)
              & (np.abs(turned[:, -1] - turned[:, 0]) < 1.0))
    assert swings.sum() > 150
    ext = engine.rocker_extremes(a, b, c, e, f, g, alpha, branch)
    assert not np.any(np.isnan(ext.swing[swings]))
    bound = 0.5 * np.max(np.abs(psi.dda), axis=1) * (np.pi / n) ** 2 * 1.01 + 1e-12
    top = np.abs(wrap(turned.max(axis=1) - ext.psi_max))
    bottom = np.abs(wrap(turned.min(axis=1) - ext.psi_min))
    assert np.all(top[swings] <= bound[swings]) and np.all(bottom[swings] <= bound[swings])


def test_perpendicular_axes_worked_example():
    # alpha = 90 deg (the source's case for the 51 and 208 rows): A = -2 c f is constant; the extreme
    # condition reads tan(phi) = -g / (c cos(psi) + e)
    p = PERP
    ext = engine.rocker_extremes(p["a"], p["b"], p["c"], p["e"], p["f"], p["g"], p["alpha_rad"],
                                 1.0)
    assert np.degrees(ext.psi_min) == pytest.approx(62.253939662, abs=1e-8)
    assert np.degrees(ext.psi_max) == pytest.approx(112.983483368, abs=1e-8)
    assert np.degrees(ext.swing) == pytest.approx(50.729543706, abs=1e-8)
    assert np.degrees(ext.phi_at_min) % 360 == pytest.approx(343.294171462, abs=1e-8)
    assert np.degrees(ext.phi_at_max) == pytest.approx(156.149648246, abs=1e-8)
    for phi, psi in ((ext.phi_at_min, ext.psi_min), (ext.phi_at_max, ext.psi_max)):
        assert np.tan(phi) == pytest.approx(-p["g"] / (p["c"] * np.cos(psi) + p["e"]), abs=1e-12)

    # an independent bounded optimiser on psi(phi) finds the same extremes
    def psi_of(x):
        return float(rocker(np.array([x]), p, 1.0)[0].a[0])

    top = minimize_scalar(lambda x: -psi_of(x), bounds=(ext.phi_at_max - 0.3,
                          ext.phi_at_max + 0.3), method="bounded", options={"xatol": 1e-10})
    bottom = minimize_scalar(psi_of, bounds=(ext.phi_at_min - 0.3, ext.phi_at_min + 0.3),
                             method="bounded", options={"xatol": 1e-10})
    assert -top.fun == pytest.approx(ext.psi_max, abs=1e-12)
    assert bottom.fun == pytest.approx(ext.psi_min, abs=1e-12)
    # the swing's sensitivities (deg per mm, deg per deg) quoted in the docs
    grow = {k: np.degrees(engine.rocker_sensitivities(ext.phi_at_max, **p, branch=1.0)[k]
                          - engine.rocker_sensitivities(ext.phi_at_min, **p, branch=1.0)[k])
            for k in ("a", "b", "c", "e", "g")}
    assert grow == pytest.approx({"a": 5.4555, "b": 0.3295, "c": -2.1936, "e": -0.4287,
                                  "g": 0.2040}, abs=1e-4)
    # the other assembly of the same links swings less (40.66 deg)
    other = engine.rocker_extremes(p["a"], p["b"], p["c"], p["e"], p["f"], p["g"],
                                   p["alpha_rad"], -1.0)
    assert np.degrees(other.swing) == pytest.approx(40.662422517, abs=1e-8)
    # |F_psi| = R |sin(psi - delta)| is the same on both roots: so is the transmission angle
    q = np.linspace(0, 2 * np.pi, 361)
    plus, minus = rocker(q, p, 1.0)[1], rocker(q, p, -1.0)[1]
    assert np.max(np.abs(plus.transmission_deg - minus.transmission_deg)) < 1e-9


def test_non_assembling_machine_gives_nan_and_the_miss():
    q = np.linspace(0, 2 * np.pi, 181)
    p = dict(PERP, b=20.0)  # the coupler is too short on every crank angle
    psi, closure = rocker(q, p, 1.0)
    assert np.all(np.isnan(psi.a)) and np.all(np.isnan(psi.da))
    assert np.all(closure.miss_mm > 0)
    # the miss is the gap to the nearest point of the rocker circle: min over psi of |BC| - b
    grid = np.linspace(-np.pi, np.pi, 100_001)
    for i in range(0, q.size, 15):
        bp, cp = engine.spatial_joints(q[i], grid, p["a"], p["c"], p["e"], p["f"], p["g"],
                                       p["alpha_rad"])
        nearest = np.linalg.norm(bp - cp, axis=-1).min()
        assert closure.miss_mm[i] == pytest.approx(nearest - p["b"], abs=1e-6)
    # and a machine that closes on part of the turn only: counted per angle, never raised
    psi, closure = rocker(q, dict(PERP, b=45.0), 1.0)
    assert 0 < np.sum(closure.miss_mm > 0) < q.size
    assert np.array_equal(np.isnan(psi.a), closure.miss_mm > 0)
    # no extremes where it never closes
    assert np.isnan(engine.rocker_extremes(10.0, 20.0, 25.0, 55.0, 15.0, 20.0, np.pi / 2,
                                           1.0).swing)


def test_extremes_broadcast_over_a_batch():
    b = np.array([58.0, 60.0, 62.0])
    ext = engine.rocker_extremes(10.0, b, 25.0, 55.0, 15.0, 20.0, np.pi / 2, 1.0)
    for i, bi in enumerate(b):
        one = engine.rocker_extremes(10.0, bi, 25.0, 55.0, 15.0, 20.0, np.pi / 2, 1.0)
        assert ext.psi_max[i] == one.psi_max and ext.psi_min[i] == one.psi_min


def test_batch_module_matches_the_engine_and_the_file():
    ev = scr.evaluate({"b": np.array([60.0, 20.0, 60.0]), "alpha": [90.0, 90.0, 90.0],
                       "branch_psi": [1.0, 1.0, -1.0]})
    assert list(ev.status) == ["ok", "cannot_close", "ok"]
    assert list(ev.failed_group) == ["", "psi", ""]
    assert np.all(np.isnan([v[1] for v in ev.outputs.values()]))
    for i, branch in ((0, 1.0), (2, -1.0)):
        ext = engine.rocker_extremes(10.0, 60.0, 25.0, 55.0, 15.0, 20.0, np.pi / 2, branch)
        # 720 samples: the sampled extremes lie within (1/2) max|psi''| (pi/720)^2 of the exact
        assert ev.outputs["rocker_swing_deg"][i] == pytest.approx(np.degrees(ext.swing), abs=2e-3)
        assert ev.outputs["rocker_max_deg"][i] == pytest.approx(
            np.degrees(ext.psi_max), abs=1e-3)
        step = 0.5
        assert abs((ev.outputs["crank_at_rocker_max_deg"][i] - np.degrees(ext.phi_at_max)
                    + 180) % 360 - 180) <= step
        assert abs((ev.outputs["crank_at_rocker_min_deg"][i] - np.degrees(ext.phi_at_min)
                    + 180) % 360 - 180) <= step
    omega = 4000 * 2 * np.pi / 60
    assert ev.outputs["rocker_tip_speed_max_m_s"][0] == pytest.approx(
        25e-3 * omega * ev.outputs["rocker_rate_max"][0], rel=1e-15)
    # planar, b + c = e + a + 1e-4: closes all round but coupler and rocker nearly stretch out
    # at phi = 180 deg (transmission about 0.2 deg): a dead point, counted and named
    dead = scr.evaluate({"b": [40.0001, 40.5], "alpha": 0.0, "f": 0.0, "g": 0.0})
    assert list(dead.status) == ["dead_point", "ok"]
    assert list(dead.failed_group) == ["psi", ""]
    assert np.isnan(dead.outputs["transmission_min_deg"][0])
    # planar crank-rocker: the smallest transmission is at phi = 180 deg (a sample), where
    # |BQ| = e + a and the folded law-of-cosines angle between coupler and rocker is 14.58 deg
    stretched = np.degrees(np.arccos((40.5**2 + 25.0**2 - 65.0**2) / (2 * 40.5 * 25.0)))
    assert dead.outputs["transmission_min_deg"][1] == pytest.approx(180.0 - stretched, abs=1e-9)
    # the file declares the same parameters, nominals, tolerances and outputs as the module
    with open(ROOT / "examples" / "spatial_crank_rocker.toml", "rb") as fh:
        doc = tomllib.load(fh)
    assert doc["format"] == "sewtol-mechanism/1"
    assert list(doc["parameters"]) == list(scr.PARAMETERS)
    for name, spec in doc["parameters"].items():
        assert (spec["unit"], spec["nominal"], spec["rule"], spec["doc"]) == scr.PARAMETERS[name]
    assert [o["name"] for o in doc["outputs"]] == list(scr.OUTPUTS)
    assert doc["tolerances"] == scr.TOLERANCES
    assert doc["mechanism"]["samples"] == scr.SAMPLES and doc["mechanism"]["rpm"] == scr.RPM
    rocker_group = next(grp for grp in doc["groups"] if grp["type"] == "spatial_rocker")
    assert rocker_group["name"] == scr.GROUP


def test_batch_module_refuses_bad_input_by_name():
    with pytest.raises(ParameterError, match="^beta: is not a parameter.*valid: a, b"):
        scr.evaluate({"beta": 1.0})
    with pytest.raises(ParameterError, match="^c: must be a positive length"):
        scr.evaluate({"c": -1.0})
    with pytest.raises(ParameterError, match="^branch_psi: must be"):
        scr.evaluate({"branch_psi": 0.0})
    with pytest.raises(ParameterError,
                       match=r"^e: must have as many values as a \(2\) \(got '3 values'\)"):
        scr.evaluate({"a": [10.0, 11.0], "e": [55.0, 55.0, 55.0]})


def test_monte_carlo_of_the_swing_quoted_in_the_docs():
    # 20000 machines uniform within the file's illustrative tolerances, default_rng(2026):
    # the exact extremes give the docs' figures; the sampled batch path stays within the
    # sampling bound of them machine by machine (720 samples: swing short by < 2e-3 deg)
    nom, tol = scr.nominal(), scr.TOLERANCES["illustrative"]

    def draw(n):
        rng = np.random.default_rng(2026)
        return {k: nom[k] + rng.uniform(-t, t, n) for k, t in tol.items()}

    vals = draw(20000)
    ext = engine.rocker_extremes(vals["a"], vals["b"], vals["c"], vals["e"], vals["f"],
                                 vals["g"], np.radians(vals["alpha"]), 1.0)
    swing = np.degrees(ext.swing)
    assert not np.any(np.isnan(swing))
    assert swing.mean() == pytest.approx(50.72993, abs=1e-5)
    assert swing.std() == pytest.approx(0.07526, abs=1e-5)
    assert (swing.min(), swing.max()) == pytest.approx((50.52197, 50.94165), abs=1e-5)
    few = {k: v[:500] for k, v in draw(20000).items()}
    ev = scr.evaluate(few)
    assert np.all(ev.status == "ok")
    short = swing[:500] - ev.outputs["rocker_swing_deg"]
    assert np.all((short >= 0.0) & (short < 2e-3))
