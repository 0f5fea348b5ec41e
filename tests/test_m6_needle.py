"""M6 needle drive: reconstruction, exact travel, transfer functions, reactions, energy, inputs."""

import ast
import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sewtol import engine
from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.m6_needle import model as m6
from sewtol.mechanisms.m6_needle.model import M6Needle
from sewtol.protocol import input_law

TOML = Path(__file__).resolve().parents[1] / "examples" / "m6_needle.toml"


@pytest.fixture(scope="module")
def nominal():
    return M6Needle()


@pytest.fixture(scope="module")
def nominal_reactions(nominal):
    return m6.reactions(nominal, samples=720)


def test_reconstruction_meets_travel_and_point(nominal):
    assert abs(float(m6.travel_mm(nominal)) - 24.2) < 1e-9
    lo, hi = m6.needle_extremes(nominal)
    mid = 0.5 * (lo + hi)
    assert abs(mid - (50.1 + 13.3j)) < 1e-9
    assert abs(abs(nominal.pivot) - 52.3) < 1e-12
    # the defaults are what reconstruct() solves today
    rec = m6.reconstruct()
    for f in dataclasses.fields(M6Needle):
        assert abs(float(getattr(rec.params, f.name)) - float(getattr(nominal, f.name))) < 1e-9, f
    assert abs(rec.residual_travel_mm) < 1e-9 and rec.residual_point_mm < 1e-9


def test_travel_closed_form_and_against_a_dense_turn(nominal):
    # arm horizontal in the middle of the swing, slot through O2: the pin B rises by
    # 2 arm sin(psi_max) = 2 arm r / d and the vertical rod's foreshortening is equal at both ends
    r, d, arm = nominal.crank_mm, nominal.pivot_mm, nominal.arm_mm
    assert abs(float(m6.travel_mm(nominal)) - 2 * arm * r / d) < 1e-12
    c = P.column(nominal, None)
    q = np.linspace(0, 2 * np.pi, 400_001)
    y = m6.chain(c, q)["J"].p.imag
    exact = float(m6.travel_mm(nominal))
    assert 0 <= exact - np.ptp(y) < 1e-8
    for alt in m6.alternatives():
        qa = np.linspace(0, 2 * np.pi, 200_001)
        ya = m6.chain(P.column(alt.params, None), qa)["J"].p.imag
        assert 0 <= float(m6.travel_mm(alt.params)) - np.ptp(ya) < 1e-7, alt.name
    # a short rod on a tilted arm: J stands still inside the swing (the rod along the arm) and
    # turns back there, beyond its position at the lever's extremes by 5 um
    odd = M6Needle(crank_mm=8.58, pivot_mm=51.98, pivot_deg=120.06, slot_offset_mm=1.0,
                   arm_deg=55.59, arm_mm=73.24, rod_mm=6.25, guide_x_mm=51.72, guide_y_mm=12.41,
                   guide_deg=94.31)
    c = P.column(odd, None)
    s = (m6.chain(c, q)["J"].p * np.exp(-1j * np.radians(odd.guide_deg))).real
    lo, hi = m6.lever_extremes(c)
    at_ends = abs(m6.needle_at_lever(c, hi) - m6.needle_at_lever(c, lo))
    assert np.ptp(s) - at_ends > 4e-3
    assert 0 <= float(m6.travel_mm(odd)) - np.ptp(s) < 1e-8


def test_alternatives_fit_equally_well():
    alts = m6.alternatives()
    fitting = [a for a in alts if a.name != "point_from_pivot"]
    assert len(fitting) == 7
    for a in fitting:
        assert abs(float(m6.travel_mm(a.params)) - 24.2) < 1e-9, a.name
        lo, hi = m6.needle_extremes(a.params)
        assert abs(0.5 * (lo + hi) - (50.1 + 13.3j)) < 1e-9, a.name
    other = alts[-1]
    assert abs(other.params.arm_mm - math.hypot(50.1, 13.3)) < 1e-12
    fitted = alts[-2]
    assert fitted.name == "pivot_above_tilt_fitted_R50"
    assert m6.reactions(fitted.params, 720).peaks()["R50_N"] == pytest.approx(7.0, abs=1e-6)
    assert fitted.arm_tilt_deg == pytest.approx(-12.045, abs=1e-3)


def test_chain_keeps_links_and_constraints():
    batch = P.with_deviations(M6Needle(), {"crank_mm": np.array([0.0, 0.3]),
                                           "slot_offset_mm": np.array([0.0, 1.5]),
                                           "guide_deg": np.array([0.0, 4.0])})
    c = P.column(batch, 2)
    q = np.radians(np.arange(0, 360, 3.0))
    o = m6.chain(c, q)
    A, B, J, O2, f = o["A"], o["B"], o["J"], o["O2"], o["lever"]
    assert np.max(np.abs(np.abs(A.p) - c["crank_mm"])) < 1e-12
    assert np.max(np.abs(np.abs(B.p - O2.p) - c["arm_mm"])) < 1e-12
    assert np.max(np.abs(np.abs(J.p - B.p) - c["rod_mm"])) < 1e-12
    # A on the slot's line: cross(u, A - O2) = slot offset
    u = np.exp(1j * f.a)
    assert np.max(np.abs((u.conjugate() * (A.p - O2.p)).imag - c["slot_offset_mm"])) < 1e-12
    ug = np.exp(1j * np.radians(c["guide_deg"]))
    g = c["guide_x_mm"] + 1j * c["guide_y_mm"]
    assert np.max(np.abs((ug.conjugate() * (J.p - g)).imag)) < 1e-12


def test_transfer_functions_match_central_differences():
    batch = P.with_deviations(M6Needle(), {"crank_mm": np.array([0.0, -0.4]),
                                           "slot_offset_mm": np.array([0.0, 2.0]),
                                           "arm_deg": np.array([0.0, 10.0])})
    c = P.column(batch, 2)
    q = np.radians(np.arange(0, 360, 7.0))
    o = m6.chain(c, q)
    for h, attr, tol in ((1e-5, "dp", 1e-7), (1e-3, "ddp", 1e-5)):
        plus, minus = m6.chain(c, q + h), m6.chain(c, q - h)
        for key in ("A", "B", "J", "G4"):
            if attr == "dp":
                num = (plus[key].p - minus[key].p) / (2 * h)
            else:
                num = (plus[key].p - 2 * o[key].p + minus[key].p) / h**2
            assert np.max(np.abs(getattr(o[key], attr) - num)) < tol, (key, attr)
    num = (m6.chain(c, q + 1e-5)["lever"].a - m6.chain(c, q - 1e-5)["lever"].a) / 2e-5
    assert np.max(np.abs(o["lever"].da - num)) < 1e-9


def test_pin_speed_peak_is_the_closed_form(nominal):
    # slot through O2: the lever turns fastest, psi' = r / (d - r), when the crank points at O2
    c = P.column(nominal, None)
    q = np.array([math.radians(nominal.pivot_deg)])
    B = m6.chain(c, q)["B"]
    r, d = nominal.crank_mm, nominal.pivot_mm
    assert abs(abs(B.dp[0]) - nominal.arm_mm * r / (d - r)) < 1e-9
    qs = np.linspace(0, 2 * np.pi, 100_001)
    assert abs(np.max(np.abs(m6.chain(c, qs)["B"].dp)) - nominal.arm_mm * r / (d - r)) < 1e-6


def test_speed_and_acceleration_as_reported(nominal):
    fig = m6.evaluate(nominal, samples=3600)
    assert float(fig.travel_mm) == pytest.approx(24.2, abs=1e-9)
    assert float(fig.speed_max_m_s) == pytest.approx(6.0109, abs=2e-4)
    assert float(fig.accel_max_m_s2) == pytest.approx(2371.65, abs=0.05)
    other = m6.published_point_from_pivot().params
    fo = m6.evaluate(other, samples=3600)
    assert float(fo.travel_mm) == pytest.approx(15.7925, abs=1e-4)
    assert float(fo.speed_max_m_s) == pytest.approx(3.9031, abs=2e-4)
    assert float(fo.accel_max_m_s2) == pytest.approx(1576.74, abs=0.05)
    # speed and acceleration scale with the shaft speed and its square
    half = m6.evaluate(nominal.override(rpm=2000.0), samples=3600)
    assert float(half.speed_max_m_s) == pytest.approx(float(fig.speed_max_m_s) / 2, rel=1e-12)
    assert float(half.accel_max_m_s2) == pytest.approx(float(fig.accel_max_m_s2) / 4, rel=1e-12)


def test_reactions_balance_every_body(nominal, nominal_reactions):
    assert np.max(nominal_reactions.residual_N) < 1e-9
    # a needle load adds to the balance, it does not break it
    loaded = m6.reactions(nominal, samples=360, needle_force_N=20.0)
    assert np.max(loaded.residual_N) < 1e-9


def test_energy_check(nominal, nominal_reactions):
    R = nominal_reactions
    scale = np.max(np.abs(R.torque_Nm))
    assert np.max(np.abs(R.torque_Nm - R.energy_torque_Nm)) / scale < 1e-9
    loaded = m6.reactions(nominal, samples=360, needle_force_N=20.0)
    scale = np.max(np.abs(loaded.torque_Nm))
    assert np.max(np.abs(loaded.torque_Nm - loaded.energy_torque_Nm)) / scale < 1e-9
    # over a turn at uniform speed without losses the shaft puts in no net work
    assert abs(np.mean(R.torque_Nm)) < 1e-9 * scale


def test_reaction_peaks_as_reported(nominal_reactions):
    pk = nominal_reactions.peaks()
    expected = {"R12_N": 108.85, "R23_N": 108.66, "R34_N": 108.66, "R40_N": 104.60,
                "R45_N": 32.30, "R50_N": 0.910}
    for k, v in expected.items():
        assert pk[k] == pytest.approx(v, abs=0.01), k
    # without masses only gravity is left: the needle bar's weight through the rod
    light = m6.reactions(M6Needle(lever_kg=0.0, lever_kgm2=0.0, bar_kg=0.0, shaft_kg=0.0),
                         samples=72)
    assert np.max(np.abs(light.torque_Nm)) < 1e-12 and np.max(np.abs(light.F02)) < 1e-12


def test_static_case_against_hand_calculation():
    # at 1e-6 rpm only gravity acts: the rod carries the needle bar's weight (vertical rod at
    # the middle of the swing, where the crank points along the slot)
    p = M6Needle(rpm=1e-6)
    c = P.column(p, None)
    lo, hi = m6.lever_extremes(c)
    R = m6.reactions(p, samples=7200)
    o = m6.chain(c, np.radians(R.phi_deg))
    k = int(np.argmin(np.abs(o["lever"].a - 0.5 * (lo + hi))))
    assert abs(R.S[k] - p.bar_kg * m6.G_M_S2) < 1e-3 * p.bar_kg * m6.G_M_S2


@pytest.fixture(scope="module")
def mech():
    from sewtol.mechanism import load

    return load(TOML)


def test_scan_is_the_exact_travel_by_hand(nominal, mech):
    from sewtol.studies.scan import scan

    ts = mech.tolerance_sets["illustrative"]
    res = scan(mech, ts, ["travel_mm"])
    rows = res.rows
    assert len(rows) == 2 * len(ts.items) and (rows["status"] == "ok").all()
    for _, r in rows.iterrows():
        by_hand = float(m6.travel_mm(nominal.override(**{
            r["param"]: float(getattr(nominal, r["param"])) + r["deviation"]})))
        assert abs(r["value"] - by_hand) < 1e-12, (r["param"], r["side"])
        assert abs(r["change"] - (by_hand - 24.2)) < 1e-12
    sc = {(r["param"], r["side"]): r["value"] for _, r in rows.iterrows()}
    tol = {t.param: t.upper for t in ts.items}

    def slope(k):
        return (sc[k, "upper"] - sc[k, "lower"]) / (2 * tol[k])

    r, d, arm = nominal.crank_mm, nominal.pivot_mm, nominal.arm_mm
    assert slope("crank_mm") == pytest.approx(2 * arm / d, rel=1e-9)
    assert slope("arm_mm") == pytest.approx(2 * r / d, rel=1e-9)
    assert slope("pivot_mm") == pytest.approx(-2 * arm * r / d**2, rel=1e-6)
    # the rod and the needle bar's x do not change the travel (equal foreshortening at both ends)
    assert abs(sc["rod_mm", "upper"] - 24.2) < 1e-12
    assert abs(sc["guide_x_mm", "lower"] - 24.2) < 1e-12
    # the generic (sampled) scan lies below, within the kernel's bound
    from sewtol.mechanisms.m6_needle.fast_path import travel_kernel_bound

    generic = scan(mech, ts, ["travel_mm"], fast=False).rows["value"].to_numpy()
    gap = rows["value"].to_numpy() - generic
    assert np.all(gap >= 0) and np.all(gap <= travel_kernel_bound(mech, res.values)["travel_mm"])


def test_montecarlo_draws_the_shared_sampler_and_repeats(nominal, mech):
    from sewtol.studies.montecarlo import montecarlo
    from sewtol.tolerances import Tolerance, ToleranceSet

    ts = ToleranceSet("t", tuple(Tolerance(k, -t, t) for k, t in
                                 {"crank_mm": 0.02, "pivot_mm": 0.03, "arm_mm": 0.05}.items()))
    a = montecarlo(mech, ts, 500, 7, ["travel_mm"], fast=True).machines
    b = montecarlo(mech, ts, 500, 7, ["travel_mm"], fast=True).machines
    assert a.equals(b)
    assert not a.equals(montecarlo(mech, ts, 500, 8, ["travel_mm"], fast=True).machines)
    # the machines are the one sampler's for the seed (every study draws these)
    dev = input_law(mech, ts).draw(500, 7)
    r, d, arm = (nominal.crank_mm + dev["crank_mm"], nominal.pivot_mm + dev["pivot_mm"],
                 nominal.arm_mm + dev["arm_mm"])
    assert np.max(np.abs(a["travel_mm"].to_numpy() - 2 * arm * r / d)) < 1e-12
    assert (a["status"] == "ok").all()


def test_kernel_is_the_exact_travel_on_random_machines(mech):
    from sewtol.mechanisms.m6_needle.fast_path import travel_kernel, travel_kernel_bound

    rng = np.random.default_rng(21)
    n = 300
    spread = {"crank_mm": 1.0, "pivot_mm": 2.0, "pivot_deg": 5.0, "slot_offset_mm": 2.0,
              "arm_deg": 20.0, "arm_mm": 5.0, "rod_mm": 30.0, "guide_x_mm": 2.0,
              "guide_y_mm": 2.0, "guide_deg": 10.0}
    nominal = mech.nominal_values()
    values = {k: nominal[k] + rng.uniform(-w, w, n) for k, w in spread.items()}
    got = travel_kernel(mech, values)["travel_mm"]
    ev = mech.evaluate(values, ["travel_mm"])
    runs = ev.status == "ok"
    # short rods that miss the guide somewhere in the swing: NaN exactly where the file fails
    assert 10 < np.sum(~runs) < n - 100
    assert np.array_equal(np.isnan(got), ~runs)
    with np.errstate(invalid="ignore"):
        exact = m6.travel_mm(M6Needle(**values))
    assert np.max(np.abs(got - exact)[runs]) < 1e-12
    # within the bound above the file's sampled travel
    gap = (got - ev.outputs["travel_mm"])[runs]
    bound = travel_kernel_bound(mech, values)["travel_mm"][runs]
    assert np.all(gap >= 0) and np.all(gap <= bound)


def test_kernel_keeps_the_file_where_the_closed_form_does_not_hold(mech):
    from sewtol.mechanisms.m6_needle.fast_path import travel_kernel

    # a rod too short to reach the guide (cannot close), a lever that turns round (crank
    # beyond pivot_mm + |slot_offset_mm|) with a rod that reaches the guide all round (runs:
    # the file's sampled travel), the nominal
    values = {"rod_mm": np.array([0.46, 200.0, 31.461184236855885]),
              "crank_mm": np.array([8.2, 60.0, 8.2])}
    ev = mech.evaluate(values, ["travel_mm"])
    got = travel_kernel(mech, values)["travel_mm"]
    assert list(ev.status) == ["cannot_close", "ok", "ok"]
    assert np.isnan(got[0]) and got[1] == ev.outputs["travel_mm"][1]
    assert got[2] == pytest.approx(24.2, abs=1e-12)


def test_failures_are_counted_and_named(nominal):
    # a rod of 0.46 mm cannot follow the pin's 0.95 mm sideways excursion; a horizontal guide
    # placed so that the rod stands 0.57 deg off perpendicular to it at the pin's top position
    # closes everywhere but passes a dead point
    r, d = nominal.crank_mm, nominal.pivot_mm
    y_top = nominal.pivot.imag + nominal.arm_mm * r / d
    dead_y = y_top - nominal.rod_mm * math.cos(math.asin(0.01))
    batch = P.with_deviations(nominal, {"rod_mm": np.array([0.0, -31.0, 0.0]),
                                        "guide_deg": np.array([0.0, 0.0, -90.0]),
                                        "guide_y_mm": np.array([0.0, 0.0, dead_y - 13.3])})
    fig = m6.evaluate(batch, samples=3600)
    assert list(fig.status) == ["ok", "cannot_close", "dead_point"]
    assert list(fig.failed_group) == ["", "B-J-guide", "B-J-guide"]
    assert np.isfinite(fig.travel_mm[0]) and np.isnan(fig.travel_mm[1:]).all()


@pytest.mark.parametrize("change, field", [
    ({"crank_mm": -1.0}, "crank_mm"), ({"rod_mm": 0.0}, "rod_mm"),
    ({"rod_branch": 0.0}, "rod_branch"), ({"crank_mm": 60.0}, "crank_mm"),
    ({"lever_kg": -0.1}, "lever_kg"), ({"rpm": 0.0}, "rpm"), ({"arm_deg": float("nan")}, "arm_deg"),
])
def test_bad_values_name_the_field(change, field):
    with pytest.raises(ParameterError) as err:
        M6Needle(**change)
    assert err.value.field == field
    with pytest.raises(ParameterError, match="unknown parameter"):
        M6Needle().override(crank=8.0)


# --- the example file: the same chain, written as data ----------------------------------------

_FUNCS = {"sin": math.sin, "cos": math.cos, "tan": math.tan, "sqrt": math.sqrt,
          "radians": math.radians, "degrees": math.degrees}


def _value(expr, names):
    """Evaluate a file value by walking a whitelisted ast (numbers, names, + - * / **, calls)."""
    if not isinstance(expr, str):
        return float(expr)

    def ev(n):
        if isinstance(n, ast.Expression):
            return ev(n.body)
        if isinstance(n, ast.Constant) and isinstance(n.value, (int, float)):
            return float(n.value)
        if isinstance(n, ast.Name):
            return names[n.id]
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.USub):
            return -ev(n.operand)
        if isinstance(n, ast.BinOp):
            a, b = ev(n.left), ev(n.right)
            ops = {ast.Add: a + b, ast.Sub: a - b, ast.Mult: a * b}
            if isinstance(n.op, tuple(ops)):
                return ops[type(n.op)]
            if isinstance(n.op, ast.Div):
                return a / b
            if isinstance(n.op, ast.Pow):
                return a**b
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id in _FUNCS:
            return _FUNCS[n.func.id](*(ev(x) for x in n.args))
        raise AssertionError(f"not allowed in a mechanism file: {ast.dump(n)}")

    return ev(ast.parse(expr, mode="eval"))


def test_example_file_reproduces_the_module():
    spec = tomllib.loads(TOML.read_text())
    assert spec["format"] == "sewtol-mechanism/1"
    pars = spec["parameters"]
    nominal = M6Needle()
    names = {k: float(v["nominal"]) for k, v in pars.items()}
    for k, v in names.items():
        assert abs(v - float(getattr(nominal, k))) < 1e-12, k
    q = np.radians(np.arange(0, 360, 0.5))
    pts, angles = {}, {}
    for g in spec["groups"]:
        def val(key, g=g):
            return _value(g[key], names)

        if g["type"] == "point":
            pts[g["name"]] = engine.fixed(val("x"), val("y"))
        elif g["type"] == "crank":
            c = pts[g["center"]]
            pts[g["name"]] = engine.crank(c.x, c.y, val("radius"), q, math.radians(val("phase_deg")),
                                          val("sense"))
        elif g["type"] == "rpr":
            angles[g["name"]], _ = engine.rpr(pts[g["pivot"]], pts[g["block"]], val("offset"))
        elif g["type"] == "on_body":
            ang = angles[g["angle"]] + math.radians(val("offset_deg"))
            pts[g["name"]] = engine.on_body(pts[g["origin"]], ang, val("u") + 1j * val("v"))
        elif g["type"] == "rrp":
            pts[g["name"]], _ = engine.rrp(pts[g["p1"]], val("r"), val("x"), val("y"),
                                           math.radians(val("angle_deg")), val("branch"))
        else:
            raise AssertionError(g["type"])
    ref = m6.chain(P.column(nominal, None), q)
    for key in ("A", "B", "J"):
        for attr in ("p", "dp", "ddp"):
            assert np.max(np.abs(getattr(pts[key], attr) - getattr(ref[key], attr))) < 1e-9
    outs = {o["name"]: o for o in spec["outputs"]}
    assert set(outs) == {"travel_mm", "speed_max_m_s", "accel_max_m_s2"}
    assert spec["mechanism"]["rpm"] == nominal.rpm
    y = pts["J"].p.imag
    # sampled every 0.5 deg (720 samples) the range falls 1.16e-4 mm short of the exact 24.2
    assert 0 < 24.2 - np.ptp(y) < 2e-4
    tol = spec["tolerances"]["illustrative"]
    assert set(tol) <= set(pars) and all(v > 0 for v in tol.values())


def test_report_matches_the_committed_tables(tmp_path):

    import pandas as pd

    from test_report_reproducible import compare_printed

    root = Path(__file__).resolve().parents[1]
    from cli_helpers import study_script

    mod = study_script("m6_needle_report")
    mod.main(["--out", str(tmp_path)])
    new, old = tmp_path / "m6_needle", root / "reports" / "m6_needle"
    names = sorted(p.name for p in old.glob("*.csv"))
    assert names == sorted(p.name for p in new.glob("*.csv"))
    for name in names:
        assert compare_printed((new / name).read_text(), (old / name).read_text()) == [], name
    res = pd.read_csv(new / "residuals.csv", comment="#").set_index("figure")
    assert res.loc["travel_mm", "model"] == pytest.approx(24.2, abs=1e-9)
    assert res.loc["speed_max_m_s", "residual"] == pytest.approx(2.0109, abs=2e-4)
    assert res.loc["R45_N", "residual"] == pytest.approx(-0.696, abs=1e-3)


def test_run_scan_and_montecarlo_take_the_exact_travel(nominal):
    from cli_helpers import run, strict_loads

    code, out, err = run("run", "m6_needle", "scan", "--output", "travel_mm", "--format", "json")
    fast = strict_loads(out)
    assert code == 0 and fast["context"]["path"] == "m6_needle", err
    assert fast["context"]["path_reason"] is None
    code, out, _ = run("run", "m6_needle", "scan", "--output", "travel_mm", "--path", "generic",
                       "--format", "json")
    generic = strict_loads(out)
    assert code == 0 and generic["context"]["path"] == "generic"
    from sewtol.mechanism import load
    from sewtol.mechanisms.m6_needle.fast_path import travel_kernel_bound

    mech = load(TOML)
    for a, b in zip(fast["rows"], generic["rows"], strict=True):
        machine = {a["param"]: float(getattr(nominal, a["param"])) + a["deviation"]}
        by_hand = float(m6.travel_mm(nominal.override(**machine)))
        assert abs(a["value"] - by_hand) < 1e-12
        # the sampled travel lies below, within the bound
        bound = travel_kernel_bound(mech, {k: np.array([v]) for k, v in machine.items()})
        assert 0 <= a["value"] - b["value"] <= bound["travel_mm"][0]
    code, out, _ = run("run", "m6_needle", "montecarlo", "--output", "travel_mm", "--n", "50",
                       "--seed", "3", "--format", "json")
    mc = strict_loads(out)
    assert code == 0 and mc["context"]["path"] == "m6_needle"
    assert mc["counts"]["fixed"]["ok"] == 50
    # every output: the kernel gives one of them, so the Monte-Carlo stays generic and says so
    code, out, _ = run("run", "m6_needle", "montecarlo", "--n", "50", "--format", "json")
    ctx = strict_loads(out)["context"]
    assert code == 0 and ctx["path"] == "generic" and "travel_mm alone" in ctx["path_reason"]


@pytest.mark.parametrize("old, new, why", [
    ('axis = "along"\nangle_deg = "guide_deg"', 'axis = "along"\nangle_deg = 90',
     "output travel_mm is not along the guide"),
    ('axis = "along"\nangle_deg = "guide_deg"', 'axis = "y"', "no travel output"),
    ('radius = "crank_mm"', 'radius = "crank_mm * 1.001"', "A differs by"),
])
def test_the_fast_path_is_refused_to_a_file_that_is_not_the_model(old, new, why):
    from sewtol.mechanism import loads

    text = TOML.read_text()
    assert old in text
    with pytest.raises(ParameterError, match=why) as err:
        loads(text.replace(old, new), "m6.toml")
    assert err.value.field.endswith("[mechanism] fast_path")
