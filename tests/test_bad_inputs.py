"""Every bad input gives one line on stderr and exit 2, before anything is written; the table in
docs/cli.md is what the CLI prints (studies/bad_input_table.py generates it)."""

import re
from pathlib import Path

import pytest

from cli_helpers import study_script

ROOT = Path(__file__).resolve().parents[1]
table = study_script("bad_input_table")


def readme_rows() -> dict[str, str]:
    """The bad-input table's rows (docs/cli.md, moved there from the README)."""
    out = {}
    for line in (ROOT / "docs" / "cli.md").read_text().splitlines():
        m = re.match(r"^\| `(sewtol [^`]*)` \| (.*) \|$", line)
        if m:
            out[m.group(1)] = m.group(2).replace("&#124;", "|")
    return out


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    table.make_files(d)
    return d


@pytest.mark.parametrize("args", table.CASES)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(folder, args):
    out = folder / "study"
    code, stdout, err = table.run_case(f"{args} --out {out}" if args.startswith(
        "needle montecarlo") and "--out" not in args and "--resume" not in args else args, folder)
    assert code == 2 and stdout == "", (args, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sewtol: error: "), err
    assert "Traceback" not in err
    assert not out.exists(), args  # not even the manifest
    shown = f"sewtol {args.format(d=table.SHOWN)}"
    expected = readme_rows().get(shown)
    assert expected is not None, f"docs/cli.md's bad-input table has no row for `{shown}`"
    message = lines[0].replace(str(folder), table.SHOWN)
    for cut in table.MACHINE_DEPENDENT:
        if cut in expected:
            expected, message = expected.split(cut)[0], message.split(cut)[0]
    assert message == expected
