"""Polukhin's spatial crank-slider (engine.spatial_slider) and the pressure angle of the spatial
groups: the position function against the geometry, the planar limit against engine.rrp,
finite differences and an independent vector-loop route for s', s'', s''', the exact stroke
extremes against a dense sweep, the transmission angle against the 3-D pressure angle and the
planar crank-slider's, dead points and misses counted by the file evaluation, and the example
file through `sewtol run ... nominal` and `scan`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar
from scipy.spatial.transform import Rotation

from cli_helpers import run
from sewtol import engine
from sewtol.mechanism import load

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "spatial_crank_slider.toml"
# generic skew machines (illustrative): guide inclined 35 deg and -60 deg to the crank's plane
SKEW = dict(a=10.0, b=60.0, e=15.0, f=12.0, alpha_rad=np.radians(35.0))
STEEP = dict(a=7.0, b=33.0, e=-9.0, f=-5.0, alpha_rad=np.radians(-60.0))
PLANAR = dict(a=12.0, b=50.0, e=8.0, f=0.0, alpha_rad=0.0)


def crank_axis(alpha_rad):
    return np.array([0.0, np.sin(alpha_rad), np.cos(alpha_rad)])


def crank_pin(phi, a, f, alpha_rad):
    """B by rotating the arm a X about the crank axis k through A = f k (scipy Rotation)."""
    k = crank_axis(alpha_rad)
    rot = Rotation.from_rotvec(np.outer(np.atleast_1d(phi), k))
    return f * k + rot.apply([a, 0.0, 0.0])


def slider_by_bracketing(phi, a, b, e, f, alpha_rad, branch):
    """s from |B - (e, s, 0)| = b by brentq on the guide, either side of the foot of B."""
    bp = crank_pin(phi, a, f, alpha_rad)[0]
    foot = bp[1]

    def g(s):
        return np.sum((bp - np.array([e, s, 0.0])) ** 2) - b * b

    return brentq(g, foot, foot + branch * 2.0 * b, xtol=1e-14, rtol=1e-15)


def vector_loop_derivatives(phi, s, a, b, e, f, alpha_rad):
    """s', s'', s''' from differentiating (C - B).(C - B) = b^2 along the motion: with C' = s' Y
    and B^(n) = k x B^(n-1) (B turns about k),
    (C - B).(C' - B') = 0, |C' - B'|^2 + (C - B).(C'' - B'') = 0,
    3 (C' - B').(C'' - B'') + (C - B).(C''' - B''') = 0."""
    k = crank_axis(alpha_rad)
    bp = crank_pin(phi, a, f, alpha_rad)
    r = bp - f * k
    b1 = np.cross(k, r)
    b2 = np.cross(k, b1)
    b3 = np.cross(k, b2)
    y = np.array([0.0, 1.0, 0.0])
    d = np.stack([np.full_like(s, e), s, np.zeros_like(s)], -1) - bp
    dy = d[:, 1]
    s1 = np.sum(d * b1, -1) / dy
    v1 = s1[:, None] * y - b1
    s2 = (np.sum(d * b2, -1) - np.sum(v1 * v1, -1)) / dy
    v2 = s2[:, None] * y - b2
    s3 = (np.sum(d * b3, -1) - 3.0 * np.sum(v1 * v2, -1)) / dy
    return s1, s2, s3


def test_position_function_is_the_coupler_length(rng):
    for _ in range(50):
        a, b = rng.uniform(1, 60, 2)
        e, f, s = rng.uniform(-50, 50, 3)
        alpha, phi = rng.uniform(-np.pi, np.pi, 2)
        bp = crank_pin(phi, a, f, alpha)[0]
        truth = np.sum((bp - np.array([e, s, 0.0])) ** 2) - b * b
        assert engine.slider_position_function(phi, s, a, b, e, f, alpha) == pytest.approx(
            truth, abs=1e-9)
        jb, jc = engine.slider_joints(phi, s, a, e, f, alpha)
        assert np.max(np.abs(jb - bp)) < 1e-12 and np.max(np.abs(jc - [e, s, 0.0])) < 1e-12


@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_planar_limit_is_the_rrp_crank_slider(branch):
    q = np.linspace(0.0, 2.0 * np.pi, 721)
    drive = engine.driving_angle(q)
    c, closure = engine.spatial_slider(drive, branch=branch, **PLANAR)
    crank = engine.polar(engine.fixed(0.0, 0.0), PLANAR["a"], drive)
    # the planar crank-slider: the slider on the line x = e along +y
    j, jc = engine.rrp(crank, PLANAR["b"], PLANAR["e"], 0.0, np.pi / 2, branch)
    assert np.max(np.abs(c.p - j.p)) < 1e-9
    assert np.max(np.abs(c.dp - j.dp)) < 1e-9 and np.max(np.abs(c.ddp - j.ddp)) < 1e-9
    assert np.all(closure.miss_mm == 0.0) and np.all(jc.miss_mm == 0.0)
    # planar transmission angle: between the coupler and the guide's normal (x), i.e. 90 deg
    # minus the angle between the coupler and the guide
    u = j.p - crank.p
    planar = np.degrees(np.arcsin(np.abs(u.imag) / np.abs(u)))
    assert np.max(np.abs(closure.transmission_deg - planar)) < 1e-7
    # the closed-form planar extremes of an offset crank-slider
    x = engine.slider_extremes(branch=branch, **PLANAR)
    a, b, e = PLANAR["a"], PLANAR["b"], PLANAR["e"]
    far, near = np.sqrt((a + b) ** 2 - e**2), np.sqrt((b - a) ** 2 - e**2)
    if branch > 0:
        assert (x.s_max, x.s_min) == pytest.approx((far, near), abs=1e-10)
    else:
        assert (x.s_max, x.s_min) == pytest.approx((-near, -far), abs=1e-10)
    inline = engine.slider_extremes(a, b, 0.0, 0.0, 0.0, branch)
    assert float(inline.stroke) == pytest.approx(2.0 * a, abs=1e-10)


def test_planar_limit_misses_like_the_rrp_group():
    q = np.linspace(0.0, 2.0 * np.pi, 361)
    drive = engine.driving_angle(q)
    for b, e in ((10.0, 30.0), (6.0, 8.0), (3.0, 8.0)):  # never, part of the turn, never
        c, closure = engine.spatial_slider(drive, 12.0, b, e, 0.0, 0.0, 1.0)
        crank = engine.polar(engine.fixed(0.0, 0.0), 12.0, drive)
        j, jc = engine.rrp(crank, b, e, 0.0, np.pi / 2, 1.0)
        assert np.array_equal(np.isnan(c.p), np.isnan(j.p))
        assert np.max(np.abs(closure.miss_mm - jc.miss_mm)) < 1e-9
        assert np.any(closure.miss_mm > 0.0)
    _, partial = engine.spatial_slider(drive, 12.0, 6.0, 8.0, 0.0, 0.0, 1.0)
    assert np.any(partial.miss_mm == 0.0)


@pytest.mark.parametrize("params", [SKEW, STEEP], ids=["skew", "steep"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_slider_closes_with_its_coupler_length_on_both_branches(params, branch):
    phi = np.linspace(0.0, 2.0 * np.pi, 1441)
    s = engine.spatial_slider_displacement(phi, branch=branch, **params)[0]
    bp, cp = engine.slider_joints(phi, s, params["a"], params["e"], params["f"],
                                  params["alpha_rad"])
    assert np.max(np.abs(np.linalg.norm(cp - bp, axis=-1) - params["b"])) < 1e-9
    # the branch is the side of the foot of B on the guide: never left
    assert np.all(np.sign(s - bp[:, 1]) == branch)
    # an independent solver (brentq on the guide, B from scipy's Rotation)
    for p in phi[::120]:
        assert engine.spatial_slider_displacement(p, branch=branch, **params)[0] == pytest.approx(
            slider_by_bracketing(p, branch=branch, **params), abs=1e-9)


@pytest.mark.parametrize("params", [SKEW, STEEP], ids=["skew", "steep"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_transfer_functions_match_differences_and_the_vector_loop(params, branch):
    phi = np.linspace(0.0, 2.0 * np.pi, 73)
    s, d1, d2, d3, miss, _ = engine.spatial_slider_displacement(phi, branch=branch, **params)
    assert np.all(miss == 0.0)
    h = 1e-4

    def at(p, i):
        return engine.spatial_slider_displacement(p, branch=branch, **params)[i]

    # central differences of s, s', s'' (errors O(h^2) times the next derivatives)
    fd1 = (at(phi + h, 0) - at(phi - h, 0)) / (2 * h)
    fd2 = (at(phi + h, 1) - at(phi - h, 1)) / (2 * h)
    fd3 = (at(phi + h, 2) - at(phi - h, 2)) / (2 * h)
    assert np.max(np.abs(fd1 - d1)) < 2e-7
    assert np.max(np.abs(fd2 - d2)) < 2e-7
    assert np.max(np.abs(fd3 - d3)) < 5e-7
    # and the second difference of s itself
    dd = (at(phi + h, 0) - 2 * s + at(phi - h, 0)) / h**2
    assert np.max(np.abs(dd - d2)) < 1e-4
    # the vector-loop route (no partial derivative of F)
    v1, v2, v3 = vector_loop_derivatives(phi, s, params["a"], params["b"], params["e"],
                                         params["f"], params["alpha_rad"])
    scale = 1.0 + np.max(np.abs(d3))
    assert np.max(np.abs(v1 - d1)) < 1e-10 * scale
    assert np.max(np.abs(v2 - d2)) < 1e-10 * scale
    assert np.max(np.abs(v3 - d3)) < 1e-10 * scale


def test_transfer_functions_chain_through_a_driven_crank():
    # the crank angle as a function of the driving angle q: phi = 0.3 + q + 0.2 sin q
    q = np.linspace(0.0, 2.0 * np.pi, 97)

    def drive(qq):
        return engine.Angle(0.3 + qq + 0.2 * np.sin(qq), 1.0 + 0.2 * np.cos(qq),
                            -0.2 * np.sin(qq))

    c, _ = engine.spatial_slider(drive(q), branch=1.0, **SKEW)
    h = 1e-4
    up, _ = engine.spatial_slider(drive(q + h), branch=1.0, **SKEW)
    down, _ = engine.spatial_slider(drive(q - h), branch=1.0, **SKEW)
    assert np.max(np.abs((up.p - down.p) / (2 * h) - c.dp)) < 1e-6
    assert np.max(np.abs((up.dp - down.dp) / (2 * h) - c.ddp)) < 1e-6
    assert np.all(c.p.real == SKEW["e"]) and np.all(c.dp.real == 0.0)


@pytest.mark.parametrize("params", [SKEW, STEEP], ids=["skew", "steep"])
@pytest.mark.parametrize("branch", [1.0, -1.0])
def test_stroke_extremes_are_where_s_prime_vanishes_and_match_a_dense_sweep(params, branch):
    x = engine.slider_extremes(branch=branch, **params)
    phi = np.linspace(0.0, 2.0 * np.pi, 1_000_001)
    s = engine.spatial_slider_displacement(phi, branch=branch, **params)[0]
    # the sweep's step is 6.3e-6 rad: its extremes are short by (1/2) |s''| step^2 < 1e-9 mm
    assert float(x.s_max) == pytest.approx(np.max(s), abs=1e-9)
    assert float(x.s_min) == pytest.approx(np.min(s), abs=1e-9)
    assert float(x.s_max) >= np.max(s) - 1e-12 and float(x.s_min) <= np.min(s) + 1e-12
    for s_ext, phi_ext, sign in ((x.s_max, x.phi_at_max, -1.0), (x.s_min, x.phi_at_min, 1.0)):
        got = engine.spatial_slider_displacement(phi_ext, branch=branch, **params)
        assert float(got[0]) == pytest.approx(float(s_ext), abs=1e-9)
        assert abs(float(got[1])) < 1e-9 and sign * float(got[2]) > 0.0
        # s' = 0 is s cos(alpha) cos(phi) = e sin(phi): the crank pin's velocity normal to BC
        ca = np.cos(params["alpha_rad"])
        assert float(s_ext) * ca * np.cos(phi_ext) == pytest.approx(
            params["e"] * np.sin(phi_ext), abs=1e-9)
        # a bounded optimiser on s(phi) near the extreme finds the same value
        res = minimize_scalar(
            lambda p, sg=sign: sg * float(engine.spatial_slider_displacement(
                p, branch=branch, **params)[0]),
            bounds=(float(phi_ext) - 0.3, float(phi_ext) + 0.3), method="bounded",
            options={"xatol": 1e-10})
        assert sign * res.fun == pytest.approx(float(s_ext), abs=1e-9)


def test_extremes_are_nan_where_the_coupler_does_not_reach_the_guide_all_round():
    # a machine reaching the guide on part of the turn only, and one that never does
    for b in (20.0, 2.0):
        x = engine.slider_extremes(10.0, b, 15.0, 12.0, np.radians(35.0), 1.0)
        assert np.isnan(x.s_max) and np.isnan(x.stroke)
    # the largest distance of B from the guide decides, exactly: a coupler a hair longer closes
    phi = np.linspace(0.0, 2.0 * np.pi, 2_000_001)
    bp, _ = engine.slider_joints(phi, 0.0, 10.0, 15.0, 12.0, np.radians(35.0))
    rho_max = np.max(np.hypot(bp[:, 0] - 15.0, bp[:, 2]))
    assert np.isnan(engine.slider_extremes(10.0, rho_max - 1e-6, 15.0, 12.0,
                                           np.radians(35.0), 1.0).s_max)
    assert np.isfinite(engine.slider_extremes(10.0, rho_max + 1e-6, 15.0, 12.0,
                                              np.radians(35.0), 1.0).s_max)
    # broadcast over a batch
    bs = np.array([60.0, 20.0, 45.0])
    xs = engine.slider_extremes(10.0, bs, 15.0, 12.0, np.radians(35.0), 1.0)
    for i, b in enumerate(bs):
        one = engine.slider_extremes(10.0, b, 15.0, 12.0, np.radians(35.0), 1.0)
        np.testing.assert_array_equal(xs.stroke[i], one.stroke)


@pytest.mark.parametrize("params", [SKEW, STEEP], ids=["skew", "steep"])
def test_transmission_is_90_deg_minus_the_pressure_angle_in_3d(params):
    # pressure angle: between the coupler force (along B -> C) and C's velocity, from the 3-D
    # positions by a central difference, folded into [0, 90]
    phi = np.linspace(0.0, 2.0 * np.pi, 181)
    h = 1e-6
    for branch in (1.0, -1.0):
        c, closure = engine.spatial_slider(engine.driving_angle(phi), branch=branch, **params)
        s = c.p.imag
        bp, cp = engine.slider_joints(phi, s, params["a"], params["e"], params["f"],
                                      params["alpha_rad"])
        s_up = engine.spatial_slider_displacement(phi + h, branch=branch, **params)[0]
        s_dn = engine.spatial_slider_displacement(phi - h, branch=branch, **params)[0]
        _, c_up = engine.slider_joints(phi, s_up, params["a"], params["e"], params["f"],
                                       params["alpha_rad"])
        _, c_dn = engine.slider_joints(phi, s_dn, params["a"], params["e"], params["f"],
                                       params["alpha_rad"])
        vel = (c_up - c_dn) / (2 * h)
        force = cp - bp
        cos_theta = np.abs(np.sum(force * vel, -1)) / (
            np.linalg.norm(force, axis=-1) * np.linalg.norm(vel, axis=-1))
        pressure = np.degrees(np.arccos(np.minimum(cos_theta, 1.0)))
        moving = np.abs(c.dp) > 1e-3  # at s' = 0 the direction of C's velocity is undefined
        assert np.max(np.abs(closure.transmission_deg - (90.0 - pressure))[moving]) < 1e-6
        if branch == 1.0:
            t_plus = closure.transmission_deg
    # both assemblies have the same transmission angle at every crank angle (|s - m| = sqrt D)
    assert np.max(np.abs(closure.transmission_deg - t_plus)) < 1e-9


def test_rocker_transmission_output_equals_its_3d_pressure_angle():
    """The transmission output on a spatial_rocker group: the smallest over the turn of
    90 deg minus the angle between the coupler and C's velocity (C turning about the rocker
    axis Z: velocity Z x (C - D))."""
    mech = load(ROOT / "examples" / "spatial_crank_rocker.toml")
    v = mech.nominal_values()
    ev = mech.evaluate()
    phi = mech.angles_rad()
    psi, _ = engine.spatial_rocker(engine.driving_angle(phi), v["a"], v["b"], v["c"], v["e"],
                                   v["f"], v["g"], np.radians(v["alpha"]), v["branch_psi"])
    bp, cp = engine.spatial_joints(phi, psi.a, v["a"], v["c"], v["e"], v["f"], v["g"],
                                   np.radians(v["alpha"]))
    vel = np.cross([0.0, 0.0, 1.0], cp - np.array([v["e"], 0.0, v["g"]]))
    force = cp - bp
    cos_theta = np.abs(np.sum(force * vel, -1)) / (np.linalg.norm(force, axis=-1)
                                                   * np.linalg.norm(vel, axis=-1))
    transmission = 90.0 - np.degrees(np.arccos(cos_theta))
    assert ev.outputs["transmission_min_deg"][0] == pytest.approx(np.min(transmission), abs=1e-9)


def test_file_counts_dead_points_and_misses_of_the_slider_group():
    mech = load(EXAMPLE)
    v = mech.nominal_values()
    phi = np.linspace(0.0, 2.0 * np.pi, 2_000_001)
    bp, _ = engine.slider_joints(phi, 0.0, v["a"], v["e"], v["f"], np.radians(v["alpha"]))
    rho_max = float(np.max(np.hypot(bp[:, 0] - v["e"], bp[:, 2])))
    # a coupler barely longer than the largest distance of B from the guide passes within
    # 1 deg of a dead point (the coupler normal to the guide); a shorter one cannot close
    ev = mech.evaluate({"b": [v["b"], rho_max + 1e-4, rho_max - 0.5]})
    assert list(ev.status) == ["ok", "dead_point", "cannot_close"]
    assert list(ev.failed_group) == ["", "C", "C"]
    assert np.isfinite(ev.outputs["stroke_mm"][0]) and np.all(np.isnan(ev.outputs["stroke_mm"][1:]))
    state = mech.state({"b": [rho_max + 1e-4]})
    assert np.min(state.closures["C"].transmission_deg) < 1.0


def test_example_file_nominal_and_scan_against_the_closed_form():
    mech = load(EXAMPLE)
    v = mech.nominal_values()
    ev = mech.evaluate()
    assert list(ev.status) == ["ok"]
    x = engine.slider_extremes(v["a"], v["b"], v["e"], v["f"], np.radians(v["alpha"]),
                               v["branch_s"])
    # the file samples the turn every 0.5 deg: its stroke is short of the exact one by at most
    # (1/2) max|s''| (pi/720)^2 at each end
    phi = mech.angles_rad()
    _, d1, d2, _, _, t = engine.spatial_slider_displacement(
        phi, v["a"], v["b"], v["e"], v["f"], np.radians(v["alpha"]), v["branch_s"])
    bound = np.max(np.abs(d2)) * (np.pi / 720) ** 2
    gap = float(x.stroke) - ev.outputs["stroke_mm"][0]
    assert 0.0 <= gap < bound
    assert float(x.stroke) == pytest.approx(20.876514, abs=1e-6)  # the docs' figure
    omega = 4000 * 2 * np.pi / 60
    assert ev.outputs["slider_speed_max_m_s"][0] == pytest.approx(
        np.max(np.abs(d1)) * omega * 1e-3, rel=1e-12)
    assert ev.outputs["transmission_min_deg"][0] == pytest.approx(np.min(t), abs=1e-12)
    code, out, err = run("run", str(EXAMPLE), "nominal", "--format", "csv")
    assert code == 0, err
    row = next(r for r in out.splitlines() if r.startswith("stroke_mm,"))
    assert float(row.split(",")[2]) == pytest.approx(ev.outputs["stroke_mm"][0], abs=1e-4)
    code, out, err = run("run", str(EXAMPLE), "scan", "--output", "stroke_mm", "--format", "csv")
    assert code == 0, err
    lines = [r.split(",") for r in out.splitlines()[1:]]
    assert len(lines) == 10 and all("ok" in r for r in lines)
    # the crank's upper limit lengthens the stroke by about twice the tolerance (0.02 mm)
    a_up = next(r for r in lines if r[0] == "a" and r[1] == "upper")
    x_up = engine.slider_extremes(v["a"] + 0.02, v["b"], v["e"], v["f"],
                                  np.radians(v["alpha"]), v["branch_s"])
    assert float(a_up[5]) == pytest.approx(float(x_up.stroke), abs=bound + 1e-4)


def test_random_machines_close_with_their_coupler_length_or_report_the_miss(rng):
    phi = np.linspace(0.0, 2.0 * np.pi, 64)
    fine = np.linspace(0.0, 2.0 * np.pi, 4001)
    closed = missed = 0
    for _ in range(200):
        a, b = rng.uniform(1, 40, 2)
        e, f = rng.uniform(-40, 40, 2)
        alpha = rng.uniform(-np.pi, np.pi)
        branch = rng.choice([1.0, -1.0])
        s, _, _, _, miss, t = engine.spatial_slider_displacement(phi, a, b, e, f, alpha, branch)
        bp, cp = engine.slider_joints(phi, s, a, e, f, alpha)
        # the miss is the brute-force gap: the pin's distance from the guide less b
        rho = np.hypot(bp[:, 0] - e, bp[:, 2])
        assert np.max(np.abs(miss - np.maximum(rho - b, 0.0))) < 1e-9
        ok = miss == 0.0
        assert np.array_equal(np.isfinite(s), ok) and np.array_equal(np.isfinite(t), ok)
        if ok.any():
            assert np.max(np.abs(np.linalg.norm(cp - bp, axis=-1)[ok] - b)) < 1e-9
        closed += ok.all()
        missed += (~ok).any()
        # where the branch closes all round, its exact stroke bounds the sampled one
        x = engine.slider_extremes(a, b, e, f, alpha, branch)
        sf, _, _, _, mf, _ = engine.spatial_slider_displacement(fine, a, b, e, f, alpha, branch)
        if np.all(mf == 0.0) and not (abs(np.cos(alpha)) < 1e-9 and e == 0.0):
            assert float(x.s_max) >= np.max(sf) - 1e-9 and float(x.s_min) <= np.min(sf) + 1e-9
            assert float(x.stroke) - np.ptp(sf) < 1e-3 * (1.0 + np.max(np.abs(sf)))
        elif np.any(mf > 0.0):
            assert np.isnan(x.stroke)
    assert closed > 20 and missed > 20  # both outcomes were exercised


def test_file_refuses_a_bad_slider_group_by_field(tmp_path):
    text = EXAMPLE.read_text()
    for old, new, words in (('branch = "branch_s"', "branch = 2", "C.branch"),
                            ('alpha_deg = "alpha"', 'alpha_deg = "beta"', "C.alpha_deg"),
                            ('group = "C"', 'group = "B"', "transmission_min_deg.group")):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace(old, new))
        code, out, err = run("run", str(bad), "nominal")
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
        assert words in err, err
