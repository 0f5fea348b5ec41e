"""Built-in mechanisms, one folder (package) each.

A mechanism folder holds everything about one mechanism and nothing about the studies:

- ``mechanism.toml``: the mechanism as data (format ``sewtol-mechanism/1``, docs/mechanism_files.md):
  parameters with units, nominal values and rules; the topology as engine groups in assembly
  order; the named outputs; the compensators and their ranges; tolerance sets.
- ``README.md``: its documentation page (the site shows it under Mechanisms): the source's
  figures, every assumption, and the residuals against what the source publishes.
- ``__init__.py``: a docstring naming the folder's modules, and optional declarations read by
  sewtol: ``OUTPUT_KINDS`` (custom output kind -> the module that registers it) and
  ``FAST_PATHS`` (fast-path name -> the module holding its ``FAST_PATH``).
- optional Python: a model with a closed form or a fused kernel (``model.py``, ``kernels/``)
  and studies only this mechanism has (the needle's exact beta optimiser, its frame
  reconstruction).

The generic studies (sewtol.studies) take any of them by its file; a newcomer adds a mechanism
by adding a folder (or by writing a file anywhere and running ``sewtol run FILE.toml``), never
by touching sewtol.studies. ``sewtol mechanisms`` lists the built-in ones.

Only this package's own sub-packages are ever imported from here: a mechanism file names output
kinds and fast paths, never a module.
"""

from __future__ import annotations

import importlib
import pkgutil
from functools import cache
from pathlib import Path

FILE = "mechanism.toml"
DOCS = "README.md"


@cache
def names() -> tuple[str, ...]:
    """The built-in mechanisms: the sub-packages of sewtol.mechanisms that hold a mechanism.toml."""
    return tuple(sorted(m.name for m in pkgutil.iter_modules(__path__)
                        if m.ispkg and (folder(m.name) / FILE).is_file()))


def folder(name: str) -> Path:
    """The folder of built-in mechanism `name` (the first entry of the package path that has
    it)."""
    for root in __path__:
        if (Path(root) / name).is_dir():
            return Path(root) / name
    return Path(__path__[0]) / name


def mechanism_file(name: str) -> Path:
    """The mechanism file of built-in mechanism `name` (raises KeyError for an unknown name)."""
    if name not in names():
        raise KeyError(name)
    return folder(name) / FILE


def declared(attribute: str) -> dict[str, str]:
    """Merge the declarations `attribute` (a dict name -> module) of every built-in mechanism
    package; a name declared twice is an error of the package, not of a user's file."""
    out: dict[str, str] = {}
    for name in names():
        pkg = importlib.import_module(f"{__name__}.{name}")
        for key, module in getattr(pkg, attribute, {}).items():
            if key in out:
                raise RuntimeError(f"{attribute} {key!r} declared by two mechanisms")
            out[key] = module
    return out
