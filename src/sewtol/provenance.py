"""Provenance of a run: what made a table (version, revision, command, inputs, seed, times)."""

from __future__ import annotations

import datetime as dt
import platform
import sys
from pathlib import Path

from sewtol import __version__


def git_revision() -> str:
    """The commit sewtol was installed from ('+dirty' with uncommitted changes), recorded by
    setup.py at install time; 'unknown' when none was recorded. No git process runs here (a
    repository's hooks or fsmonitor would run with it), and a checkout made while a study runs
    does not change what it records."""
    try:
        from sewtol._revision import REVISION
    except ImportError:
        return "unknown (not recorded at install)"
    return str(REVISION)


def version_record() -> dict:
    """What identifies the code: bound into every study manifest and run.json."""
    return {"sewtol_version": __version__, "git_revision": git_revision()}


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def portable_command(argv: list[str]) -> list[str]:
    """The command line as a user would type it again on any machine: `python -m sewtol` for
    sewtol's __main__.py, `sewtol` for its console script, a script under the working folder
    relative to it (an absolute path of this machine's checkout would differ on every other)."""
    argv = [str(a) for a in argv]
    if not argv:
        return argv
    first = Path(argv[0])
    if first.name == "__main__.py" and first.parent.name == "sewtol":
        return ["python", "-m", "sewtol", *argv[1:]]
    if first.name == "sewtol":
        return ["sewtol", *argv[1:]]
    if first.is_absolute():
        try:
            return [str(first.relative_to(Path.cwd())), *argv[1:]]
        except ValueError:
            pass
    return argv


def run_record(started: str, inputs: dict, argv: list[str] | None = None,
               runs: list | None = None) -> dict:
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
        "command_line": portable_command(sys.argv if argv is None else argv),
        "started_utc": started,
        "finished_utc": now(),
        "python": platform.python_version(),
        "libraries": {name: ver(name) for name in
                      ("numpy", "scipy", "pandas", "SALib", "joblib", "numba", "matplotlib")},
        "inputs": inputs,
        **({"runs": runs} if runs is not None else {}),
    }
