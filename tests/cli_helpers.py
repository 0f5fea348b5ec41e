"""Helpers shared by the test modules: the CLI run in-process, strict JSON, a stretched dyad,
a study script loaded as a module."""

from __future__ import annotations

import importlib.util
import io
import json
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

from sewtol.cli import main
from sewtol.mechanisms.needle_208 import model as nd
from sewtol.mechanisms.needle_208.model import Needle208


def study_script(name: str):
    """studies/NAME.py (a report script, not a package module) loaded as a module."""
    path = Path(__file__).resolve().parents[1] / "studies" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


def needle_columns(nominal, dev):
    """The machines nominal + dev as the needle's parameter columns, each (n, 1)."""
    from sewtol.mechanisms import params as P
    from sewtol.mechanisms.needle_208 import metrics as nm

    n = len(next(iter(dev.values())))
    c, _ = nm.columns(P.with_deviations(nominal, dev))
    return {k: np.broadcast_to(v, (n, 1)).copy() for k, v in c.items()}


def fixed_um(nominal, dev):
    """SumDelta (um) of nominal + dev, beta as given, by the fast path's fused kernel."""
    from sewtol.mechanisms.needle_208.metrics import total_um_kernel

    return total_um_kernel(needle_columns(nominal, dev))


def beta_adjusted(nominal, dev, range_deg=(10.0, 35.0), engine="numba"):
    """The exact beta optimum (needle_208.adjust.optimise) of nominal + dev in range_deg."""
    from sewtol.mechanisms.needle_208.adjust import optimise

    return optimise(needle_columns(nominal, dev), {"beta": tuple(range_deg)}, engine=engine)
