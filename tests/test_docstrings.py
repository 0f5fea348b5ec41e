"""The public namespace is documented: numpy-style docstrings naming every argument, type hints,
an API page for every name, and docs that stand on their own (no pointers outside the repository).

`make docs` (mkdocs build --strict) checks the same docstrings against the signatures and every
link between pages; these tests hold the rest without the docs tools installed.
"""

from __future__ import annotations

import ast
import doctest
import importlib
import inspect
import re
from pathlib import Path

import pytest

import sewtol

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = ["tolerance_set", *sewtol._PUBLIC]
CALLABLE = [n for n in PUBLIC if callable(getattr(sewtol, n))]
# where each public name is defined (module, attribute): what the API pages' ::: blocks name
DEFINED = {"tolerance_set": ("sewtol", "tolerance_set"), **sewtol._PUBLIC}


def _section(doc: str, title: str) -> bool:
    """A numpy-style section: the title on its own line, underlined with dashes."""
    return re.search(rf"^\s*{title}\n\s*-{{{len(title)}}}\s*$", doc, re.M) is not None


def _documented_names(doc: str) -> set[str]:
    """Names in the Parameters section: 'a : type' or 'a, b : type' or '**changes : type'."""
    m = re.search(r"^\s*Parameters\n\s*-+\n(.*?)(?:^\s*\w[\w ]*\n\s*-+\s*$|\Z)", doc, re.M | re.S)
    if not m:
        return set()
    names = set()
    for line in m.group(1).splitlines():
        head = re.match(r"^(\S[^:]*?)\s*:\s", line)  # entries start at the section's indent
        if head:
            names.update(n.strip().lstrip("*") for n in head.group(1).split(","))
    return names


def _arguments(obj) -> list[str]:
    sig = inspect.signature(obj)
    return [p.name for p in sig.parameters.values() if p.name not in ("self", "cls")]


@pytest.mark.parametrize("name", CALLABLE)
def test_public_name_has_numpy_docstring(name):
    obj = getattr(sewtol, name)
    doc = inspect.getdoc(obj)
    assert doc and len(doc.splitlines()[0]) > 10, f"{name}: no summary line"
    args = _arguments(obj)
    if args:
        assert _section(doc, "Parameters"), f"{name}: no Parameters section"
        missing = set(args) - _documented_names(doc)
        assert not missing, f"{name}: arguments not in its Parameters section: {sorted(missing)}"
    if inspect.isfunction(obj):
        assert _section(doc, "Returns"), f"{name}: no Returns section"


@pytest.mark.parametrize("name", CALLABLE)
def test_public_name_has_type_hints(name):
    obj = getattr(sewtol, name)
    sig = inspect.signature(obj)
    bare = [p.name for p in sig.parameters.values()
            if p.name not in ("self", "cls") and p.annotation is inspect.Parameter.empty]
    assert not bare, f"{name}: arguments without a type hint: {bare}"
    if inspect.isfunction(obj):
        assert sig.return_annotation is not inspect.Signature.empty, f"{name}: no return type"


def test_public_methods_named_in_docs_have_docstrings():
    # the methods a user reaches first on the mechanisms
    for meth in (sewtol.Needle208.nominal, sewtol.Needle208.override, sewtol.Feed131.override):
        doc = inspect.getdoc(meth)
        assert doc and _section(doc, "Returns"), meth.__qualname__


def _attribute_docstring(module: str, attr: str) -> str | None:
    """The string literal right after a module-level `attr = ...` (what mkdocstrings shows)."""
    tree = ast.parse(Path(importlib.import_module(module).__file__).read_text())
    body = tree.body
    for i, node in enumerate(body[:-1]):
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == attr for t in targets):
            nxt = body[i + 1]
            if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) \
                    and isinstance(nxt.value.value, str):
                return nxt.value.value
    return None


def test_public_values_have_docstrings():
    values = [n for n in PUBLIC if not callable(getattr(sewtol, n))]
    assert values == ["NEEDLE_208_SETS"]
    doc = _attribute_docstring(*DEFINED["NEEDLE_208_SETS"])
    assert doc is not None
    # it restates the source's limits: check them against the sets themselves
    sets = sewtol.NEEDLE_208_SETS
    assert "+0.25/-0.8" in doc and "CD +/-0.01" in doc and "CD exact" in doc
    lf = next(t for t in sets["recommended"].items if t.param == "LF")
    assert (lf.lower, lf.upper) == (-0.8, 0.25)
    assert "CD" not in sets["base"].params
    assert _attribute_docstring("sewtol.mechanisms.needle_208.frames", "DEFAULT_FRAME") is not None


def test_every_public_name_has_an_api_page_entry():
    blocks = set()
    for page in (ROOT / "docs" / "api").glob("*.md"):
        blocks.update(re.findall(r"^::: ([\w.]+)\s*$", page.read_text(), re.M))
    for name, (module, attr) in DEFINED.items():
        assert f"{module}.{attr}" in blocks, f"{name}: no '::: {module}.{attr}' in docs/api/"
    # every block names something that exists (mkdocs --strict checks this too)
    for path in blocks:
        module, _, attr = path.rpartition(".")
        assert hasattr(importlib.import_module(module), attr), path


def test_mkdocs_nav_pages_exist():
    text = (ROOT / "mkdocs.yml").read_text()
    nav = text[text.index("\nnav:"):]
    pages = re.findall(r":\s*(\S+\.md)\s*$", nav, re.M)
    assert "index.md" in pages and "api/index.md" in pages and len(pages) >= 20
    for page in pages:
        assert (ROOT / "docs" / page).is_file(), page
    for page in ("needle_208.md", "feed_131.md", "studies.md", "adjust.md", "adjustment.md",
                 "rare_event.md", "study_folders.md", "cluster.md", "reproducibility.md"):
        assert page in pages, f"{page} missing from the nav"



def test_the_api_reference_opens_with_the_protocol_and_the_generic_studies():
    """The API pages in the nav: the overview, then the protocol page (protocol, the suite,
    loading a file, the generic studies, its worked example), then everything else; the
    protocol page documents those modules before anything of one mechanism."""
    text = (ROOT / "mkdocs.yml").read_text()
    nav = text[text.index("\nnav:"):]
    api = [p for p in re.findall(r":\s*(\S+\.md)\s*$", nav, re.M) if p.startswith("api/")]
    assert api[:2] == ["api/index.md", "api/protocol.md"]
    page = (ROOT / "docs" / "api" / "protocol.md").read_text()
    blocks = re.findall(r"^::: (\S+)", page, re.M)
    firsts = [next(i for i, b in enumerate(blocks) if b.startswith(m)) for m in
              ("sewtol.protocol.", "sewtol.checks.", "sewtol.mechanism.loader.load",
               "sewtol.studies.")]
    assert firsts == sorted(firsts) and not [b for b in blocks if ".mechanisms." in b
                                             or ".tables." in b]
    assert page.index("## A worked example") < page.index("::: ")

# a pointer a reader outside the project cannot follow: the design notes beside the repository,
# or the project's issue tracker
OUTSIDE = re.compile(r"\.\./shared|shared/design|\bissues?\s*#?\s*\d|\bissues show\b|/issues\b",
                     re.I)


def _user_facing_docs() -> list[Path]:
    return [*sorted((ROOT / "docs").rglob("*.md")), ROOT / "README.md", ROOT / "CHANGELOG.md",
            ROOT / "mkdocs.yml"]


def test_docs_never_point_outside_the_repository():
    hits = []
    for path in _user_facing_docs():
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if OUTSIDE.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not hits, "\n".join(hits)
    assert OUTSIDE.search("see ../shared/design/needle_208.md") and OUTSIDE.search("(issue 13)")


def test_public_docstrings_never_point_outside_the_repository():
    for name in PUBLIC:
        doc = inspect.getdoc(getattr(sewtol, name)) or ""
        assert not OUTSIDE.search(doc), name
    for module in {m for m, _ in DEFINED.values()}:
        doc = importlib.import_module(module).__doc__ or ""
        assert not OUTSIDE.search(doc), module


def test_design_facts_are_restated_in_the_docs():
    """What a user needs from the source is in docs/, with the source's numbers."""
    needle = (ROOT / "docs" / "needle_208.md").read_text()
    p = sewtol.Needle208.nominal()
    for name in ("LF", "LM", "AM", "AB", "BC", "BE", "CD"):
        value = f"{getattr(p, name):g}"
        assert re.search(rf"^\| {name} \|[^\n]*\| {re.escape(value)} \|$", needle, re.M), name
    assert "(38.5, 79.729)" in needle and (p.guide_x, p.guide_y) == pytest.approx((38.5, 79.729))
    assert "| 2 Delta max (um) | 10.6 | 10.3 | 10.3 | 12.8 | 12.5 | 10.9 | 14.0 |" in needle
    assert "What is known about the frame" in needle
    feed = (ROOT / "docs" / "feed_131.md").read_text()
    f = sewtol.Feed131()
    assert f"F = O1 + {f.O1F:g} e(phi + {f.lift_phase:g})" in feed
    assert f"DB = {f.DB:g}, A1B = {f.A1B:g}" in feed
    assert f"Q2 = L + {f.slot_offset:g} e(f + 90) + {f.tooth2_u:g} e(f) + {f.tooth2_v:g} e(f - 90)" \
        in feed
    assert "EN = 98.66" in feed and "sqrt(95.7^2 + 24^2) = 98.6635" in feed


@pytest.mark.parametrize("name", ["tolerance_set", "ParameterError", "Needle208", "montecarlo"])
def test_docstring_examples_hold(name):
    obj = getattr(sewtol, name)
    finder = doctest.DocTestFinder(recurse=False)
    tests = finder.find(obj, name, globs={})
    assert tests and tests[0].examples, f"{name}: no example"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for t in tests:
        runner.run(t)
    assert runner.failures == 0


def test_home_page_example_prints_what_it_shows(capsys):
    """docs/index.md's first study runs as written and prints the table the page shows."""
    page = (ROOT / "docs" / "index.md").read_text()
    code = re.search(r"## A first study in Python.*?```python\n(.*?)```", page, re.S).group(1)
    shown = re.search(r"```text\n(.*?)```", page, re.S).group(1)
    exec(compile(code, "docs/index.md", "exec"), {})
    printed = capsys.readouterr().out
    norm = [" ".join(line.split()) for line in printed.splitlines()]
    for line in shown.strip().splitlines():
        assert " ".join(line.split()) in norm, line
    # and the numbers in the comment next to nominal_figures
    fig = sewtol.nominal_figures(sewtol.Needle208.nominal())
    assert f"beta* {fig.beta_opt_deg:.2f} deg, SumDelta {fig.total_um:.2f} um" in code
