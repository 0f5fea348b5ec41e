"""engine.spatial_slider against a blind second implementation (tests/data/independent_slider_*).

A second engineer wrote the reference from a description of the mechanism alone (frame, branch
and transmission-angle conventions), without seeing sewtol: brentq on |B - C(s)| - b polished by
Newton in mpmath at 30 digits, derivatives by mpmath.diff, extremes by a sweep, a bounded search
and Newton on ds/dphi = 0 (tests/data/independent_slider_METHOD.md; every value within 0.5 ulp).
Six geometries (planar, perpendicular, skew, one that does not assemble all round), both
branches, phi = 0, 10, ..., 350 deg.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sewtol.engine import spatial as S

DATA = Path(__file__).parent / "data"
# (a, b, e, f, alpha_deg) as given to the reference
GEOMETRIES = {"G1": (10, 40, 5, 8, 30), "G2": (12, 50, 0, 0, 0), "G3": (8, 35, 10, 15, 90),
              "G4": (15, 30, -6, 4, 60), "G5": (10, 12, 3, 2, 20), "G6": (5, 60, 20, -10, 120)}
EPS = np.finfo(float).eps
POSITIONS = pd.read_csv(DATA / "independent_slider_positions.csv")
EXTREMES = pd.read_csv(DATA / "independent_slider_extremes.csv")


@pytest.mark.numerics
@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
@pytest.mark.parametrize("branch", [1, -1])
def test_positions_derivatives_and_transmission_equal_the_reference(geometry, branch):
    a, b, e, f, alpha = GEOMETRIES[geometry]
    ref = POSITIONS[(POSITIONS.geometry == geometry) & (POSITIONS.branch == branch)]
    assert len(ref) == 36
    s, d1, d2, d3, _, mu = S.spatial_slider_displacement(np.radians(ref.phi_deg.to_numpy()),
                                                         a, b, e, f, np.radians(alpha), branch)
    # the same crank angles fail to assemble in both (G5 between 154.08 and 212.81 deg)
    gap = ref.s_mm.isna().to_numpy()
    assert np.array_equal(np.isnan(s), gap)
    assert gap.sum() == (6 if geometry == "G5" else 0)
    ok = ~gap
    # s = m + branch sqrt(D) in doubles: the root's error is about eps (|s| + b / sin(mu)), the
    # sqrt magnifying the rounding of D = b^2 sin^2(mu) where the coupler nears the guide's
    # normal; 100 times that bound. Each derivative divides by F_s = 2 b sin(mu) once more.
    sin_mu = np.sin(np.radians(ref.mu_deg.to_numpy()[ok]))
    scale = np.abs(ref.s_mm.to_numpy()[ok]) + b / sin_mu
    for ours, col, power in ((s, "s_mm", 0), (d1, "ds", 1), (d2, "d2s", 2), (d3, "d3s", 3)):
        theirs = ref[col].to_numpy()[ok]
        bound = 100 * EPS * (scale + np.abs(theirs)) / sin_mu**power
        assert np.all(np.abs(ours[ok] - theirs) <= bound), col
    # mu from sin(mu) = sqrt(D) / b: its error is eps / cos(mu) in radians
    bound_mu = np.degrees(100 * EPS / np.maximum(np.cos(np.radians(ref.mu_deg[ok])), 1e-3))
    assert np.all(np.abs(mu[ok] - ref.mu_deg.to_numpy()[ok]) <= bound_mu)


@pytest.mark.numerics
@pytest.mark.parametrize("row", range(12))
def test_stroke_extremes_equal_the_reference(row):
    r = EXTREMES.iloc[row]
    a, b, e, f, alpha = GEOMETRIES[r.geometry]
    x = S.slider_extremes(a, b, e, f, np.radians(alpha), int(r.branch))
    if not r.assembles_all_round:  # G5: no stroke where the crank cannot turn all round
        assert r.geometry == "G5" and np.isnan(float(x.stroke))
        return
    # the extremes are roots of a quartic polished to the double nearest: 1e-12 mm is ~100 ulp
    for ours, theirs in ((x.s_min, r.s_min_mm), (x.s_max, r.s_max_mm), (x.stroke, r.stroke_mm)):
        assert float(ours) == pytest.approx(theirs, abs=1e-12)
    # where s' = 0 the crank angle is fixed to sqrt(eps) of s only, but both sides solve
    # F_phi = 0 for it exactly; compared on the circle (one side reports 0..360, the other
    # -180..180)
    for ours, theirs in ((x.phi_at_min, r.phi_at_min_deg), (x.phi_at_max, r.phi_at_max_deg)):
        d = (np.degrees(float(ours)) - theirs + 180.0) % 360.0 - 180.0
        assert abs(d) <= 1e-9
