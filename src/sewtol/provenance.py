"""Provenance of a run: what made a table (version, revision, command, inputs, seed, times)."""

from __future__ import annotations

import datetime as dt
import platform
import subprocess
import sys
from pathlib import Path

from . import __version__


def git_revision() -> str:
    """The checkout's commit (with '+dirty' when it has changes), or 'unknown' outside git."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                             text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def run_record(started: str, inputs: dict, argv: list[str] | None = None) -> dict:
    """The run.json record; `inputs` holds every parameter, tolerance set and seed used."""
    from importlib.metadata import PackageNotFoundError, version

    def ver(name):
        try:
            return version(name)
        except PackageNotFoundError:
            return "not installed"

    return {
        "sewtol_version": __version__,
        "git_revision": git_revision(),
        "command_line": list(sys.argv if argv is None else argv),
        "started_utc": started,
        "finished_utc": now(),
        "python": platform.python_version(),
        "libraries": {name: ver(name) for name in
                      ("numpy", "scipy", "pandas", "SALib", "joblib", "numba", "matplotlib")},
        "inputs": inputs,
    }
