"""`sewtol run FILE STUDY --adjust C --objective target=T|centre=L,U` (scan, worst-case,
montecarlo, ppm, allocation, strategies, settings): the adjusted
case brought to a target (an eccentric pivot setting a rocker's swing back) or centred, not
only minimised, through the generic adjuster (sewtol.adjuster); refused in one line where it
means nothing."""

from __future__ import annotations

import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file

ROCKER = "spatial_crank_rocker"
# the adjuster stops where no cell of its search can lower |swing - T| by more than its tol,
# 1e-6 deg; the largest miss measured on these rows is 1.1e-6 deg
REACHED_DEG = 1e-5


def _built_c(row) -> float:
    """The rocker's c as built on a scan row: the slot's setting is an offset from it."""
    c = load(mechanism_file(ROCKER)).nominal_values()["c"]
    return c + (row["deviation"] if row["param"] == "c" else 0.0)


def _scan(*flags):
    code, out, err = run("run", ROCKER, "scan", "--output", "rocker_swing_deg", "--adjust",
                         "rocker_arm", *flags, "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    rows = obj["rows"]
    return obj, [r for r in rows if r["output"].endswith("_adjusted")], \
        [r for r in rows if not r["output"].endswith("_adjusted")]


def test_a_target_brings_every_scanned_machine_back_to_it_inside_the_box():
    """The rocker's slot (c +-1 mm) sets the swing back to 50.73 deg on every machine of the
    scan (each tolerance at its limits, 0.11 deg off at most as built); the rows as built are
    those of the scan without an objective, and the setting stays inside the box."""
    obj, adjusted, built = _scan("--objective", "target=50.73")
    _, minimised, built_min = _scan()
    assert built == built_min and len(adjusted) == 14
    assert max(abs(r["value"] - 50.73) for r in adjusted) < REACHED_DEG
    assert max(abs(r["value"] - 50.7292529) for r in built) > 0.1  # the scan moved it
    c = [_built_c(r) for r in adjusted]
    assert all(x - 1 < r["setting"] < x + 1 for x, r in zip(c, adjusted, strict=True))
    # minimised instead, the slot runs to its end and the swing lands elsewhere
    assert all(abs(r["setting"] - x - 1) < 1e-12 for x, r in zip(c, minimised, strict=True))
    assert min(abs(r["value"] - 50.73) for r in minimised) > 1.0
    assert obj["context"]["objective"] == "target=50.73" and obj["context"]["path"] == "generic"


def test_a_target_beyond_reach_stops_at_the_bound_and_says_so():
    """60 deg is beyond the slot: every setting sits on the end that raises the swing most,
    and the swing stays short of 60 (the loss is reported, not hidden)."""
    _, adjusted, _ = _scan("--objective", "target=60")
    assert all(abs(r["setting"] - _built_c(r) + 1) < 1e-12 for r in adjusted)
    assert all(50.7 < r["value"] < 60.0 for r in adjusted)


def test_centre_and_worst_case_take_it_too(tmp_path):
    """Centred in [50.5, 51.0] deg: the worst case over a two-part box after adjustment stays
    at the centre 50.75 deg (reached on every corner), where the fixed case spans +-0.18."""
    path = tmp_path / "t.toml"
    path.write_text("[sets.two]\na = 0.02\nc = 0.03\n")
    code, out, err = run("run", ROCKER, "worst-case", "--output", "rocker_swing_deg",
                         "--adjust", "rocker_arm", "--objective", "centre=50.5,51.0",
                         "--tolerances", f"{path}:two", "--format", "json")
    assert code == 0, err
    rows = strict_loads(out)["rows"]
    assert [r["extreme"] for r in rows] == ["max", "min"]
    assert all(abs(r["value"] - 50.75) < REACHED_DEG for r in rows)


@pytest.mark.parametrize("argv,rule", [
    ((ROCKER, "scan", "--objective", "target=60"), "needs --adjust"),
    ((ROCKER, "scan", "--adjust", "rocker_arm", "--objective", "target=x"),
     "must be minimise, target=T or centre=L,U (got 'target=x')"),
    ((ROCKER, "scan", "--adjust", "rocker_arm", "--objective", "centre=3"),
     "must be minimise, target=T or centre=L,U"),
    ((ROCKER, "sobol", "--objective", "target=50"), "is not used by `run sobol`"),
    ((ROCKER, "montecarlo", "--objective", "target=50"), "needs --adjust"),
    ((ROCKER, "ppm", "--adjust", "rocker_arm", "--objective", "target=x"),
     "must be minimise, target=T or centre=L,U (got 'target=x')"),
    ((ROCKER, "strategies", "--objective", "centre=1"),
     "must be minimise, target=T or centre=L,U (got 'centre=1')"),
    (("feed_131", "montecarlo", "--adjust", "b", "--objective", "tgt=2"),
     "must be minimise, target=T or centre=L,U (got 'tgt=2')"),
])
def test_bad_objectives_are_one_line_naming_the_flag(argv, rule):
    code, out, err = run("run", *argv)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert err.startswith(f"sewtol: error: --objective: {rule}"), err


def test_the_needle_file_leaves_its_fast_path_for_another_objective():
    code, out, err = run("run", "needle_208", "scan", "--adjust", "beta", "--output",
                         "SumDelta_um", "--objective", "centre=2,6", "--format", "json")
    assert code == 0, err
    ctx = strict_loads(out)["context"]
    assert ctx["path"] == "generic"
    assert ctx["path_reason"] == "--objective centre=2,6: the needle commands minimise SumDelta"


SWING = ("--output", "rocker_swing_deg")
# a two-sided spec around the nominal swing (50.729 deg): minimised, the slot runs to its end
# and every machine leaves it; brought to 50.73, every machine stays
SPEC = ("--limit", "50.9", "--lower-limit", "50.6")


def test_montecarlo_brings_every_machine_to_the_target_as_the_library_does():
    """The same seed through the CLI and sewtol.studies.montecarlo(objective=...): the same
    machines, every adjusted swing at the target, counts adding up to n in both cases."""
    from sewtol.studies.montecarlo import montecarlo

    n, seed, goal = 40, 3, "target=50.73"
    code, out, err = run("run", ROCKER, "montecarlo", *SWING, *SPEC, "--adjust", "rocker_arm",
                         "--objective", goal, "--n", str(n), "--seed", str(seed),
                         "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    mech = load(mechanism_file(ROCKER))
    res = montecarlo(mech, mech.tolerance_sets["illustrative"], n, seed, ["rocker_swing_deg"],
                     50.9, "rocker_swing_deg", adjust="rocker_arm", lower_limit=50.6,
                     objective=goal)
    ref = res.to_dict()
    assert obj["counts"] == ref["counts"] and obj["quantiles"] == ref["quantiles"]
    for case, k in obj["counts"].items():
        assert k["ok"] + k["out_of_spec"] + k["failed"] == k["n"] == n, case
    swing = res.machines["rocker_swing_deg_adjusted"].to_numpy()
    assert len(swing) == n and max(abs(swing - 50.73)) < REACHED_DEG
    assert obj["counts"]["adjusted_rocker_arm"]["ok"] == n
    assert obj["context"]["objective"] == goal
    # minimised instead (the same machines as built), none is near the target
    minimised = montecarlo(mech, mech.tolerance_sets["illustrative"], n, seed,
                           ["rocker_swing_deg"], adjust="rocker_arm")
    assert (minimised.machines["rocker_swing_deg"] == res.machines["rocker_swing_deg"]).all()
    assert min(abs(minimised.machines["rocker_swing_deg_adjusted"] - 50.73)) > 1.0


def test_ppm_strategies_settings_and_allocation_take_the_objective():
    """ppm: 0 of 100 machines fail when the slot brings the swing to 50.73, all 100 when it
    minimises it; strategies and settings: every machine of the row at the target."""
    base = ("run", ROCKER, "ppm", *SWING, *SPEC, "--adjust", "rocker_arm", "--n", "100",
            "--method", "mc", "--target", "0.05", "--format", "json")
    reached, minimised = (strict_loads(run(*base, *extra)[1]) for extra in
                          (("--objective", "target=50.73"), ()))
    assert reached["failures"] == 0 and minimised["failures"] == 100
    assert reached["context"]["objective"] == "target=50.73"
    code, out, err = run("run", ROCKER, "strategies", *SWING, *SPEC, "--strategy",
                         "slot=rocker_arm", "--n", "20", "--objective", "target=50.73",
                         "--format", "json")
    assert code == 0, err
    (row,) = strict_loads(out)["rows"]
    assert row["ok"] + row["out_of_spec"] + row["failed"] == row["n"] == 20 == row["ok"]
    assert abs(row["p50"] - 50.73) < REACHED_DEG and abs(row["p99"] - 50.73) < REACHED_DEG
    code, out, err = run("run", ROCKER, "settings", "--set", "longer:c=25.02", *SWING, *SPEC,
                         "--adjust", "rocker_arm", "--n", "20", "--objective", "target=50.73",
                         "--format", "json")
    assert code == 0, err
    (row,) = strict_loads(out)["rows"]
    assert row["ok_adjusted"] == row["n"] == 20 and abs(row["p95_adjusted"] - 50.73) < REACHED_DEG
    code, out, err = run("run", ROCKER, "allocation", *SWING, *SPEC, "--adjust", "rocker_arm",
                         "--n", "20", "--objective", "target=50.73", "--format", "json")
    assert code == 0, err
    assert strict_loads(out)["context"]["objective"] == "target=50.73"
