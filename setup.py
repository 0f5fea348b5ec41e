"""Records the git revision at install time in src/sewtol/_revision.py (never at run time).

At run time sewtol reads only that file: no git process runs, so no repository's hooks or
fsmonitor are executed, and a checkout made while a study runs cannot change its record.
"""

import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
SAFE_GIT = ["git", "-c", "core.fsmonitor=false", "-c", "core.hooksPath=/dev/null"]


def _git(*args) -> str:
    return subprocess.run(SAFE_GIT + list(args), cwd=ROOT, capture_output=True, text=True,
                          timeout=20, check=True).stdout.strip()


def revision() -> str:
    try:
        # only this source tree's own repository counts, not one that happens to enclose it
        if Path(_git("rev-parse", "--show-toplevel")).resolve() != ROOT:
            return "unknown"
        rev = _git("rev-parse", "HEAD")
        dirty = _git("status", "--porcelain", "--untracked-files=no")
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def write_revision(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "_revision.py").write_text(
        '"""Written by setup.py at install time; do not edit."""\n\n'
        f"REVISION = {revision()!r}\n")


class BuildPyWithRevision(build_py):
    def run(self):
        write_revision(ROOT / "src" / "sewtol")
        super().run()
        if not getattr(self, "editable_mode", False):
            write_revision(Path(self.build_lib) / "sewtol")


setup(cmdclass={"build_py": BuildPyWithRevision})
