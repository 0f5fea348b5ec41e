"""Feed chains of the 131-42+3: source figures, transfer functions, errors, regulator."""

import math

import numpy as np
import pytest

from cli_helpers import study_script
from sewtol.errors import AssemblyError, ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.feed_131 import analysis as feed
from sewtol.mechanisms.feed_131 import model as fd
from sewtol.mechanisms.feed_131.model import Feed131
from sewtol.studies import summaries as SU


def _report():
    """studies/feed_131_report.py: the feed report's outputs and tables over the generic
    studies."""
    return study_script("feed_131_report")


T = _report()


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
    mech = T.feed_file()
    sc = T.scan(mech, mech.tolerance_sets["assumed"])
    row = sc[(sc.param == "O3C") & (sc.side == "upper")].iloc[0]
    direct = feed.metrics(p.override(O3C=p.O3C + 0.05))
    assert abs(row.lower_step_mm - direct.lower["feed_step_mm"]) < 1e-9
    assert abs(row.differential_ratio - direct.differential_ratio) < 1e-9


def test_feed_montecarlo_reproducible():
    mech = T.feed_file()
    ts = mech.tolerance_sets["assumed"]
    a = T.montecarlo(mech, ts, 300, seed=4)
    b = T.montecarlo(mech, ts, 300, seed=4, n_jobs=2)
    assert a.equals(b)
    assert a["lower_step_mm"].notna().all()


# --- the analysis program's dog-bar arithmetic, from the note's formulas alone -------------

def _e(a_deg):
    return math.cos(math.radians(a_deg)), math.sin(math.radians(a_deg))


def _dyad(X, XJ, Y, YJ, left):
    """J at XJ from X and YJ from Y, on the left (or right) of X->Y."""
    dx, dy = Y[0] - X[0], Y[1] - X[1]
    d = math.hypot(dx, dy)
    a = (XJ * XJ - YJ * YJ + d * d) / (2 * d)
    h = math.sqrt(XJ * XJ - a * a) * (1 if left else -1)
    return X[0] + (a * dx - h * dy) / d, X[1] + (a * dy + h * dx) / d


def _ang(X, Y):
    return math.degrees(math.atan2(Y[1] - X[1], Y[0] - X[0]))


def _note_lower_tooth(phi, program):
    """Steps 1-11 of ../shared/design/feed_131-42-3.md for one angle, in plain floats. With
    program=True the axis u is the program's ((c EP - s PN) / EN, (s EP + c PN) / EN)."""
    F = tuple(1.8 * v for v in _e(phi + 224))
    O4 = (56.0, 7.5)
    K = _dyad(O4, 24.0, F, 52.0, True)
    c, s = _e(_ang(O4, K) - 98)
    M = (O4[0] + 25 * c, O4[1] + 25 * s)
    A1 = tuple(4.0 * v for v in _e(phi))
    c, s = _e(90 + 30)
    D = (-37.6 + 18 * c, -16.6 + 18 * s)
    B = _dyad(D, 18.0, A1, 41.3, False)
    O3 = (-63.0, -1.0)
    C = _dyad(O3, 20.0, B, 18.0, True)
    c, s = _e(_ang(O3, C) + 88)
    E = (O3[0] + 24 * c, O3[1] + 24 * s)
    N = _dyad(M, 18.0, E, 98.66, True)
    EN = math.hypot(N[0] - E[0], N[1] - E[1])
    c, s = (N[0] - E[0]) / EN, (N[1] - E[1]) / EN
    if program:
        u = ((c * 95.7 - s * 24.0) / 98.66, (s * 95.7 + c * 24.0) / 98.66)
    else:
        t = math.atan(24.0 / 95.7)
        u = (c * math.cos(t) - s * math.sin(t), s * math.cos(t) + c * math.sin(t))
    up = (-u[1], u[0])
    return E[0] + 64.1 * u[0] + 9.3 * up[0], E[1] + 64.1 * u[1] + 9.3 * up[1]


def _model_lower_tooth(params, phi_deg):
    return fd.chains(P.column(params, None), np.radians(phi_deg))["Q1"].p


def test_program_arithmetic_reproduces_the_note_formulas():
    phi = np.arange(0.0, 360.0, 1.0)
    for program in (False, True):
        ref = np.array([complex(*_note_lower_tooth(float(a), program)) for a in phi])
        q = _model_lower_tooth(Feed131(dog_bar_program=float(program)), phi)
        assert np.max(np.abs(q - ref)) < 1e-9, program


def test_program_and_exact_dog_bar_differ_by_the_documented_offset():
    phi = np.arange(0.0, 360.0, 1.0)
    d = (_model_lower_tooth(Feed131(dog_bar_program=1.0), phi)
         - _model_lower_tooth(Feed131(), phi)) * 1e3  # um
    # the program's u is hypot(95.7, 24) / 98.66 long: the tooth moves outward from E by that
    # factor minus one times |E Q1| = hypot(64.1, 9.3), on every angle
    scale = math.hypot(95.7, 24.0) / 98.66
    assert abs(scale - 1.0000357) < 1e-7  # the note: 1.0000355 (truncated)
    assert np.allclose(np.abs(d), (scale - 1) * math.hypot(64.1, 9.3) * 1e3, atol=1e-9)
    assert abs(d.real.mean() - 2.28) < 0.01 and abs(d.imag.mean() - 0.34) < 0.01
    assert np.ptp(d.real) < 0.02 and np.ptp(d.imag) < 0.1  # near-constant over the turn


def test_program_arithmetic_is_only_a_flag():
    with pytest.raises(ParameterError, match="dog_bar_program: must be 0"):
        Feed131(dog_bar_program=0.5)
    with pytest.raises(ParameterError, match="upper_sense: must be -1"):
        Feed131(upper_sense=0.0)
    # the upper chain has no such quirk: the flag leaves it untouched
    phi = np.radians(np.arange(0.0, 360.0, 5.0))
    a = fd.chains(P.column(Feed131(), None), phi)["Q2"].p
    b = fd.chains(P.column(Feed131(dog_bar_program=1.0), None), phi)["Q2"].p
    assert np.array_equal(a, b)


# --- the source's read-offs against the model ----------------------------------------------

@pytest.fixture(scope="module")
def readoffs():
    return feed.readoff_residuals()


def test_readoff_residuals_are_the_models_figures(readoffs, nominal_metrics):
    r = readoffs.to_dataframe()
    assert len(r) == len(feed.READOFFS) * len(readoffs.explanations)
    note = r[r.explanation == "note"].set_index(["dog", "figure"])
    for dog in ("lower", "upper"):
        m = getattr(nominal_metrics, dog)
        assert abs(note.loc[(dog, "entry_phi_deg"), "model"] - m["entry_phi_deg"]) < 1e-9
        assert abs(note.loc[(dog, "feed_step_mm"), "model"] - abs(m["feed_step_mm"])) < 1e-9
        for fig, src in ((f, v) for d, f, v in feed.READOFFS if d == dog):
            row = note.loc[(dog, fig)]
            assert row.source == src
            res = row.model - src
            if fig.endswith("_deg"):
                res = (res + 180) % 360 - 180
            assert abs(row.residual - res) < 1e-9
    # the documented note residuals: lower exit 38.0 against 9, rise 1.283 at 301.2
    assert abs(note.loc[("lower", "exit_phi_deg"), "residual"] - 28.99) < 0.01
    assert abs(note.loc[("lower", "max_rise_mm"), "residual"] - 0.183) < 0.001
    assert abs(note.loc[("upper", "entry_phi_deg"), "residual"] - 161.34) < 0.01


def test_readoff_explanations(readoffs):
    s = readoffs.summary().set_index("explanation")
    # y = 30 lies below the whole lower tooth path: nothing can be read there, and it is said
    assert s.loc["plate 30", "not_produced"] == len(feed.READOFFS)
    assert s.loc["plate 30", "lower_feeds"] == "n/a"
    # the program's arithmetic moves the tooth by 2.3 um: no figure changes by more than
    # 0.02 deg or 0.01 mm, it explains nothing
    r = readoffs.to_dataframe().set_index(["explanation", "dog", "figure"])["model"]
    diff = (r.loc["program dog bar"] - r.loc["note"]).abs()
    assert diff.max() < 0.02
    # the phase conventions that bring the upper phases near 4 .. 180 make it feed in reverse
    for name in s.index:
        if name.startswith("upper") and name != "upper return stroke":
            assert s.loc[name, "upper_feeds"] == "reverse", name
            assert s.loc[name, "upper_max_phase_residual_deg"] < 30, name
    assert s.loc["note", "upper_max_phase_residual_deg"] > 170


def test_fitted_upper_phase_is_the_brute_force_optimum(readoffs):
    """The fitted phase of 'upper phi + c' against an independent 0.5 deg scan."""
    from sewtol.mechanisms.feed_131.metrics import dog_figures

    name = next(e for e in readoffs.explanations if e.name.startswith("upper phi +")
                and e.changes.get("upper_phase") is not None)
    grid = np.arange(0.0, 360.0, 0.5)
    c, _ = feed.columns(Feed131(upper_sense=1.0, upper_phase=grid))
    f = dog_figures(c, "upper")
    mis = np.max(np.abs([(getattr(f, k) - v + 180) % 360 - 180 for k, v in
                         (("entry_phi_deg", 4.0), ("exit_phi_deg", 180.0),
                          ("max_rise_phi_deg", 102.0))]), axis=0)
    fitted = readoffs.summary().set_index("explanation").loc[
        name.name, "upper_max_phase_residual_deg"]
    assert fitted <= np.nanmin(mis) + 1e-6
    assert abs(name.changes["upper_phase"] - grid[np.nanargmin(mis)]) < 0.5


def test_feed_sobol_each_output_over_its_own_parameters():
    from sewtol.studies.montecarlo import contributors
    from sewtol.studies.sobol import case_indices, problem_of, sample

    p = Feed131()
    mech = T.feed_file()
    ts = mech.tolerance_sets["assumed"]
    mc = T.montecarlo(mech, ts, 200, seed=3)
    res, chosen = SU.screened_sobol(mech, ts, ("lower_step_mm", "differential_ratio"), 16, 5,
                                    mc, chunk_size=20)
    # the ratio's own contributors, not the lower step's
    for output, names in chosen.items():
        eta = contributors(mc, ts.active().params, output)
        assert names == eta["param"].tolist()[:len(names)]
        assert 4 <= len(names) <= 12
    assert chosen["differential_ratio"] != chosen["lower_step_mm"]
    # the chunked run equals SALib on the whole sample in one call, output by output
    for output, names in chosen.items():
        sub = ts.active()
        sub = type(sub)(sub.name, tuple(t for t in sub.items if t.param in names),
                        sub.description)
        problem = problem_of(sub)
        X = sample(problem, 16, 5)
        y = feed.outputs(p, {k: X[:, i] for i, k in enumerate(problem["names"])})[output]
        ref = case_indices(problem, X, y, 16, 5, output).indices
        got = res.indices[res.indices.case == output].reset_index(drop=True)
        assert np.allclose(got[["S1", "ST"]].to_numpy(), ref[["S1", "ST"]].to_numpy(),
                           atol=1e-12, equal_nan=True)
    assert list(res.convergence["case"]) == ["lower_step_mm", "differential_ratio"]
