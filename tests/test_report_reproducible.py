"""Reports agree across machines to their printed precision.

The nominal report is regenerated from scratch and compared number by number with the committed
one. Under `make test-narrowed` this runs with another OpenBLAS kernel set, numpy's SIMD dispatch
narrowed and numba compiled for a generic CPU, i.e. as on another machine. A printed number may
differ by one unit in its last place only (a value sitting on a rounding boundary; the printed
resolution is chosen 10^4 times coarser than the measured cross-CPU spread, so that is rare).
"""

from __future__ import annotations

import re
import subprocess
import sys
from decimal import Decimal
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def _ulp(token: str) -> Decimal:
    """One unit in the last printed place of a number as printed."""
    d = Decimal(token)
    return Decimal(1).scaleb(d.as_tuple().exponent)


def compare_printed(new: str, old: str) -> list[str]:
    """Differences beyond one unit in the last printed place, as readable lines."""
    problems = []
    new_lines, old_lines = new.splitlines(), old.splitlines()
    if len(new_lines) != len(old_lines):
        return [f"{len(new_lines)} lines against {len(old_lines)} committed"]
    for i, (a, b) in enumerate(zip(new_lines, old_lines, strict=True), 1):
        if a == b:
            continue
        na, nb = NUMBER.findall(a), NUMBER.findall(b)
        if NUMBER.sub("#", a) != NUMBER.sub("#", b) or len(na) != len(nb):
            problems.append(f"line {i}: text differs: {a!r} / {b!r}")
            continue
        for x, y in zip(na, nb, strict=True):
            if x != y and abs(Decimal(x) - Decimal(y)) > max(_ulp(x), _ulp(y)):
                problems.append(f"line {i}: {x} against committed {y}")
    return problems


def test_compare_printed_allows_one_unit_in_the_last_place_only():
    assert compare_printed("a 1.2345 b", "a 1.2346 b") == []
    assert compare_printed("a 1.2345 b", "a 1.2347 b") != []
    assert compare_printed("x,-0.0302017", "x,-0.0302018") == []
    assert compare_printed("x 1", "y 1") != []


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reports")
    subprocess.run([sys.executable, str(ROOT / "studies" / "needle_208_nominal.py"),
                    "--out", str(out)], check=True, capture_output=True)
    return out / "needle_208"


@pytest.mark.parametrize("name", ["nominal", "deviation", "sum_delta_vs_beta"])
def test_nominal_report_matches_the_committed_one_at_printed_precision(regenerated, name):
    for ext in ("md", "csv"):
        new = (regenerated / f"{name}.{ext}").read_text()
        old = (ROOT / "reports" / "needle_208" / f"{name}.{ext}").read_text()
        assert compare_printed(new, old) == [], f"{name}.{ext}"


def test_csv_resolution_follows_the_unit_in_the_column_name():
    import pandas as pd

    from sewtol.reports.tables import to_csv, unit_of

    assert [unit_of(c) for c in ("d_um_at_beta_opt", "SumDelta (um)", "beta* (deg)",
                                 "deviation (mm)", "yield", "S1")] == ["um", "um", "deg", "mm",
                                                                       None, None]
    frame = pd.DataFrame({"total_um": [1.23456789012], "beta_deg": [22.58487993361],
                          "p_fail": [4.1666666667e-6]})
    assert to_csv(frame).splitlines()[1] == "1.234568,22.5848799,4.16666667e-06"


def test_run_records_name_the_command_as_typed_on_any_machine(tmp_path, monkeypatch):
    """run.json's command line holds no path of this machine's checkout."""
    import sewtol
    from sewtol.provenance import portable_command

    main_py = str(Path(sewtol.__file__).with_name("__main__.py"))
    assert portable_command([main_py, "run", "needle_208", "report"]) == [
        "python", "-m", "sewtol", "run", "needle_208", "report"]
    assert portable_command(["/opt/venv/bin/sewtol", "needle", "scan"]) == [
        "sewtol", "needle", "scan"]
    monkeypatch.chdir(tmp_path)
    script = tmp_path / "studies" / "x.py"
    assert portable_command([str(script), "--out", "r"]) == ["studies/x.py", "--out", "r"]
    assert portable_command(["/elsewhere/y.py"]) == ["/elsewhere/y.py"]
    committed = Path(__file__).resolve().parents[1] / "reports"
    for run_json in committed.rglob("*run.json"):
        import json

        cmd = json.loads(run_json.read_text()).get("command_line", [])
        assert not any(str(a).startswith("/") for a in cmd), run_json
