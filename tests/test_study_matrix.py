"""Every study runs on every built-in mechanism by name (`sewtol run NAME STUDY`): exit 0, strict
JSON, the same shape whatever the mechanism, and counts that add up to n."""

from __future__ import annotations

import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanism import load
from sewtol.mechanisms import mechanism_file, names
from sewtol.protocol import plugins
from sewtol.studies.strategies import STATUSES

# small sizes: this holds that each study runs and answers in its shape, not its numbers
ARGS = {"nominal": [], "scan": [], "worst-case": [],
        "montecarlo": ["--n", "40", "--seed", "1"], "sobol": ["--n", "16", "--seed", "1"],
        "ppm": ["--n", "400", "--method", "mc", "--seed", "1"],
        "allocation": ["--n", "40", "--seed", "1"], "strategies": ["--n", "20", "--seed", "1"],
        "shapley": ["--n", "4", "--seed", "1"], "largest-tolerances": []}
NEEDS_LIMIT = ("ppm", "allocation", "largest-tolerances")


def _limit(name: str) -> list[str]:
    """A mechanism without a spec gets an upper limit on its first output: the nominal value
    plus 1 % (so some machines fail and some pass)."""
    mech = load(mechanism_file(name))
    if mech.specs:
        return []
    out = mech.output_names[0]
    y = float(mech.evaluate().outputs[out][0])
    return ["--output", out, "--limit", repr(y + 0.01 * abs(y) + 1e-9)]


@pytest.mark.parametrize("study", list(ARGS))
@pytest.mark.parametrize("name", names())
def test_every_study_runs_on_every_built_in(name, study):
    argv = ["run", name, study, *ARGS[study], "--format", "json"]
    if study in NEEDS_LIMIT:
        argv += _limit(name)
    code, out, err = run(*argv)
    assert code == 0, err
    obj = strict_loads(out)
    assert isinstance(obj, dict) and "context" in obj
    assert obj["context"]["mechanism"] == name
    if study == "montecarlo":
        for case, c in obj["counts"].items():
            assert c["ok"] + c["out_of_spec"] + c["failed"] == c["n"] == 40, (case, c)
    if study == "shapley":
        assert [r["param"] for r in obj["rows"]] == list(load(mechanism_file(name)).tolerance_sets
                                                         [obj["tolerances"]].active().params)
    if study == "largest-tolerances":
        assert len(obj["rows"]) == 2 * len(load(mechanism_file(name)).tolerance_sets
                                           [obj["tolerances"]].active().params)
    if study == "strategies":  # the counts in the mechanism's words (the needle's: its own)
        words = plugins(load(mechanism_file(name))).columns.get("strategies", {})
        for row in obj["rows"]:
            assert sum(row[words.get(k, k)] for k in STATUSES) == row["n"] == 20, row


def test_settings_compares_named_settings_on_every_built_in():
    for name in names():
        mech = load(mechanism_file(name))
        p = next(p for p in mech.parameters if p.rule == "positive")
        code, out, err = run("run", name, "settings", "--set", f"as_drawn:{p.name}={p.nominal}",
                             "--set", f"longer:{p.name}={p.nominal * 1.001}", "--format", "json")
        assert code == 0, (name, err)
        rows = strict_loads(out)["rows"]
        assert [r["setting"] for r in rows] == ["as_drawn", "longer"]
