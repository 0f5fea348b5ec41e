"""Every script in benchmarks/ imports and parses its flags (`--help`, exit 0): a refactor that
moves a function must not leave `make bench` or `make validate` broken. Nothing is timed here;
speed is measured by the scripts themselves."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))


def test_there_are_benchmark_scripts():
    assert {p.name for p in SCRIPTS} >= {"throughput.py", "studies.py", "rare_event.py",
                                         "validate_adjust.py", "validate_generic_adjuster.py"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_benchmark_script_imports_and_parses_its_flags(script):
    done = subprocess.run([sys.executable, str(script), "--help"], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage:" in done.stdout
