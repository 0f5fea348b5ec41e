"""The CLI contract of issue 2: keys, columns, one-line errors with non-zero exit."""

import io
import json

import numpy as np
import pandas as pd
import pytest

from cli_helpers import run, strict_loads
from sewtol.mechanisms.needle_208.single import deviation_table


def test_nominal_json_keys_and_values():
    code, out, _ = run("needle", "nominal", "--format", "json")
    assert code == 0
    d = strict_loads(out)
    for key in ("beta_opt_deg", "total_um", "plus_um", "minus_um", "window_deg", "guide",
                "stroke_mm", "A_mm", "D_mm"):
        assert key in d
    assert set(d["guide"]) >= {"x_mm", "y_mm", "angle_from_vertical_deg"}
    assert abs(d["beta_opt_deg"] - 22.7) <= 0.5
    assert abs(d["guide"]["angle_from_vertical_deg"] - 20) <= 0.2
    assert len(d["window_deg"]) == 2 and d["window_deg"][0] < d["beta_opt_deg"] < d["window_deg"][1]
    assert abs(d["plus_um"] + d["minus_um"] - d["total_um"]) < 1e-9


def test_deviation_csv_columns_match_the_model(nominal):
    code, out, _ = run("needle", "deviation", "--beta", "21", "--format", "csv")
    assert code == 0
    frame = pd.read_csv(io.StringIO(out))
    assert list(frame.columns) == ["phi_deg", "x_mm", "y_mm", "d_um"]
    assert len(frame) == 360
    ref = deviation_table(nominal.override(beta=21.0))
    assert np.max(np.abs(frame["d_um"] - ref["d_um"])) < 1e-6


def test_set_overrides_reach_the_model():
    _, a, _ = run("needle", "nominal", "--format", "json")
    _, b, _ = run("needle", "nominal", "--format", "json", "--set", "CD=30.01")
    assert strict_loads(a)["beta_opt_deg"] != strict_loads(b)["beta_opt_deg"]


def test_bad_inputs_exit_nonzero_with_one_line():
    cases = [
        (("--set", "LF=-2"), "LF: must be a positive length in mm (got -2.0)"),
        (("--set", "QQ=1"), "QQ: unknown parameter; valid names are LF, LM, AM"),
        (("--set", "LF"), "--set: must be NAME=VALUE"),
        (("--set", "LF=abc"), "LF: must be a number"),
        (("--set", "CD=5"), "dyad B-C-D cannot close at angle"),
        (("--set", "LM=30"), "dyad L-M-A cannot close at angle"),
    ]
    for extra, message in cases:
        code, out, err = run("needle", "nominal", *extra)
        assert code == 2, extra
        assert out == ""
        lines = err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (extra, err)


def test_feed_trajectory_csv_and_metrics_json():
    code, out, _ = run("feed", "trajectory", "--step-deg", "2", "--format", "csv")
    assert code == 0
    frame = pd.read_csv(io.StringIO(out))
    assert list(frame.columns) == ["phi_deg", "lower_x_mm", "lower_y_mm", "upper_x_mm",
                                   "upper_y_mm"]
    assert len(frame) == 180 and frame["phi_deg"].iloc[-1] == 358
    code, out, _ = run("feed", "metrics", "--format", "json")
    d = strict_loads(out)
    keys = {"feed_step_mm", "max_rise_mm", "max_rise_phi_deg", "entry_phi_deg", "exit_phi_deg",
            "vertical_travel_mm"}
    assert keys <= set(d["lower"]) and keys <= set(d["upper"])
    assert abs(d["differential_ratio"] - d["upper"]["feed_step_mm"] / d["lower"]["feed_step_mm"]) \
        < 1e-12
    code, out2, _ = run("feed", "metrics", "--format", "json", "--set", "b=20")
    assert strict_loads(out2)["lower"]["feed_step_mm"] < d["lower"]["feed_step_mm"]


def test_feed_bad_inputs():
    code, out, err = run("feed", "metrics", "--set", "EN=50")
    assert code == 2 and out == ""
    assert err.strip().startswith("sewtol: error: dyad M-N-E cannot close at angle")
    code, _, err = run("feed", "trajectory", "--set", "O9=1")
    assert code == 2 and "valid names are O1F" in err
    code, _, err = run("feed", "trajectory", "--step-deg", "0")
    assert code == 2 and "--step-deg: must be in [0.001, 90] (got 0.0)" in err


def _commands(parser, path=()):
    """Every command path of the parser tree: (), ("needle",), ("needle", "scan"), ..."""
    import argparse

    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


def test_every_command_prints_its_help():
    """`--help` on every command and group: exit 0, the command's usage and each of its flags."""
    from sewtol.cli import build_parser

    seen = 0
    for path, parser in _commands(build_parser()):
        code, out, err = run(*path, "--help")
        assert code == 0 and err == "", (path, err)
        assert out.startswith(f"usage: {' '.join(('sewtol', *path))}"), path
        for action in parser._actions:
            for flag in action.option_strings:
                assert flag in out, (path, flag)
        seen += 1
    assert seen >= 24  # sewtol, needle and its 12 commands, feed and its 6, run, mechanisms, fit
    # a help text with a literal percent sign is written %% (argparse formats it)
    assert "its 95 % interval" in " ".join(run("needle", "strategies", "--help")[1].split())


def test_every_run_study_prints_its_help():
    """`sewtol run FILE STUDY --help` for every study and every built-in mechanism (a name or
    a path): exit 0, run's usage with every study named, nothing on stderr."""
    from sewtol.cli.run import STUDIES
    from sewtol.mechanisms import mechanism_file

    names = ("needle_208", "feed_131", "khujand_feed", "spatial_crank_rocker")
    first = None
    for name in (*names, str(mechanism_file("needle_208"))):
        for study in STUDIES:
            code, out, err = run("run", name, study, "--help")
            assert code == 0 and err == "", (name, study, err)
            assert out.startswith("usage: sewtol run"), (name, study)
            first = first or out
            assert out == first  # one parser: the same help whatever the file and study
    for study in STUDIES:
        assert study in first
    for flag in ("--wide", "--format", "--out", "--adjust", "--path"):
        assert flag in first


def test_the_installed_command_prints_its_help():
    """`python -m sewtol --help` in a fresh process, and the console script names sewtol.cli:main."""
    import os
    import subprocess
    import sys
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"sewtol": "sewtol.cli:main"}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root / "src"), *filter(None, [os.environ.get("PYTHONPATH")])])}
    done = subprocess.run([sys.executable, "-m", "sewtol", "--help"], capture_output=True,
                          text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stderr == ""
    assert done.stdout.startswith("usage: sewtol")
    for group in ("needle", "feed", "run", "mechanisms"):
        assert group in done.stdout


def test_start_up_imports_only_what_the_command_uses():
    """In a fresh process: building and running the parser imports no study's libraries, and
    a Monte-Carlo of the needle (built-in command as a table, and the file on its fast path as
    JSON) never imports scipy.stats, scipy.optimize, joblib, pandas, the plotting and cluster
    libraries, another mechanism's model or a study it does not run, nor executes numpy.f2py or
    numpy.testing (bound unexecuted by the CLI; scipy.special's numpy copy binds every numpy
    submodule): each costs a part of the start-up the command has no use for. With the kernels
    compiled ahead of time built (make kernels), the Monte-Carlo never imports numba either."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from sewtol.mechanisms.needle_208.kernels import ahead

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root / "src"), *filter(None, [os.environ.get("PYTHONPATH")])])}
    probe = ("import contextlib, io, json, sys\n"
             "from sewtol.cli import build_parser, main\n"
             "build_parser().parse_args(sys.argv[1:])\n"
             "parsed = sorted(sys.modules)\n"
             "with contextlib.redirect_stdout(io.StringIO()):\n"
             "    code = main(sys.argv[1:])\n"
             "print(json.dumps([code, parsed, sorted(sys.modules)]))\n")
    never = {"scipy.stats", "scipy.optimize", "joblib", "matplotlib", "SALib", "dask",
             "distributed", "tqdm", "sewtol.mechanisms.feed_131.model", "pandas", "unittest",
             "numpy.f2py.crackfortran", "sewtol.studies.generic", "sewtol.studies.scan",
             "sewtol.studies.worst_case", "sewtol.studies.settings"}
    for command in (["needle", "montecarlo", "--n", "50"],
                    ["run", "needle_208", "montecarlo", "--n", "50", "--format", "json"]):
        done = subprocess.run([sys.executable, "-c", probe, *command], capture_output=True,
                              text=True, env=env, timeout=300)
        assert done.returncode == 0, done.stderr
        code, parsed, ran = json.loads(done.stdout)
        assert code == 0
        assert not {m for m in parsed if m.split(".")[0] in never | {"scipy", "pandas", "numba"}}
        assert not {m for m in ran if m in never or m.split(".")[0] in never}
        if ahead() is not None:
            assert not {m for m in ran if m.split(".")[0] in ("numba", "llvmlite")}


def test_a_table_of_records_prints_the_bytes_of_its_dataframe(capsys):
    """emit's pandas-free table (plain records: text, counts, floats, NaN and inf) prints
    exactly what pandas' to_markdown prints for DataFrame(records), compact (the failure
    columns summed into `failed`) and wide, with the same --wide note; records pandas must
    type (a None, a bool, a missing cell, text and numbers mixed, no text column) go through
    pandas itself. JSON and CSV of records are those of the frame."""
    from sewtol.cli.common import emit, plain_columns

    plain = [{"case": "fixed", "n": 1000, "ok": 72, "cannot_close": 0, "dead_point": 2,
              "yield": 0.072, "p95_um": np.float64(87.65741), "Cpu": float("inf"),
              "beta_at_bound": 0, "mixed": 1},
             {"case": "adjusted", "n": 1000, "ok": 89, "cannot_close": 3, "dead_point": 0,
              "yield": 0.089, "p95_um": np.float64(84.05), "Cpu": float("nan"),
              "beta_at_bound": np.int64(201), "mixed": 2.5}]
    typed = [[{**plain[0], "lower_limit": None}, plain[1]],
             [{**plain[0], "flag": True}, {**plain[1], "flag": False}],
             [plain[0], {k: v for k, v in plain[1].items() if k != "ok"}],
             [plain[0], {**plain[1], "mixed": "x"}],
             [{k: v for k, v in r.items() if k != "case"} for r in plain]]
    compact = ("case", "n", "ok", "failed", "yield", "p95_um", "mixed", "absent")
    assert plain_columns(plain, compact, False) is not None
    assert all(plain_columns(r) is None for r in typed)
    for records in (plain, *typed):
        for fmt, wide in (("table", False), ("table", True), ("json", False), ("csv", False)):
            emit(fmt, frame=records, compact=compact, wide=wide)
            got = capsys.readouterr().out
            emit(fmt, frame=pd.DataFrame(records), compact=compact, wide=wide)
            assert got == capsys.readouterr().out


def test_kernels_are_cached_on_disk_and_compile_nothing_at_import():
    """Every numba kernel of sewtol is declared with cache=True and none has a compiled
    signature after its module is imported (a fresh process): a warm start loads kernels from
    the cache when they are first called and compiles nothing."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root / "src"), *filter(None, [os.environ.get("PYTHONPATH")])])}
    probe = ("import gc, importlib, json\n"
             "from numba.core.caching import NullCache\n"
             "from numba.core.registry import CPUDispatcher\n"
             "for m in ('sewtol.mechanisms.needle_208.kernels.fused',\n"
             "          'sewtol.mechanisms.needle_208.kernels.window',\n"
             "          'sewtol.mechanisms.needle_208.kernels.positions',\n"
             "          'sewtol.mechanisms.presser_foot.kernel', 'sewtol.mechanism.compiled'):\n"
             "    importlib.import_module(m)\n"
             "ds = [d for d in gc.get_objects() if isinstance(d, CPUDispatcher)\n"
             "      and d.py_func.__module__.startswith('sewtol')]\n"
             "print(json.dumps([[d.py_func.__module__ + '.' + d.__name__,\n"
             "                   not isinstance(d._cache, NullCache), len(d.signatures)]\n"
             "                  for d in ds]))\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    kernels = json.loads(done.stdout)
    assert len(kernels) >= 40
    assert [k for k, cached, _ in kernels if not cached] == []
    assert [k for k, _, compiled in kernels if compiled] == []


def test_the_readme_flag_table_matches_the_parser():
    """Every flag the README's flag table offers a command is one that command's parser has:
    rows name commands in backticks (`needle nominal`, `scan`: a bare name keeps the group
    before it; "every `needle` command": all of them; "(`needle scan`: `--out` only)": that
    flag alone). Rows for "all" or "every study" are the common parser's, checked by the
    help test."""
    import re
    from pathlib import Path

    from sewtol.cli import build_parser

    parsers = dict(_commands(build_parser()))
    root = Path(__file__).resolve().parents[1]

    def flag_table(path):
        text = (root / path).read_text()
        return text[text.index("| flag | meaning | commands |"):].split("\n\n")[0].splitlines()

    table = flag_table("README.md")
    assert flag_table("docs/cli.md") == table  # the reference page carries the same table
    assert any(row.startswith("| `--wide` |") for row in table)
    table = table[2:]
    checked = 0

    def targets(cell):
        if cell.startswith("all"):  # "all", "all but `needle frames`": the common parser's
            return []
        if cell.startswith("every `"):
            group = re.match(r"every `(\w+)` command", cell).group(1)
            but = [tuple(n.split()) for n in re.findall(r"`([^`]+)`", cell.partition(" but ")[2])]
            return [p for p in parsers if len(p) == 2 and p[0] == group and p not in but]
        out, group = [], None
        for name in re.findall(r"`([^`]+)`", cell):
            words = tuple(name.split())
            if words[0] == "run":  # `run`: its one parser, whatever the study
                out.append(("run",))
                group = None
                continue
            if words[0] in ("needle", "feed"):
                group, words = words[0], words[1:]
            if not words or words[0].startswith("--"):
                continue
            assert group is not None, (cell, name)
            out.append((group, *words))
        return out

    for row in table:
        flag_cell, _, where = (c.strip() for c in row.strip("|").split(" | "))
        flags = re.findall(r"`(--[a-z-]+)", flag_cell)
        main, _, aside = where.partition("(")
        groups = [(flags, targets(main))]
        if aside:
            groups.append((re.findall(r"`(--[a-z-]+)` only", aside), targets(aside)))
        for wanted, paths in groups:
            for path in paths:
                assert path in parsers, (row, path)
                have = {f for a in parsers[path]._actions for f in a.option_strings}
                for flag in wanted:
                    assert flag in have, (path, flag)
                    checked += 1
    assert checked >= 40  # the table names commands in most rows


def _table(text):
    """The first Markdown table of a command's output: (header, rows as lists of cells)."""
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    cells = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    return cells[0], cells[2:]


def test_wide_tables_are_compact_by_default_and_whole_with_wide():
    """A wide table prints the columns a decision needs and names what --wide adds; --wide
    prints every column JSON and CSV hold, in their order; the counts still add up to n."""
    from sewtol.cli.needle import COMPACT

    argv = ("needle", "strategies", "--n", "20", "--seed", "3")
    rows = strict_loads(run(*argv, "--format", "json")[1])["rows"]
    code, compact, _ = run(*argv)
    assert code == 0
    header, cells = _table(compact)
    assert header == [c for c in COMPACT["strategies"]]
    assert len(header) < len(rows[0])
    hidden = [k for k in rows[0] if k not in header]
    assert f"note: --wide adds {len(hidden)} more columns ({', '.join(hidden)})" in compact
    for row, line in zip(rows, cells, strict=True):
        shown = dict(zip(header, line, strict=True))
        failed = row["cannot_assemble"] + row["dead_point"]
        assert int(shown["failed"]) == failed
        assert int(shown["ok"]) + int(shown["out_of_spec"]) + failed == row["n"] == 20
        assert float(shown["yield"]) == pytest.approx(row["yield"], abs=5e-5)
    code, wide, _ = run(*argv, "--wide")
    assert code == 0 and "--wide adds" not in wide
    header, cells = _table(wide)
    assert header == list(rows[0]) and len(cells) == len(rows)
    csv = run(*argv, "--format", "csv")[1]
    assert csv.splitlines()[0].split(",") == list(rows[0])  # CSV stays complete

    argv = ("needle", "montecarlo", "--n", "50", "--seed", "3")
    summary = strict_loads(run(*argv, "--format", "json")[1])["counts"]
    header, cells = _table(run(*argv)[1])
    assert header == list(COMPACT["montecarlo"])
    for line in cells:
        shown = dict(zip(header, line, strict=True))
        assert int(shown["ok"]) + int(shown["out_of_spec"]) + int(shown["failed"]) == 50
        assert int(shown["ok"]) == summary[shown["case"]]["ok"]
    wide_header, _ = _table(run(*argv, "--wide")[1])
    assert set(header) < set(wide_header) and "Cpu_percentile" in wide_header
    # `run FILE montecarlo` on the fast path is the needle command, --wide included
    assert run("run", "needle_208", "montecarlo", "--n", "50", "--seed", "3", "--wide")[1] == \
        run(*argv, "--wide")[1]


def test_wide_is_offered_by_every_command_with_a_compact_table():
    from sewtol.cli import build_parser
    from sewtol.cli import needle as N
    from sewtol.cli import run as R

    parsers = dict(_commands(build_parser()))
    wanted = [("needle", k) for k in N.COMPACT] + [("feed", "scan"), ("feed", "montecarlo"),
                                                    ("run",)]
    assert set(R.COMPACT) <= set(R.STUDIES)
    for path in wanted:
        assert "--wide" in {f for a in parsers[path]._actions for f in a.option_strings}, path
    # the generic run studies: the counts in the compact table add up to n
    header, cells = _table(run("run", "khujand_feed", "montecarlo", "--n", "40", "--seed", "1")[1])
    assert header == [c for c in R.COMPACT["montecarlo"] if c != "case"]
    for line in cells:
        shown = dict(zip(header, line, strict=True))
        assert int(shown["ok"]) + int(shown["out_of_spec"]) + int(shown["failed"]) == 40
    # `feed montecarlo` is `run feed_131 montecarlo`: the same compact table, --wide the rest
    argv = ("montecarlo", "--n", "30", "--seed", "1")
    header, _ = _table(run("feed", *argv)[1])
    assert header == [c for c in R.COMPACT["montecarlo"] if c != "case"]
    assert "p95" in _table(run("feed", *argv, "--wide")[1])[0]
