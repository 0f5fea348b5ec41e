"""Presser foot with an elastic link: kinematics, the event-driven dynamics against an
independent ODE integration, the fit to the source's table (its residuals asserted as
docs/presser_foot.md states them), impact and energy invariants, identifiability, studies."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from sewtol.errors import ParameterError
from sewtol.mechanisms.presser_foot import kernel as K
from sewtol.mechanisms.presser_foot import model as PF
from sewtol.tables import presser_foot as S

R, L, A = 17.5, 42.0, 8.0


def test_slider_is_the_published_formula_with_exact_derivatives():
    phi = np.radians(np.arange(0.0, 360.0, 7.3))
    y, d1, d2 = PF.slider(phi, R, L, A)
    published = np.sqrt(L**2 - (R * np.sin(phi)) ** 2) + R * np.cos(phi) + A
    np.testing.assert_allclose(y, published, rtol=0, atol=1e-12)
    assert PF.slider(0.0, R, L, A)[0] == pytest.approx(L + R + A, abs=1e-12)
    assert PF.slider(math.pi, R, L, A)[0] == pytest.approx(L - R + A, abs=1e-12)
    h = 1e-5
    fd1 = (PF.slider(phi + h, R, L, A)[0] - PF.slider(phi - h, R, L, A)[0]) / (2 * h)
    fd2 = (PF.slider(phi + h, R, L, A)[1] - PF.slider(phi - h, R, L, A)[1]) / (2 * h)
    np.testing.assert_allclose(d1, fd1, atol=1e-8)
    np.testing.assert_allclose(d2, fd2, atol=1e-8)
    for p, yy, a1, a2 in zip(phi, y, d1, d2, strict=True):   # the kernel's copy is the same
        assert K.slider(p, R, L, A) == pytest.approx((yy, a1, a2), abs=1e-12)


@pytest.mark.parametrize("nu,zeta", [(0.7, 0.012), (3.0, 0.012), (1.3, 0.3), (2.0, 0.0)])
def test_free_vibration_is_the_ode_solution(nu, zeta):
    x0, v0, xe = 50.0, 18.4, 56.0
    t = np.linspace(0.0, 4.0, 41)
    sol = solve_ivp(lambda _, s: [s[1], -nu * nu * (s[0] - xe) - 2 * zeta * nu * s[1]],
                    (0.0, 4.0), [x0, v0], t_eval=t, rtol=1e-13, atol=1e-13, method="DOP853")
    closed = np.array([K.free(dt, x0, v0, nu, zeta, xe) for dt in t])
    scale = np.max(np.abs(sol.y[0] - xe))
    np.testing.assert_allclose(closed[:, 0] - xe, sol.y[0] - xe, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(closed[:, 1], sol.y[1], rtol=0,
                               atol=1e-9 * np.max(np.abs(sol.y[1])))


def _reference_flight(nu, zeta, xe):
    """An independent run: loss by brentq on the contact force, flight by solve_ivp."""
    def force(p):
        y, d1, d2 = PF.slider(p, R, L, A)
        return nu * nu * (xe - y) - 2 * zeta * nu * d1 - d2
    grid = np.radians(np.arange(0.0, 360.0, 0.1))
    f = np.array([force(p) for p in grid])
    start = int(np.argmax(f))
    order = np.r_[start:grid.size, 0:start]
    for i, j in zip(order[:-1], order[1:], strict=True):
        if f[i] >= 0 > f[j]:
            a, b = grid[i], grid[j] if j > i else grid[j] + 2 * np.pi
            lo = brentq(force, a, b, xtol=1e-14)
            break
    y0, v0, _ = PF.slider(lo, R, L, A)

    def gap(p, s):
        return PF.slider(p, R, L, A)[0] - s[0]
    gap.terminal, gap.direction = True, -1
    sol = solve_ivp(lambda _, s: [s[1], -nu * nu * (s[0] - xe) - 2 * zeta * nu * s[1]],
                    (lo, lo + 4 * np.pi), [y0, v0], events=gap,
                    rtol=1e-12, atol=1e-12, method="DOP853", dense_output=True)
    re = sol.t_events[0][0]
    p = np.linspace(lo, re, 20001)
    sep = np.max(PF.slider(p, R, L, A)[0] - sol.sol(p)[0])
    return math.degrees(lo) % 360, math.degrees(re) % 360, sep


@pytest.mark.parametrize("nu,xe", [(1.3, 52.0), (5.0, 63.0)])
def test_flight_events_agree_with_an_ode_integration(nu, xe):
    loss, regain, lost, sep, impacts, landed, status, by_force, count = K.one_machine(
        R, L, A, nu, 0.012, xe, np.inf)
    assert status == K.OK and by_force == 1 and impacts == 0 and landed == 0 and count == 1
    ref = _reference_flight(nu, 0.012, xe)
    assert loss == pytest.approx(ref[0], abs=1e-7)
    assert regain == pytest.approx(ref[1], abs=1e-7)   # the ODE event, rtol 1e-12
    assert sep == pytest.approx(ref[2], abs=1e-8)


def test_recontact_is_continuous_and_plastic():
    nu, z, xe = 1.3, 0.012, 52.0
    loss, regain, *_ = K.one_machine(R, L, A, nu, z, xe, np.inf)
    pl = math.radians(loss)
    pr = pl + math.radians((regain - loss) % 360)
    y0, v0, _ = K.slider(pl, R, L, A)
    xf, vf = K.free(pr - pl, y0, v0, nu, z, xe)
    ys, vs, _ = K.slider(pr, R, L, A)
    assert xf == pytest.approx(ys, abs=1e-9)         # positions meet at the impact
    assert vf - vs > 0.0                              # the foot closes on the seat
    # plastic impact with a much heavier seat: the foot takes vs; the energy lost per unit
    # mass is (vf - vs)^2 / 2 and the contact that follows holds
    assert K.contact_force(pr, R, L, A, nu, z, xe) >= 0.0


def test_undamped_flight_keeps_its_energy():
    nu, xe, x0, v0 = 2.3, 60.0, 50.0, 15.0
    e0 = 0.5 * v0**2 + 0.5 * nu**2 * (x0 - xe) ** 2
    for dt in np.linspace(0.0, 10.0, 57):
        x, v = K.free(dt, x0, v0, nu, 0.0, xe)
        assert 0.5 * v**2 + 0.5 * nu**2 * (x - xe) ** 2 == pytest.approx(e0, rel=1e-12)


def test_damped_flight_loses_exactly_the_damper_work():
    from scipy.integrate import quad

    nu, z, xe, x0, v0 = 2.3, 0.012, 60.0, 50.0, 15.0

    def energy(x, v):
        return 0.5 * v**2 + 0.5 * nu**2 * (x - xe) ** 2
    for end in (0.7, 2.9, 6.1):
        work, _ = quad(lambda t: 2 * z * nu * K.free(t, x0, v0, nu, z, xe)[1] ** 2, 0.0, end,
                       epsabs=1e-13, epsrel=1e-13, limit=200)
        lost = energy(x0, v0) - energy(*K.free(end, x0, v0, nu, z, xe))
        assert lost == pytest.approx(work, rel=1e-10)


def test_fit_reproduces_the_source_table_within_the_stated_residuals():
    fit = _fit()
    assert fit.phase_deg == pytest.approx(317.75, abs=0.01)
    assert fit.material_mm == pytest.approx(61.2804, abs=2e-4)
    rows = fit.rows
    assert set(rows.status) == {"ok"}
    np.testing.assert_allclose(rows.loss_residual_deg, -2.469, atol=0.01)
    expected_regain = np.where(rows.wire_mm == 0.32, 6.969, 1.969)
    np.testing.assert_allclose(rows.regain_residual_deg, expected_regain, atol=0.01)
    expected_sep = {0.32: 0.210, 0.41: 0.030, 0.47: -0.011, 0.52: -0.024, 0.56: -0.031,
                    0.59: -0.034, 0.63: -0.036, 0.65: -0.037, 0.68: -0.086, 0.71: -0.039,
                    0.87: 0.170, 0.88: -0.042}
    for d, res in zip(rows.wire_mm, rows.separation_residual_mm, strict=True):
        assert res == pytest.approx(expected_sep[round(d, 2)], abs=6e-4)
    assert fit.rms_angle_deg == pytest.approx(2.687, abs=0.005)
    assert fit.rms_separation_mm == pytest.approx(0.0733, abs=5e-4)
    # the fitted cycle is the kinematic one: the seat passes the material at loss and regain
    nom = PF.PresserFoot()
    res = PF.evaluate(nom)
    assert not res.lost_by_force[0] and res.landed[0]
    assert res.separation_mm[0] == pytest.approx(R + L + A - nom.material_mm, abs=1e-9)
    for ang in (res.loss_deg[0], res.regain_deg[0]):
        y = PF.slider(math.radians(ang - nom.phase_deg), R, L, A)[0]
        assert y == pytest.approx(nom.material_mm, abs=1e-9)


_FIT = {}


def _fit():
    if "fit" not in _FIT:
        _FIT["fit"] = PF.fit_source()
    return _FIT["fit"]


def test_mass_stiffness_and_preload_enter_only_as_ratios():
    # a machine that flies (holding below the threshold) and the nominal one
    flying = PF.PresserFoot(stiffness_n_per_mm=0.02, preload_n=1.5)
    for base in (PF.PresserFoot(), flying):
        # mass, spring rate and preload all times each factor: k/m and (F + m g)/m unchanged
        f = np.array([0.2, 1.0, 5.0])
        family = dataclasses.replace(base, mass_kg=base.mass_kg * f,
                                     stiffness_n_per_mm=base.stiffness_n_per_mm * f,
                                     preload_n=base.preload_n * f)
        fam = PF.evaluate(family).to_dataframe()
        for col in ("loss_deg", "regain_deg", "lost_deg", "separation_mm"):
            np.testing.assert_allclose(fam[col], fam[col].iloc[1], rtol=0, atol=1e-9)
    assert PF.evaluate(flying).lost_by_force[0]


def test_the_follow_threshold_separates_kinematic_from_flying_cycles():
    nom = PF.PresserFoot(stiffness_n_per_mm=0.02)
    need = PF.follow_threshold_m_s2(nom)
    assert 100.0 < need < 125.0       # soft spring: about max y'' omega^2 = 124 m/s^2
    m, g = nom.mass_kg, PF.GRAVITY_M_S2
    above = nom.override(preload_n=m * (need * 1.001 - g))
    below = nom.override(preload_n=m * (need * 0.999 - g))
    ra, rb = PF.evaluate(above), PF.evaluate(below)
    # above: one lost interval, at the material; below: the foot also hops off the seat
    assert ra.intervals[0] == 1 and not ra.lost_by_force[0]
    assert rb.intervals[0] > 1
    kin = PF.evaluate(PF.PresserFoot())
    assert ra.separation_mm[0] == pytest.approx(kin.separation_mm[0], abs=1e-9)
    assert ra.loss_deg[0] == pytest.approx(kin.loss_deg[0], abs=1e-9)
    # every spring of the source's table, as assumed (same mass and pressing force), follows
    # the seat: the table's springs all give the same cycle
    for k in np.asarray(PF.source_springs().stiffness_n_per_mm):
        one = PF.PresserFoot().override(stiffness_n_per_mm=float(k))
        assert PF.holding_m_s2(one) > PF.follow_threshold_m_s2(one)


def test_montecarlo_counts_add_up_and_repeat_for_the_same_seed():
    nom = PF.PresserFoot()
    a = S.montecarlo(nom, S.tolerance_sets()["assumed"], 400, 7)
    b = S.montecarlo(nom, S.tolerance_sets()["assumed"], 400, 7)
    assert a.machines.equals(b.machines)
    c = a.counts()
    assert sum(c[s] for s in PF.STATUS) == 400
    # the separation is the kinematic r + L + a - y_m for every machine that follows
    m = a.machines
    ok = (m.status == "ok") & ~m.lost_by_force
    sep = (R + m.crank_mm) + (L + m.rod_mm) + (A + m.offset_mm) - (nom.material_mm
                                                                  + m.material_mm)
    np.testing.assert_allclose(m.separation_mm[ok], sep[ok], atol=1e-9)
    # the spring family alone moves nothing
    fam = S.montecarlo(nom, S.tolerance_sets()["spring"], 200, 3)
    assert fam.summary_frame()["std"].max() < 1e-9


def test_a_machine_that_never_loses_contact_is_counted():
    nom = PF.PresserFoot()
    batch = nom.override(material_mm=np.array([61.28, 70.0, 70.0]),
                         preload_n=np.array([8.0, 8.0, 8.0]))
    res = PF.evaluate(batch)
    assert list(res.status) == ["ok", "never_lost", "never_lost"]
    assert res.counts() == {"ok": 1, "never_lost": 2, "never_held": 0, "not_regained": 0,
                            "cannot_assemble": 0}
    out = PF.presser_contact({"y": np.array([61.28, 70.0])}, crank_mm=R, rod_mm=L,
                             offset_mm=A, speed_rad_s=100.0, phase_deg=317.75,
                             material_mm="y", mass_kg=0.05, stiffness_n_per_mm=0.4466,
                             preload_n=8.0)
    assert out["separation_mm"][1] == 0.0 and out["lost_deg"][1] == 0.0
    assert np.isnan(out["loss_deg"][1]) and out["status"][1] == "never_lost"


def test_output_kind_equals_evaluate_and_refuses_bad_fields():
    nom = PF.PresserFoot()
    vals = {"r": np.array([17.5, 17.52])}
    fields = dict(crank_mm="r", rod_mm=L, offset_mm=A, speed_rad_s=100.0, phase_deg=317.75,
                  material_mm=61.2804, mass_kg=0.05, stiffness_n_per_mm=0.4466, preload_n=8.0)
    out = PF.presser_contact(vals, **fields)
    ref = PF.evaluate(nom.override(crank_mm=vals["r"]))
    np.testing.assert_allclose(out["separation_mm"], ref.separation_mm, atol=0)
    reg = PF.presser_contact_output(None, measure="lost_deg", crank_mm=np.array([[17.52]]),
                                    **{k: v for k, v in fields.items() if k != "crank_mm"})
    assert reg[0] == pytest.approx(ref.lost_deg[1], abs=1e-12)
    with pytest.raises(ParameterError, match="crank_mm: names no parameter"):
        PF.presser_contact(vals, **{**fields, "crank_mm": "rr"})
    with pytest.raises(ParameterError, match="measure: must be one of"):
        PF.presser_contact_output(None, measure="speed", **fields)


@pytest.mark.parametrize("field,value,rule", [
    ("mass_kg", -1.0, "must be a positive mass in kg"),
    ("stiffness_n_per_mm", 0.0, "must be a positive stiffness in N/mm"),
    ("damping_ratio", 1.0, "must be in [0, 1)"),
    ("crank_mm", 50.0, "must be shorter than rod_mm"),
    ("material_mm", float("nan"), "must be a finite number"),
])
def test_bad_parameters_name_the_field_the_rule_and_the_value(field, value, rule):
    with pytest.raises(ParameterError) as err:
        PF.PresserFoot().override(**{field: value})
    assert str(err.value).startswith(f"{field}: {rule}")


def test_the_mechanism_file_is_the_model():
    """mechanisms/presser_foot/mechanism.toml: its chain (built here with the engine as the file's groups
    say) moves the seat as the published formula, with the same transfer functions; its
    nominal values and tolerances are the module's."""
    import tomllib
    from pathlib import Path

    from sewtol import engine

    doc = tomllib.loads((Path(__file__).parents[1] / "examples" / "presser_foot.toml")
                        .read_text())
    par = {k: v["nominal"] for k, v in doc["parameters"].items()}
    g = {x["name"]: x for x in doc["groups"]}
    q = np.radians(np.arange(0.0, 360.0, 5.0))
    o = engine.fixed(g["O"]["x"], g["O"]["y"])
    cr = g["B"]
    ang = engine.Angle(cr["sense"] * q + math.radians(cr["phase_deg"]),
                       cr["sense"] * np.ones_like(q), np.zeros_like(q))
    b = engine.polar(o, par[cr["radius"]], ang)
    rr = g["C"]
    c, closure = engine.rrp(b, par[rr["r"]], rr["x"], rr["y"], math.radians(rr["angle_deg"]),
                            rr["branch"])
    assert np.all(closure.miss_mm == 0.0)
    d = engine.on_body(c, engine.direction(o, c), par[g["D"]["u"]] + 1j * g["D"]["v"])
    y, d1, d2 = PF.slider(q, par["r"], par["L"], par["a"])
    np.testing.assert_allclose(d.p.imag, y, atol=1e-9)
    np.testing.assert_allclose(d.p.real, 0.0, atol=1e-9)
    np.testing.assert_allclose(d.dp.imag, d1, atol=1e-9)
    np.testing.assert_allclose(d.ddp.imag, d2, atol=1e-9)
    nom = PF.PresserFoot()
    names = {"r": "crank_mm", "L": "rod_mm", "a": "offset_mm", "omega_rad_s": "speed_rad_s",
             "phase": "phase_deg", "y_m": "material_mm", "m_kg": "mass_kg",
             "k_n_per_mm": "stiffness_n_per_mm", "F_n": "preload_n", "zeta": "damping_ratio"}
    assert {names[k]: v for k, v in par.items()} == {f: getattr(nom, f) for f in names.values()}
    # the tables read the model's names off the file's presser_contact fields
    assert S.field_names() == names
    # the assumed set as documented (docs/presser_foot.md): crank +/-0.02, rod and offset
    # +/-0.05, material +/-0.1 mm; spring rate, mass and preload +/-10 % (0.4466, 0.05 kg, 8 N)
    assumed = {names[k]: v for k, v in doc["tolerances"]["assumed"].items()
               if k != "description"}
    assert assumed == {"crank_mm": 0.02, "rod_mm": 0.05, "offset_mm": 0.05, "material_mm": 0.1,
                       "stiffness_n_per_mm": 0.045, "mass_kg": 0.005, "preload_n": 0.8}
    kinds = {o["kind"] for o in doc["outputs"] if o["type"] == "custom"}
    assert kinds == {"presser_contact"}
    for out in doc["outputs"]:
        if out["type"] == "custom":
            fields = {k: v for k, v in out.items()
                      if k not in ("name", "unit", "type", "kind", "doc")}
            assert set(fields) <= set(PF.PRESSER_CONTACT_FIELDS)
            assert out["name"] == fields["measure"]


def test_invariants_over_random_machines_in_every_regime():
    rng = np.random.default_rng(20261122)
    m = 300
    base = PF.PresserFoot()
    batch = base.override(
        stiffness_n_per_mm=rng.uniform(0.005, 5.0, m), mass_kg=rng.uniform(0.02, 0.2, m),
        preload_n=rng.uniform(-1.0, 20.0, m), material_mm=rng.uniform(55.0, 70.0, m),
        crank_mm=rng.uniform(15.0, 20.0, m))
    res = PF.evaluate(batch)
    counts = res.counts()
    assert sum(counts.values()) == m and counts["ok"] > 50 and counts["never_lost"] > 0
    ok = res.status == "ok"
    assert np.all(res.separation_mm[ok] > 0) and np.all(res.intervals[ok] >= 1)
    assert np.all((res.lost_deg[ok] > 0) & (res.lost_deg[ok] < 3 * 360))
    r = np.asarray(batch.crank_mm)
    for i in np.nonzero(ok)[0]:
        phi_l = math.radians(res.loss_deg[i] - base.phase_deg)
        phi_r = math.radians(res.regain_deg[i] - base.phase_deg)
        y_m = float(np.asarray(batch.material_mm)[i])
        nu, x_eq = float(np.asarray(batch.nu)[i]), float(np.asarray(batch.x_eq_mm)[i])
        y_l = PF.slider(phi_l, r[i], L, A)[0]
        if res.lost_by_force[i]:      # the push is zero where the foot leaves the seat
            assert K.contact_force(phi_l, r[i], L, A, nu, 0.012, x_eq) == pytest.approx(
                0.0, abs=1e-6)
        else:                         # or the seat passes the material level
            assert y_l == pytest.approx(y_m, abs=1e-9)
        # contact returns above (or at) the material, and the push then holds
        assert PF.slider(phi_r, r[i], L, A)[0] <= y_m + 1e-9
        assert K.contact_force(phi_r, r[i], L, A, nu, 0.012, x_eq) >= 0.0
        if res.landed[i] and not res.lost_by_force[i] and res.intervals[i] == 1:
            assert res.separation_mm[i] == pytest.approx(r[i] + L + A - y_m, abs=1e-9)
