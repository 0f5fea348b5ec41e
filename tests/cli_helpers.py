"""Helpers shared by the test modules: the CLI run in-process, strict JSON, a stretched dyad."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stderr, redirect_stdout

import numpy as np

from sewtol.cli import main
from sewtol.mechanisms.needle_208 import model as nd
from sewtol.mechanisms.needle_208.model import Needle208


def run(*argv):
    """`sewtol ARGV` in this process: (exit code, stdout, stderr); usage errors give their code."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(list(argv))
        except SystemExit as exc:  # argparse usage errors
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def _refuse(name):
    raise ValueError(f"not JSON: {name}")


def strict_loads(text):
    """json.loads that refuses NaN, Infinity and -Infinity (Python's default accepts them)."""
    return json.loads(text, parse_constant=_refuse)


def stretched_CD(p: Needle208) -> float:
    """The CD at which B-C-D is exactly stretched at the far end of its swing (beta fixed)."""
    c = nd.P.column(p, None)
    lo, hi, _, _ = nd.rocker_interval(c)
    t = np.linspace(float(lo), float(hi), 200_001)
    B = complex(p.Ax, p.Ay) + p.AB * np.exp(1j * (t + p.beta_sense * np.radians(p.beta)))
    return float(np.max(np.abs(complex(p.Dx, p.Dy) - B)) - p.BC)
