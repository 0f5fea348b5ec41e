"""Feed chains of the 131-42+3: source figures, transfer functions, errors, regulator."""

import numpy as np
import pytest

from sewtol import feed
from sewtol.errors import AssemblyError, ParameterError
from sewtol.mechanisms import feed_131 as fd
from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131 import Feed131


@pytest.fixture(scope="module")
def nominal_metrics():
    return feed.metrics(Feed131())


def test_lower_dog_matches_the_source(nominal_metrics):
    low = nominal_metrics.lower
    assert abs(low["entry_phi_deg"] - 202.0) < 1.0  # rises above y = 32.5 near phi = 202
    assert 2.1 <= low["feed_step_mm"] <= 2.2
    assert low["feed_step_mm"] > 0  # forward feed, counter-clockwise tooth path


def test_plate_crossings_are_on_the_plate(nominal_metrics):
    p = Feed131()
    c = P.column(p, None)
    for dog, key in (("lower", "Q1"), ("upper", "Q2")):
        m = getattr(nominal_metrics, dog)
        q = fd.chains(c, np.radians([m["entry_phi_deg"], m["exit_phi_deg"]]))[key].p
        assert np.max(np.abs(q.imag - 32.5)) < 1e-9
        assert abs((q.real[0] - q.real[1]) - m["feed_step_mm"]) < 1e-9


def test_rise_and_travel_against_a_dense_sweep(nominal_metrics):
    phi = np.radians(np.linspace(0, 360, 360_001))
    q = fd.chains(P.column(Feed131(), None), phi)["Q1"].p
    assert abs(nominal_metrics.lower["max_rise_mm"] - (q.imag.max() - 32.5)) < 1e-9
    assert abs(nominal_metrics.lower["vertical_travel_mm"] - np.ptp(q.imag)) < 1e-6


def test_tooth_velocities_match_central_differences():
    c = P.column(Feed131(), None)
    phi = np.radians(np.arange(0, 360, 7.0))
    o = fd.chains(c, phi)
    # h = 1e-4 for slopes; 1e-3 for curvatures, where round-off on points ~200 mm from the
    # origin would dominate a smaller step (the error falls as h^2 down to h = 1e-3)
    for h, attr, tol in ((1e-4, "dp", 1e-7), (1e-3, "ddp", 2e-6)):
        plus, minus = fd.chains(c, phi + h), fd.chains(c, phi - h)
        for key in ("Q1", "Q2", "C", "L", "Y"):
            if attr == "dp":
                num = (plus[key].p - minus[key].p) / (2 * h)
            else:
                num = (plus[key].p - 2 * o[key].p + minus[key].p) / h**2
            assert np.max(np.abs(getattr(o[key], attr) - num)) < tol, (key, attr)


def test_chain_keeps_link_lengths():
    p = Feed131()
    o = fd.chains(P.column(p, None), np.radians(np.arange(0, 360, 5.0)))

    def dist(a, b):
        return np.abs(o[a].p - o[b].p) if isinstance(b, str) else np.abs(o[a].p - b)

    assert np.allclose(dist("K", "F"), p.FK, atol=1e-9)
    assert np.allclose(dist("B", "A1"), p.A1B, atol=1e-9)
    assert np.allclose(dist("N", "M"), p.MN, atol=1e-9)
    assert np.allclose(dist("N", "E"), p.EN, atol=1e-9)
    assert np.allclose(dist("R", "C"), p.CR, atol=1e-9)
    assert np.allclose(dist("V", "S"), p.SV, atol=1e-9)
    assert np.allclose(dist("L", "W"), p.WL, atol=1e-9)
    assert np.allclose(dist("H", "A2"), p.A2H, atol=1e-9)
    assert np.allclose(dist("J", "I"), p.IJ, atol=1e-9)
    assert np.allclose(dist("S", "R"), p.RS, atol=1e-9)
    assert np.allclose(dist("W", complex(p.O8x, p.O8y)), p.O8W, atol=1e-9)
    # the block Y lies on the holder's slot at the offset from L
    f = o["holder_angle"].a
    rel = (o["Y"].p - o["L"].p) * np.exp(-1j * f)
    assert np.allclose(rel.imag, p.slot_offset, atol=1e-9)


def test_broken_dyad_names_the_dyad_and_angle():
    with pytest.raises(AssemblyError) as exc:
        feed.metrics(Feed131().override(EN=50.0))
    assert exc.value.group == "M-N-E" and exc.value.miss_mm > 0
    assert 0 <= exc.value.angle_deg < 360
    assert "dyad M-N-E cannot close at angle" in str(exc.value)
    with pytest.raises(AssemblyError, match="dyad D-B-A1"):
        feed.trajectory(Feed131().override(b=120.0))


def test_bad_values_are_refused():
    with pytest.raises(ParameterError, match="FK: must be a positive length"):
        Feed131(FK=-1.0)
    with pytest.raises(ParameterError, match="material_mm: must not be negative"):
        Feed131(material_mm=-0.5)
    with pytest.raises(ParameterError, match="valid names are O1F, lift_phase"):
        Feed131().override(O9x=1.0)


def test_regulator_forward_neutral_reverse():
    p = Feed131()
    sweep = feed.regulator_sweep(p, np.arange(0.0, 60.0, 5.0))
    steps = sweep["lower_step_mm"].to_numpy()
    assert steps[0] < 0 < steps[-1]  # reverse at b = 0, forward at 55
    b0 = feed.b_for_step(p, 0.0)
    assert 10 < b0 < 25
    assert abs(feed.outputs(p, {"b": np.array([b0 - p.b])})["lower_step_mm"][0]) < 1e-7
    b25 = feed.b_for_step(p, 2.5)
    assert abs(feed.outputs(p, {"b": np.array([b25 - p.b])})["lower_step_mm"][0] - 2.5) < 1e-7
    with pytest.raises(ParameterError, match="step_mm: must lie within the regulator's range"):
        feed.b_for_step(p, 40.0)


def test_scan_rows_equal_direct_calls():
    p = Feed131()
    ts = feed.default_tolerances()
    sc = feed.scan(p, ts)
    row = sc[(sc.param == "O3C") & (sc.side == "upper")].iloc[0]
    direct = feed.metrics(p.override(O3C=p.O3C + 0.05))
    assert abs(row.lower_step_mm - direct.lower["feed_step_mm"]) < 1e-9
    assert abs(row.differential_ratio - direct.differential_ratio) < 1e-9


def test_feed_montecarlo_reproducible():
    ts = feed.default_tolerances()
    a = feed.montecarlo(Feed131(), ts, 300, seed=4)
    b = feed.montecarlo(Feed131(), ts, 300, seed=4, n_jobs=2)
    assert a.equals(b)
    assert a["lower_step_mm"].notna().all()
