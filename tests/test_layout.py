"""The layout: one folder per mechanism (file, docs, its Python), generic studies that name no
mechanism, and a newcomer's mechanism found by name without touching sewtol.studies."""

import ast
import io
import json
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

import sewtol.mechanisms as M
from sewtol.cli import main
from sewtol.cli.run import load_mechanism
from sewtol.mechanism import load

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "sewtol"
BUILT_IN = ("feed_131", "khujand_feed", "m6_needle", "needle_208", "presser_foot",
            "spatial_crank_rocker", "spatial_crank_slider")


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _imports(path: Path) -> list[str]:
    """Every module a file imports, at any depth (function-level imports included)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
    return names


def test_generic_studies_import_no_mechanism():
    offenders = {p.name: m for p in (SRC / "studies").glob("*.py") for m in _imports(p)
                 if m.startswith("sewtol.mechanisms") or m.startswith("sewtol.kernels")}
    assert offenders == {}


def test_the_built_in_mechanisms_are_the_folders():
    assert M.names() == BUILT_IN


@pytest.mark.parametrize("name", BUILT_IN)
def test_each_folder_holds_its_file_docs_and_a_described_package(name):
    folder = SRC / "mechanisms" / name
    mech = load(folder / "mechanism.toml")
    assert mech.name == name
    doc = ast.get_docstring(ast.parse((folder / "__init__.py").read_text()))
    assert doc and "README.md" in doc
    readme = folder / "README.md"
    assert readme.read_text().startswith("# ")
    # the site shows the folder's page, and the examples link to the folder's file
    assert (ROOT / "docs" / f"{name}.md").resolve() == readme.resolve()
    assert f": {name}.md" in (ROOT / "mkdocs.yml").read_text()
    assert (ROOT / "examples" / f"{name}.toml").resolve() == (folder / "mechanism.toml").resolve()


def test_declarations_come_from_the_folders():
    assert M.declared("OUTPUT_KINDS") == {
        "presser_contact": "sewtol.mechanisms.presser_foot.model"}
    assert M.declared("FAST_PATHS") == {"needle_208": "sewtol.mechanisms.needle_208.fast_path"}


def test_a_name_runs_the_same_file_as_its_path():
    code_a, by_name, _ = _run(["run", "khujand_feed", "nominal", "--format", "csv"])
    code_b, by_path, _ = _run(["run", str(ROOT / "examples" / "khujand_feed.toml"), "nominal",
                               "--format", "csv"])
    assert code_a == code_b == 0
    assert by_name == by_path
    # a built-in file is named by its place in the package, the same on every machine
    assert load_mechanism("khujand_feed").path == "sewtol/mechanisms/khujand_feed/mechanism.toml"


def test_an_unknown_name_is_one_line_naming_the_built_in_ones():
    code, out, err = _run(["run", "no_such_machine", "nominal"])
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert "FILE.toml" in err and "no_such_machine" in err and "needle_208" in err


def test_mechanisms_lists_every_folder():
    code, out, _ = _run(["mechanisms", "--format", "json"])
    rows = {r["name"]: r for r in json.loads(out)["mechanisms"]}
    assert code == 0 and tuple(rows) == BUILT_IN
    assert rows["needle_208"]["fast_path"] == "needle_208"
    assert rows["presser_foot"]["output_kinds"] == "presser_contact"
    assert rows["m6_needle"]["file"] == "sewtol/mechanisms/m6_needle/mechanism.toml"


def test_a_newcomer_adds_a_folder_and_runs_it_by_name(tmp_path, monkeypatch):
    """A new folder next to the built-in ones (here on the package path) is listed and runs
    by name; nothing in sewtol.studies changes."""
    studies_before = {p.name: p.read_bytes() for p in (SRC / "studies").glob("*.py")}
    folder = tmp_path / "my_crank_slider"
    folder.mkdir()
    (folder / "__init__.py").write_text('"""My crank-slider (docs: README.md)."""\n')
    (folder / "README.md").write_text("# My crank-slider\n")
    text = (ROOT / "tests" / "data" / "crank_slider.toml").read_text()
    (folder / "mechanism.toml").write_text(text.replace('name = "crank_slider"',
                                                        'name = "my_crank_slider"'))
    monkeypatch.setattr(M, "__path__", [*M.__path__, str(tmp_path)])
    M.names.cache_clear()
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        assert "my_crank_slider" in M.names()
        code, by_name, _ = _run(["run", "my_crank_slider", "nominal", "--format", "csv"])
        code_f, by_file, _ = _run(["run", str(ROOT / "tests" / "data" / "crank_slider.toml"),
                                   "nominal", "--format", "csv"])
        assert code == code_f == 0 and by_name == by_file
    finally:
        M.names.cache_clear()
        sys.modules.pop("sewtol.mechanisms.my_crank_slider", None)
    assert {p.name: p.read_bytes() for p in (SRC / "studies").glob("*.py")} == studies_before
