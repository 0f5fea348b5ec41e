"""The clearance studies on the 208 needle with H7/g6 pins: the worst case reached by the real
model, the guide criterion's counts and its needed gap against the file's own output, the
share's machines against the Monte-Carlo's."""

from pathlib import Path

import numpy as np
import pytest

from sewtol.errors import ParameterError
from sewtol.mechanism import loads
from sewtol.studies import clearance as K
from sewtol.studies.montecarlo import montecarlo

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PINS = "".join(f'\n[[clearances]]\njoint = "{j}"\nfit = "H7/g6"\ndiameter_mm = 8\n'
               for j in "FLMABCD")
MAX_ABS = """
[[outputs]]
name = "max_abs_um"
unit = "um"
type = "line_deviation"
point = "E"
x = "guide_x"
y = "guide_y"
angle_deg = "guide_angle"
shift_um = "guide_shift_um"
measure = "max_abs"
"""


def needle(extra=""):
    return loads((EXAMPLES / "needle_208.toml").read_text() + extra + PINS, "needle.toml")


def test_the_worst_case_offsets_reach_w_in_the_real_model():
    mech = needle()
    wc = K.worst_case(mech, {"AB": [10.0, 10.02]}, "SumDelta_um")
    # H7/g6 at 8 mm: 5 to 29 um diametral, so 14.5 um radial at most
    assert wc.radius_mm == dict.fromkeys("FLMABCD", 0.0145)
    for k in (0, 200, 500):  # three crank angles
        values = {"AB": np.array([10.0, 10.02])}
        for j, r in wc.argmax_mm.items():
            values[f"{j}_dx_mm"], values[f"{j}_dy_mm"] = r[:, k].real, r[:, k].imag
        moved = K.signal(mech, mech.state(values), "SumDelta_um")[:, k]
        base = K.signal(mech, mech.state({"AB": [10.0, 10.02]}), "SumDelta_um")[:, k]
        # second order in c/l (14.5 um on 10 mm links): well inside 1 %
        np.testing.assert_allclose(moved - base, wc.total[:, k], rtol=1e-2)
    # the first loop's pins (F, L, M) only turn the rocker, along which E hardly leaves its
    # line; C and D are the two ends of a binary link: equal weight
    np.testing.assert_allclose(wc.by_pair["F"], wc.by_pair["M"], rtol=1e-6)
    np.testing.assert_allclose(wc.by_pair["C"], wc.by_pair["D"], rtol=1e-6)
    assert np.all(wc.by_pair["F"] < 0.01 * wc.by_pair["A"])


def test_guide_criterion_counts_and_needed_gap():
    mech = needle(MAX_ABS)
    g = K.guide_criterion(mech, "recommended", 40, 5, adjust=())
    ok = g.machines["status"] == "ok"
    ev = mech.evaluate(K.machines_of(mech, "recommended", 40, 5), ["max_abs_um"])
    # with ideal pins the gap is twice the largest distance from the guide, the file's output
    np.testing.assert_allclose(g.machines["needed_gap_ideal_pins_um"][ok],
                               2 * ev.outputs["max_abs_um"][ok], rtol=1e-12)
    assert np.all(g.machines["needed_gap_um"][ok] <= g.machines["needed_gap_ideal_pins_um"][ok])
    for row in g.fits.itertuples():
        assert row.runs + row.binds + row.failed == 40
        assert row.good <= min(row.runs, row.play_ok)
        assert 0 <= row.play_median_um <= row.gap_max_um
    assert list(g.fits["gap_max_um"]) == sorted(g.fits["gap_max_um"])
    assert (g.fits.loc[g.fits.fit == "H7/g6", ["gap_min_um", "gap_max_um"]].values.tolist()
            == [[5.0, 29.0]])
    again = K.guide_criterion(mech, "recommended", 40, 5, adjust=())
    assert again.machines.equals(g.machines)
    with pytest.raises(ParameterError, match="must be a line_deviation output"):
        K.guide_criterion(mech, "recommended", 4, 5, output="E_y_range_mm", adjust=())
    with pytest.raises(ParameterError, match="must be a clearance fit"):
        K.guide_criterion(mech, "recommended", 4, 5, adjust=(), fits=("H7/p6",))


def test_share_links_case_is_the_montecarlos_machines():
    mech = needle()
    s = K.clearance_share(mech, "base", 12, 3, adjust=())
    mc = montecarlo(mech, mech.tolerance_sets["base"], 12, 3, outputs=["SumDelta_um"])
    y = mc.machines["SumDelta_um"].to_numpy()
    links = s.cases.set_index("case").loc["links"]
    assert links["mean"] == pytest.approx(np.mean(y), rel=1e-12)
    assert links["variance"] == pytest.approx(np.var(y, ddof=1), rel=1e-12)
    assert s.cases.set_index("case").loc["both", "variance_share"] == 1.0
    again = K.clearance_share(mech, "base", 12, 3, adjust=())
    assert again.cases.equals(s.cases)
    w = s.worst.set_index(["source", "name"])["share"]
    assert w[("links", "sum")] + w[("pins", "sum")] == pytest.approx(1.0)


def test_run_clearance_on_a_file_and_its_one_line_refusals(tmp_path):
    from cli_helpers import run, strict_loads

    f = tmp_path / "needle_pins.toml"
    f.write_text((EXAMPLES / "needle_208.toml").read_text() + PINS)
    code, out, err = run("run", str(f), "clearance", "--n", "4", "--seed", "2",
                         "--tolerances", "base", "--guide-fit", "H7/g6", "--guide-fit", "H8/e8",
                         "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert [r["case"] for r in obj["share"]] == ["links", "pins", "both"]
    assert [r["fit"] for r in obj["guide"]["fits"]] == ["H7/g6", "H8/e8"]
    for r in obj["guide"]["fits"]:
        assert r["runs"] + r["binds"] + r["failed"] == 4
    # the links case is the Monte-Carlo's machines, through the CLI too
    direct = K.clearance_share(needle(), "base", 4, 2, adjust=())
    assert obj["share"][0]["mean"] == pytest.approx(direct.cases["mean"][0], rel=1e-12)
    for argv, line in [
        (("run", "needle_208", "clearance", "--n", "3"),
         "clearances: the mechanism file declares no revolute [[clearances]]"),
        (("run", str(f), "clearance", "--guide-fit", "H7/p6"),
         "--guide-fit: must be a clearance fit"),
        (("run", str(f), "clearance", "--guide-diameter", "600"), "--guide-diameter:"),
        (("run", str(f), "clearance", "--play-limit", "-1"), "--play-limit: must be positive"),
        (("run", str(f), "clearance", "--adjust", "gamma"), "--adjust: must name a compensator"),
        (("run", str(f), "montecarlo", "--play-limit", "3"),
         "--play-limit: is not used by `run montecarlo`"),
    ]:
        code, out, err = run(*argv)
        assert code == 2 and line in err and err.count("\n") == 1, (argv, err)


def test_adjustment_sees_the_journals():
    """The needle's plug-in adjuster knows the links only: with journals off centre the
    generic adjuster must run, and its optimum is the real model's at the setting it found."""
    mech = needle()
    values = {"AB": np.array([10.0, 10.01]), "A_dx_mm": np.array([0.0145, 0.0]),
              "B_dy_mm": np.array([0.0, -0.0145])}
    links = {"AB": values["AB"]}
    got, y, status = K.adjusted_machines(mech, values, ("beta",), "SumDelta_um")
    _, y0, _ = K.adjusted_machines(mech, links, ("beta",), "SumDelta_um")
    assert list(status) == ["ok", "ok"]
    assert np.all(np.abs(y - y0) > 0.1)  # the journals moved the optimum
    again = mech.evaluate(got, ["SumDelta_um"]).outputs["SumDelta_um"]
    np.testing.assert_allclose(again, y, rtol=1e-9)
