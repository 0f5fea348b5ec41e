"""Hostile inputs (issue 26, sections 4 and 5): each is refused in one line naming the field,
rule and value, with exit 2, within a subprocess timeout (no hang, no traceback)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NEEDLE = (ROOT / "examples" / "needle_208.toml").read_text()
TIMEOUT_S = 60  # generous for an overloaded machine; the old header regex took hours on 1 MiB


def sewtol(*argv, cwd=None, timeout=TIMEOUT_S):
    """`sewtol ARGV` in a fresh process, killed after `timeout` s: (exit code, stdout, stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    p = subprocess.run([sys.executable, "-m", "sewtol", *map(str, argv)], capture_output=True,
                       text=True, timeout=timeout, env=env, cwd=cwd)
    return p.returncode, p.stdout, p.stderr


def refused(*argv, cwd=None) -> str:
    """The one-line refusal of `sewtol ARGV` (exit 2, nothing on stdout, no traceback)."""
    code, out, err = sewtol(*argv, cwd=cwd)
    assert code == 2 and out == "" and err.count("\n") == 1, (code, out, err[-2000:])
    assert err.startswith("sewtol: error: ")
    return err


MEGA_LINE = "[" + " " * ((1 << 20) - 10_000)  # under the 1 MiB file cap with the needle


@pytest.mark.parametrize("text, expected", [
    # not TOML: refused by the TOML parser before any line is located
    (MEGA_LINE + "\n", "m.toml:1: is not valid TOML"),
    # valid TOML (the line sits in a string), refused later: the line locator scans it
    (NEEDLE.replace("[mechanism]", f'x = """\n{MEGA_LINE}\n"""\n[mechanism]'),
     "m.toml:6: x: unknown key"),
    ("x = " + "[" * 100_000 + "]" * 100_000 + "\n",
     "m.toml: nests arrays or inline tables too deeply to parse"),
    ("\ufeff" + NEEDLE, "m.toml:1: starts with a UTF-8 byte-order mark (BOM)"),
    (NEEDLE.replace("nominal = 6.75", "nominal = 1" + "0" * 399),
     "m.toml:21: [parameters] LF.nominal: must be a finite number (got 1000"),
    (NEEDLE.replace("nominal = 6.75", "nominal = 1" + "0" * 5000),
     "m.toml:1: is not valid TOML (got 'Exceeds the limit (4300 digits)"),
])
def test_hostile_file_is_refused_by_name_in_one_line(tmp_path, text, expected):
    (tmp_path / "m.toml").write_text(text)
    assert refused("run", "m.toml", "nominal", cwd=tmp_path).startswith(
        f"sewtol: error: {expected}")


@pytest.mark.parametrize("expr, rule", [
    ("9**9**9", "it is inf at the nominal values"),
    ("10.0**400", "it is inf at the nominal values"),
    ("1/0", "it is inf at the nominal values"),
    ("0**-1", "it is inf at the nominal values"),
    ("(-8)**(1/3)", "it is nan at the nominal values"),
    ("sqrt(-1)", "it is nan at the nominal values"),
    ("acos(2)", "it is nan at the nominal values"),
    ("Ax + sqrt(Ax)", "it is nan at the nominal values"),  # Ax < 0
    ("1" + "0" * 399, "a 400-digit number is not a finite 64-bit float"),
    ("Ax + 1e400", "the number inf is not a finite 64-bit float"),
])
def test_numeric_errors_of_an_expression_name_the_field_and_value(tmp_path, expr, rule):
    (tmp_path / "m.toml").write_text(NEEDLE.replace('x = "Ax"', f'x = "{expr}"'))
    err = refused("run", "m.toml", "nominal", cwd=tmp_path)
    assert err.startswith("sewtol: error: m.toml:51: [[groups]] A.x: ")
    assert rule in err and err.endswith(f"(got '{expr}')\n")


@pytest.mark.parametrize("literal", ["nan", "inf", "1" + "0" * 400])
def test_non_finite_literal_field_is_refused_at_load(tmp_path, literal):
    (tmp_path / "m.toml").write_text(NEEDLE.replace('x = "Ax"', f"x = {literal}"))
    err = refused("run", "m.toml", "nominal", cwd=tmp_path)
    assert err.startswith("sewtol: error: m.toml:51: [[groups]] A.x: ")
    assert "is not a finite 64-bit float" in err and "cannot close" not in err
