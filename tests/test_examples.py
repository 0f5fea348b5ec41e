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


def test_the_api_worked_example_prints_what_the_page_shows(capsys, monkeypatch):
    """docs/api/protocol.md's worked example (a user's own mechanism, examples/four_bar.toml)
    runs as written from the repository's root and prints every line the page shows; the page's
    TOML is the file itself (a snippet), and the command line's counts for the same seed are
    the Monte-Carlo's and the strategies row `none`'s (one sampler)."""
    from cli_helpers import run, strict_loads

    page = (ROOT / "docs" / "api" / "protocol.md").read_text()
    example = page.split("## A worked example: your own mechanism")[1].split("\n## ")[0]
    assert '```toml\n--8<-- "examples/four_bar.toml"\n```' in example
    code = re.search(r"```python\n(.*?)```", example, re.S).group(1)
    shown = re.search(r"```text\n(.*?)```", example, re.S).group(1)
    monkeypatch.chdir(ROOT)
    exec(compile(code, "docs/api/protocol.md", "exec"), {})
    printed = [" ".join(line.split()) for line in capsys.readouterr().out.splitlines()]
    assert printed == [" ".join(line.split()) for line in shown.strip().splitlines()]
    # the command line the page quotes: same machines, same counts
    code_mc, out, err = run("run", "examples/four_bar.toml", "montecarlo", "--n", "1000",
                            "--seed", "7", "--format", "json")
    assert code_mc == 0, err
    counts = strict_loads(out)["counts"]["fixed"]
    assert (counts["ok"], counts["out_of_spec"], counts["failed"]) == (996, 4, 0)
    assert "# ok 996, out_of_spec 4" in example
    code_st, out, err = run("run", "examples/four_bar.toml", "strategies", "--n", "1000",
                            "--seed", "7", "--format", "json")
    assert code_st == 0, err
    none = next(r for r in strict_loads(out)["rows"] if r["strategy"] == "none")
    assert (none["ok"], none["out_of_spec"]) == (996, 4)
