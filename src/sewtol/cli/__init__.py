"""The `sewtol` command: a thin layer over the library. Only this and study scripts write files.

One module per command family (needle, feed, run, mechanisms, fit), each importing the helpers
they share from sewtol.cli.common; this module builds the parser from them and runs a command."""

from __future__ import annotations

import argparse
import signal
import sys

from sewtol.cli.common import Parser, check_out, check_plot, resolve_progress
from sewtol.cli.feed import add_feed
from sewtol.cli.fit import add_fit
from sewtol.cli.mechanisms import add_mechanisms
from sewtol.cli.needle import add_needle
from sewtol.cli.run import add_run, needle_aliases
from sewtol.errors import AssemblyError, ParameterError
from sewtol.io import strict  # noqa: F401  (strict is part of the CLI's API)


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler, `timeout`): stop exactly like Ctrl-C (joblib stops its workers;
    no `except Exception` on the way can swallow it)."""


def build_parser() -> argparse.ArgumentParser:
    from sewtol import __version__
    from sewtol.provenance import git_revision

    ap = Parser(prog="sewtol", description=__doc__.splitlines()[0])
    ap.add_argument("--version", action="version",
                    version=f"sewtol {__version__} (revision {git_revision()})")
    sub = ap.add_subparsers(dest="group", required=True, parser_class=Parser)
    needle_aliases(add_needle(sub))  # `needle STUDY` is `run needle_208 STUDY`
    add_feed(sub)
    add_run(sub)  # `sewtol run FILE.toml STUDY`
    add_mechanisms(sub)
    add_fit(sub)  # `sewtol fit H7/g6 25`
    return ap


# numpy's submodules no command uses. scipy.special (the exact yield intervals, sewtol.intervals)
# imports scipy's array-API copy of numpy, which binds every numpy submodule (`from numpy import
# *` and getattr over dir(numpy)): f2py's regexes and numpy.testing's unittest alone are a fifth
# of a warm start-up. Bound here as lazy modules, they load (unchanged) on first attribute use.
LAZY_NUMPY = ("f2py", "testing", "ma", "polynomial", "ctypeslib", "char", "rec", "strings")


def defer_numpy_extras() -> None:
    """Put LAZY_NUMPY's modules not yet imported into sys.modules and on numpy as
    importlib.util.LazyLoader modules: binding them executes nothing, using one loads it whole.
    Only the command line calls this (a library user's numpy stays as they imported it)."""
    import importlib.util

    import numpy

    for name in LAZY_NUMPY:
        full = f"numpy.{name}"
        if full in sys.modules or (spec := importlib.util.find_spec(full)) is None:
            continue
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[full] = module
        spec.loader.exec_module(module)
        setattr(numpy, name, module)  # else numpy.__getattr__ imports it (and recurses)


def _on_sigterm(signum, frame):
    raise Terminated()


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    defer_numpy_extras()
    previous = None
    try:  # only the main thread may set handlers; a library caller's threads run without
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:
        pass
    resolve_progress(args)
    try:
        check_out(args)
        check_plot(args)
        args.func(args)
    except (ParameterError, AssemblyError) as exc:
        print(f"sewtol: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # e.g. the disk filled up while a chunk was saved
        where = getattr(args, "out", None)
        kept = (f"; finished chunks are kept in {where}/chunks: rerun with --resume" if where
                else "")
        print(f"sewtol: error: {exc.filename or 'output'}: {exc.strerror or exc}{kept}",
              file=sys.stderr)
        return 2
    except MemoryError:  # the up-front estimate passed, the study's peak did not fit
        where = getattr(args, "out", None)
        kept = (f"; finished chunks are kept in {where}/chunks: free memory and rerun with "
                "--resume" if where else "; use a smaller --n or --out DIR to keep chunks")
        print(f"sewtol: error: ran out of memory (the address-space or container limit, or the "
              f"machine's memory){kept}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        where = getattr(args, "out", None)
        hint = (f"; finished chunks are saved in {where}/chunks: rerun the same command with "
                "--resume" if where else "; nothing was saved (use --out DIR to keep chunks)")
        what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"sewtol: {what}{hint}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0
