"""Engine groups against independent solves, invariants and central differences."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import root

from sewtol import engine
from sewtol.engine.motion import Angle, Motion


def moving_point(q, c0, amp, w, phase):
    """A smooth test motion p(q) = c0 + amp e^{i(w q + phase)} with exact derivatives."""
    rot = amp * np.exp(1j * (w * q + phase))
    return Motion(c0 + rot, 1j * w * rot, -(w**2) * rot)


def central(f, q, h):
    return (f(q + h) - f(q - h)) / (2 * h), (f(q + h) - 2 * f(q) + f(q - h)) / h**2


@given(
    x1=st.floats(-50, 50), y1=st.floats(-50, 50), x2=st.floats(-50, 50), y2=st.floats(-50, 50),
    r1=st.floats(1, 80), r2=st.floats(1, 80), branch=st.sampled_from([1.0, -1.0]),
)
@settings(max_examples=300, deadline=None)
def test_rrr_keeps_link_lengths_and_branch(x1, y1, x2, y2, r1, r2, branch):
    p1, p2 = engine.fixed(x1, y1), engine.fixed(x2, y2)
    j, closure = engine.rrr(p1, r1, p2, r2, branch)
    dist = np.hypot(x2 - x1, y2 - y1)
    if dist <= 1e-12:
        assert closure.miss_mm > 0
        return
    if not abs(r1 - r2) <= dist <= r1 + r2:
        assert closure.miss_mm > 0 and np.isnan(j.p)
        return
    assert closure.miss_mm == 0
    assert abs(abs(j.p - p1.p) - r1) < 1e-9
    assert abs(abs(j.p - p2.p) - r2) < 1e-9
    cross = ((p2.p - p1.p).conjugate() * (j.p - p1.p)).imag
    assert cross * branch >= -1e-9


def test_rrr_misses_by_the_gap():
    _, closure = engine.rrr(engine.fixed(0, 0), 3.0, engine.fixed(10, 0), 4.0, 1.0)
    assert closure.miss_mm == 3.0
    _, closure = engine.rrr(engine.fixed(0, 0), 10.0, engine.fixed(2, 0), 4.0, 1.0)
    assert closure.miss_mm == 4.0


def test_rrr_against_root_solve(rng):
    for _ in range(200):
        p1 = complex(*rng.uniform(-30, 30, 2))
        p2 = complex(*rng.uniform(-30, 30, 2))
        d = abs(p2 - p1)
        r1 = rng.uniform(0.3, 1.0) * d + 1.0
        r2 = rng.uniform(max(abs(d - r1), 0.1) + 0.1, d + r1 - 0.1)
        branch = rng.choice([-1.0, 1.0])
        j, _ = engine.rrr(engine.fixed(p1.real, p1.imag), r1, engine.fixed(p2.real, p2.imag), r2,
                          branch)
        j = complex(j.p)
        guess = j + complex(*rng.uniform(-0.3, 0.3, 2))

        def eqs(v, p1=p1, p2=p2, r1=r1, r2=r2):
            z = complex(*v)
            return [abs(z - p1) - r1, abs(z - p2) - r2]

        sol = root(eqs, [guess.real, guess.imag], tol=1e-14)
        assert np.max(np.abs(eqs(sol.x))) < 1e-11
        assert abs(complex(*sol.x) - j) < 1e-9


def test_rrr_derivatives_match_central_differences():
    def chain(q):
        a = moving_point(q, 0.0, 5.0, 1.0, 0.3)
        b = moving_point(q, 30 + 4j, 2.0, -2.0, 1.1)
        j, _ = engine.rrr(a, 20.0, b, 18.0, 1.0)
        return j

    q = np.linspace(0, 2 * np.pi, 37)
    d1, d2 = central(lambda x: chain(x).p, q, 1e-4)
    j = chain(q)
    assert np.max(np.abs(j.dp - d1)) < 1e-6
    assert np.max(np.abs(j.ddp - d2)) < 1e-5


def test_direction_and_on_body_derivatives():
    def chain(q):
        a = moving_point(q, 1 + 2j, 3.0, 1.0, 0.0)
        b = moving_point(q, 20 + 0j, 4.0, 3.0, 0.5)
        ang = engine.direction(a, b)
        return ang, engine.on_body(a, ang + 0.7, 5.0 - 2.0j)

    q = np.linspace(0, 2 * np.pi, 29)
    ang, x = chain(q)
    a1, a2 = central(lambda v: np.unwrap(chain(v)[0].a), q, 1e-4)
    assert np.max(np.abs(ang.da - a1)) < 1e-7
    assert np.max(np.abs(ang.dda - a2)) < 1e-5
    p1, p2 = central(lambda v: chain(v)[1].p, q, 1e-4)
    assert np.max(np.abs(x.dp - p1)) < 1e-6
    assert np.max(np.abs(x.ddp - p2)) < 1e-5


def test_rpr_satisfies_slot_geometry_and_derivatives():
    offset = 8.0

    def chain(q):
        pivot = moving_point(q, 0.0, 1.0, 1.0, 0.2)
        block = moving_point(q, 30 + 10j, 3.0, -1.0, 0.4)
        f, closure = engine.rpr(pivot, block, offset)
        return pivot, block, f, closure

    q = np.linspace(0, 2 * np.pi, 41)
    pivot, block, f, closure = chain(q)
    assert np.all(closure.ok)
    ell = np.sqrt(np.abs(block.p - pivot.p) ** 2 - offset**2)
    rebuilt = pivot.p + offset * np.exp(1j * (f.a + np.pi / 2)) + ell * np.exp(1j * f.a)
    assert np.max(np.abs(rebuilt - block.p)) < 1e-9
    d1, d2 = central(lambda v: np.unwrap(chain(v)[2].a), q, 1e-4)
    assert np.max(np.abs(f.da - d1)) < 1e-7
    assert np.max(np.abs(f.dda - d2)) < 1e-5


def test_rpr_reports_unreachable_slot():
    f, closure = engine.rpr(engine.fixed(0, 0), engine.fixed(3, 0), 8.0)
    assert closure.miss_mm == 5.0 and np.isnan(f.a)


def test_rrp_slider_on_line_and_derivatives():
    def chain(q):
        crank = engine.crank(0.0, 0.0, 17.5, q)
        return engine.rrp(crank, 42.0, 0.0, 8.0, 0.0, 1.0)

    q = np.linspace(0, 2 * np.pi, 41)
    j, closure = chain(q)
    assert np.all(closure.ok)
    assert np.max(np.abs(j.p.imag - 8.0)) < 1e-12
    crank = engine.crank(0.0, 0.0, 17.5, q)
    assert np.max(np.abs(np.abs(j.p - crank.p) - 42.0)) < 1e-9
    d1, d2 = central(lambda v: chain(v)[0].p, q, 1e-4)
    assert np.max(np.abs(j.dp - d1)) < 1e-6
    assert np.max(np.abs(j.ddp - d2)) < 1e-5
    # closed form of the offset crank-slider: x = r cos q + sqrt(L^2 - (r sin q - e)^2)
    x = 17.5 * np.cos(q) + np.sqrt(42.0**2 - (17.5 * np.sin(q) - 8.0) ** 2)
    assert np.max(np.abs(j.p.real - x)) < 1e-12


def test_angle_offsets_keep_derivatives():
    a = Angle(np.array([0.1]), np.array([2.0]), np.array([3.0]))
    b = a + 0.5
    assert b.a[0] == 0.6 and b.da[0] == 2.0 and b.dda[0] == 3.0
