"""`sewtol needle largest-tolerances`: the API's table on the command line, with its context."""

from __future__ import annotations

import json

import numpy as np

from cli_helpers import run
from sewtol import Needle208
from sewtol.tables.needle_208 import largest_tolerances


def test_largest_tolerances_command_prints_the_api_table_with_its_context():
    code, out, err = run("needle", "largest-tolerances", "--params", "AB,CD", "--format", "json")
    assert code == 0, err
    obj = json.loads(out, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    api = largest_tolerances(Needle208.nominal(), ["AB", "CD"])
    got = [r["largest_delta_mm"] for r in obj["rows"]]
    np.testing.assert_allclose(got, api["largest_delta_mm"], rtol=0, atol=1e-12)
    # the tightest side of CD and AB as the report quotes them (+/-0.0066, +/-0.0074 mm)
    assert round(abs(api["largest_delta_mm"]).min(), 4) == 0.0066
    assert obj["context"]["frame"] == "sewtol-0.1" and obj["limit_um"] == 10.0


def test_largest_tolerances_command_refuses_bad_flags_in_one_line():
    for argv, needle in ((["--params", "AB,XX"], "--params"), (["--params", "beta"], "--params"),
                         (["--max-mm", "-1"], "--max-mm"),
                         (["--beta-range", "30", "20"], "--beta-range")):
        code, out, err = run("needle", "largest-tolerances", *argv)
        assert code == 2 and out == "" and err.count("\n") == 1 and needle in err, (argv, err)
