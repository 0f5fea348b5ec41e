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


# --- the import graph of src/sewtol: no cycles, no private names taken from another module ----

def _modules() -> dict[str, tuple[Path, bool]]:
    """Every module under src/sewtol by dotted name: (path, is a package's __init__)."""
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if package else parts)] = (path, package)
    return out


def _walk(node):
    """ast.walk, module- and function-level alike, skipping `if TYPE_CHECKING:` bodies (they
    never run)."""
    for child in ast.iter_child_nodes(node):
        test = getattr(child, "test", None) if isinstance(child, ast.If) else None
        if test is not None and "TYPE_CHECKING" in (getattr(test, "id", None),
                                                    getattr(test, "attr", None)):
            for other in child.orelse:
                yield other
                yield from _walk(other)
            continue
        yield child
        yield from _walk(child)


def _import_facts(name, path, package, modules):
    """(modules imported, private names taken) of one module: `from x import _y` and `x._y` on a
    name bound to a sewtol module, with their lines."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = name if package else name.rpartition(".")[0]
    deps, private, bound = set(), [], {}
    for node in _walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                deps.add(a.name)
                bound[a.asname or a.name.partition(".")[0]] = a.name if a.asname else \
                    a.name.partition(".")[0]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from .x import y
                stem = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join(stem + ([node.module] if node.module else []))
            for a in node.names:
                full = f"{base}.{a.name}"
                deps.add(full if full in modules else base)
                if full in modules:
                    bound[a.asname or a.name] = full
                if a.name.startswith("_") and not a.name.startswith("__") \
                        and base.startswith("sewtol"):
                    private.append(f"{name}:{node.lineno}: from {base} import {a.name}")
    for node in _walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            chain, value = [], node.value
            while isinstance(value, ast.Attribute):
                chain.insert(0, value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id in bound:
                owner = ".".join([bound[value.id], *chain])
                if owner in modules and owner.startswith("sewtol") and owner != name:
                    private.append(f"{name}:{node.lineno}: {owner}.{node.attr}")
    return {d for d in deps if d in modules and d != name}, private


def _graph():
    modules = _modules()
    facts = {n: _import_facts(n, p, pkg, modules) for n, (p, pkg) in modules.items()}
    return {n: f[0] for n, f in facts.items()}, [x for f in facts.values() for x in f[1]]


def _cycle(graph) -> list[str] | None:
    """One import cycle (a -> b -> ... -> a) if there is any (depth-first, colouring)."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == "open":
                return stack[stack.index(dep):] + [dep]
            if dep not in state and (found := visit(dep)):
                return found
        state[node] = "done"
        stack.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_checks_see_function_level_imports_and_skip_type_checking(tmp_path):
    """The two checks below on a made-up package: a cycle closed by a function-level import is
    found, one closed only under `if TYPE_CHECKING:` is not; both forms of private use count."""
    pkg = tmp_path / "sewtol"
    pkg.mkdir()
    (pkg / "a.py").write_text("import sewtol.b\n")
    (pkg / "b.py").write_text("def f():\n    from sewtol.a import _x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                              "    from sewtol import a\nfrom sewtol import b as B\nB._y\n")
    mods = {n: (pkg / f"{n}.py", False) for n in "abc"}
    mods = {f"sewtol.{n}": v for n, v in mods.items()}
    facts = {n: _import_facts(n, p, False, mods) for n, (p, _) in mods.items()}
    graph = {n: f[0] for n, f in facts.items()}
    assert graph == {"sewtol.a": {"sewtol.b"}, "sewtol.b": {"sewtol.a"}, "sewtol.c": {"sewtol.b"}}
    assert _cycle(graph) == ["sewtol.a", "sewtol.b", "sewtol.a"]
    assert facts["sewtol.b"][1] == ["sewtol.b:2: from sewtol.a import _x"]
    assert facts["sewtol.c"][1] == ["sewtol.c:5: sewtol.b._y"]
    assert _cycle({"sewtol.a": {"sewtol.b"}, "sewtol.b": set()}) is None


def test_no_import_cycles_in_sewtol():
    graph, _ = _graph()
    assert len(graph) > 50 and "sewtol.cli.common" in graph["sewtol.cli.needle"]
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_no_module_takes_another_modules_private_names():
    _, private = _graph()
    assert private == []


def test_the_cli_families_import_common_and_common_no_family():
    graph, _ = _graph()
    families = {n for n in graph if n.startswith("sewtol.cli.") and n != "sewtol.cli.common"}
    assert {"sewtol.cli.needle", "sewtol.cli.feed", "sewtol.cli.run"} <= families
    assert not {d for d in graph["sewtol.cli.common"] if d.startswith("sewtol.cli")}
    for family in families:
        assert "sewtol.cli.common" in graph[family], family
        assert "sewtol.cli" not in graph[family], family


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
        "feed_dogs": "sewtol.mechanisms.feed_131.metrics",
        "presser_contact": "sewtol.mechanisms.presser_foot.model"}
    assert M.declared("FAST_PATHS") == {"m6_needle": "sewtol.mechanisms.m6_needle.fast_path",
                                        "needle_208": "sewtol.mechanisms.needle_208.fast_path"}


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
    assert rows["m6_needle"]["fast_path"] == "m6_needle"
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


@pytest.mark.parametrize("name", BUILT_IN)
def test_folder_holds_no_module_named_after_a_study(name):
    """Their studies run through sewtol.studies; the folder keeps the model, its data, kernels and
    adjusters, and the tables in the source's columns live in sewtol.tables. A study's name is
    any module of sewtol.studies, or one the needle's studies had."""
    studies = {"scan.py", "montecarlo.py", "sobol.py", "ppm.py", "allocation.py", "strategies.py",
               "guides.py", "studies.py", "tables.py", "worst_case.py", "rare_event.py"}
    studies |= {p.name for p in (SRC / "studies").glob("*.py") if p.name != "__init__.py"}
    assert {"least_cost.py", "shapley.py", "refine.py", "settings.py"} <= studies
    files = list((SRC / "mechanisms" / name).rglob("*.py"))
    assert not studies & {p.name for p in files}
    # nor a function: scan_travel, montecarlo_travel, ... (a study's verb first)
    verbs = tuple(s.removesuffix(".py") for s in studies)
    named = [f"{p.name}:{n.name}" for p in files for n in ast.parse(p.read_text()).body
             if isinstance(n, ast.FunctionDef) and n.name.startswith(verbs)]
    assert named == []
