"""Joint clearances as further variables of the one study stack: the journal's polar offset
(r2 = |r|^2 uniform: a journal uniform over its disc; phi uniform) is the model's Cartesian
offset, the Monte-Carlo draws it where it belongs, and Sobol gives the analytic indices of a
crank pin's abscissa under a link tolerance and two pin clearances."""

import numpy as np
import pytest

from sewtol.errors import ParameterError
from sewtol.studies import clearance as K
from sewtol.studies import montecarlo as MC
from sewtol.studies.sobol import sobol
from sewtol.tolerances import Tolerance, ToleranceSet
from test_clearance_model import RADII, four_bar

LINKS = ToleranceSet("crank", (Tolerance("a", -0.02, 0.02),))


def test_the_polar_offset_is_the_cartesian_one():
    mech = four_bar()
    varied, ts = K.clearance_variables(mech, LINKS, "disc")
    rng = np.random.default_rng(5)
    polar, cart = {}, {}
    for j, c in RADII.items():
        r2, phi = rng.uniform(0, c * c, 7), rng.uniform(0, 360, 7)
        polar[f"{j}_r2_mm2"], polar[f"{j}_phi_deg"] = r2, phi
        cart[f"{j}_dx_mm"] = np.sqrt(r2) * np.cos(np.radians(phi))
        cart[f"{j}_dy_mm"] = np.sqrt(r2) * np.sin(np.radians(phi))
    a, b = varied.evaluate(polar), mech.evaluate(cart)
    for k in b.outputs:
        np.testing.assert_allclose(a.outputs[k], b.outputs[k], rtol=0, atol=1e-12)
    # at the nominal (r2 = 0) the copy is the file, bit for bit
    for k, v in mech.evaluate().outputs.items():
        np.testing.assert_array_equal(varied.evaluate().outputs[k], v)
    assert ts.name == "crank+clearances" and [t.param for t in ts.items][:3] == [
        "a", "O_r2_mm2", "O_phi_deg"]
    assert varied.header.fast_path is None


def test_montecarlo_draws_the_journals_in_their_discs_and_on_their_rims():
    mech = four_bar()
    varied, ts = K.clearance_variables(mech, LINKS, "disc")
    res = MC.montecarlo(varied, ts, 4000, 3, outputs=["L_x_mm"])
    again = MC.montecarlo(varied, ts, 4000, 3, outputs=["L_x_mm"])
    assert res.machines.equals(again.machines)
    m = res.machines
    for j, c in RADII.items():
        r = np.sqrt(m[f"{j}_r2_mm2"] + 0.0)
        assert r.max() <= c and r.min() >= 0
        # uniform over the disc: P(r <= c/2) = 1/4 (4 standard errors of 4000 draws: 0.027)
        assert abs(np.mean(r <= c / 2) - 0.25) < 0.027
    # the output is the real model's: L_x = max_q x of the crank pin = a + r_O,x + r_L,x
    expect = 10.0 + m["a"] + sum(np.sqrt(m[f"{j}_r2_mm2"]) * np.cos(np.radians(
        m[f"{j}_phi_deg"])) for j in "OL")
    np.testing.assert_allclose(m["L_x_mm"], expect, rtol=0, atol=1e-12)
    rim, ts_rim = K.clearance_variables(mech, LINKS, "rim")
    assert [t.param for t in ts_rim.items] == ["a"] + [f"{j}_phi_deg" for j in RADII]
    m = MC.montecarlo(rim, ts_rim, 200, 3, outputs=["L_x_mm"]).machines
    expect = 10.0 + m["a"] + sum(RADII[j] * np.cos(np.radians(m[f"{j}_phi_deg"]))
                                 for j in "OL")
    np.testing.assert_allclose(m["L_x_mm"], expect, rtol=0, atol=1e-12)


def test_sobol_gives_the_analytic_indices_of_a_pin_and_a_link():
    # Y = a + r_O cos phi_O + r_L cos phi_L, r^2 uniform in [0, c^2], phi uniform:
    # Var(a) = t^2 / 3; per pair Var = E[r^2] / 2 = c^2 / 4, of which E[r]^2 / 2 = 2 c^2 / 9
    # is phi's alone (E[r] = 2c / 3) and Var(r) / 2 = c^2 / 36 r2's total; r2 alone: 0
    mech = four_bar()
    radii = {"O": 0.01, "L": 0.02}
    varied, ts = K.clearance_variables(mech, LINKS, "disc")  # the pins at M, D do not move L
    res = sobol(varied, ts, "L_x_mm", 2048, 11, fast=False)
    f = res.to_dataframe().set_index("param")
    var = 0.02 ** 2 / 3 + sum(c * c / 4 for c in radii.values())
    exact = {("a", "S1"): 0.02 ** 2 / 3 / var, ("a", "ST"): 0.02 ** 2 / 3 / var}
    for j, c in radii.items():
        exact[(f"{j}_phi_deg", "S1")] = 2 * c * c / 9 / var
        exact[(f"{j}_phi_deg", "ST")] = c * c / 4 / var
        exact[(f"{j}_r2_mm2", "S1")] = 0.0
        exact[(f"{j}_r2_mm2", "ST")] = c * c / 36 / var
    for j in "MD":
        for k in ("S1", "ST"):
            exact[(f"{j}_phi_deg", k)] = exact[(f"{j}_r2_mm2", k)] = 0.0
    for (param, k), v in exact.items():
        got, conf = f.loc[param, k], f.loc[param, f"{k}_conf"]
        # within three bootstrap half-widths (95 %) plus the estimator's floor at N = 2048
        assert abs(got - v) <= 3 * conf + 2e-3, (param, k, got, v, conf)


def test_clearance_variables_refuse_in_one_line():
    mech = four_bar()
    with pytest.raises(ParameterError, match="clearances.*disc, rim.*'ring'"):
        K.clearance_variables(mech, LINKS, "ring")
    with pytest.raises(ParameterError, match="declares no revolute"):
        from sewtol.mechanism import loads
        from test_clearance_model import FOUR_BAR
        K.clearance_variables(loads(FOUR_BAR, "f.toml"), LINKS, "disc")


def test_sobol_share_sums_the_indices_by_source_and_pair():
    mech = four_bar()
    share = K.sobol_share(mech, LINKS, "L_x_mm", 256, 11)
    f = share.indices
    assert set(f["source"]) == {"link", "pin"} and len(f) == 1 + 2 * len(RADII)
    for source, k in ((s, k) for s in ("link", "pin") for k in ("S1", "ST")):
        assert share.sources.set_index("source").loc[source, k] == pytest.approx(
            f.loc[f["source"] == source, k].sum(), abs=1e-15)
    by = share.by_pair.set_index("pair")
    assert by.loc["O", "ST"] == pytest.approx(f.loc[f["pair"] == "O", "ST"].sum(), abs=1e-15)
    # the pins at M and D do not move the crank pin: their indices vanish (to SALib's noise)
    assert abs(by.loc["M", "ST"]) < 1e-12 and abs(by.loc["D", "ST"]) < 1e-12


def test_run_sobol_with_clearances_and_the_studies_that_refuse_the_flag(tmp_path):
    from cli_helpers import run, strict_loads
    from test_clearance_model import CLEARANCES, FOUR_BAR

    f = tmp_path / "four_bar.toml"
    f.write_text(FOUR_BAR + '\n[tolerances.crank]\na = 0.02\n' + CLEARANCES)
    code, out, err = run("run", str(f), "sobol", "--output", "L_x_mm", "--n", "16",
                         "--seed", "3", "--clearances", "disc", "--format", "json")
    assert code == 0, err
    rows = {r["param"] for r in strict_loads(out)["rows"]}
    assert rows == {"a"} | {f"{j}_{k}" for j in RADII for k in ("r2_mm2", "phi_deg")}
    code, out, err = run("run", str(f), "scan", "--clearances", "disc")
    assert code == 2 and err.count("\n") == 1 and "--clearances" in err and "scan" in err, err
