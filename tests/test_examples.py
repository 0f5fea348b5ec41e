"""The example study scripts run as a user runs them (small n), and what they print holds up."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_designer_study_runs_and_adding_a_compensator_never_lowers_the_yield():
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "designer_study.py"),
                          "--n", "60", "--n-sobol", "16", "--seed", "3"],
                         check=True, capture_output=True, text=True).stdout
    for heading in ("## (1)", "## (2)", "## (3)", "## (4)"):
        assert heading in out
    rows = dict(re.findall(r"^\| (\S+)\s+\|\s+([0-9.]+) \|", out.split("## (4)")[1], re.M))
    yields = {k: float(v) for k, v in rows.items()}
    assert yields["beta"] <= yields["beta+shift"] <= yields["beta+shift+angle"] <= yields["all"]
    assert yields["beta"] <= yields["beta+CD"] <= yields["all"]
