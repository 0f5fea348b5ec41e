"""Built-in fused kernels a file may name with `fast_path`, and the check that earns it.

A file gets a built-in model's kernels (and its studies) only if its own groups reproduce the
built-in chain: positions of the named joints equal to POSITION_TOL_MM at the file's sampled
angles, for the nominal machine and PERTURBED machines around it (a fixed seed, so the check
is the same every time). Otherwise the loader refuses the fast path in one line.

Each fast path lives in its mechanism's folder (a module with a `FAST_PATH`, declared in the
folder's ``FAST_PATHS``, sewtol.mechanisms); this module holds only what they share.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

POSITION_TOL_MM = 1e-9
# the file's SumDelta takes its extremes on the sampled angles, the built-in model exactly: at
# 720 samples they agree to 1e-4 um; a file with far fewer samples is not the built-in model
SUMDELTA_TOL_UM = 0.01
PERTURBED = 4
CHECK_SEED = 20261122


@dataclass(frozen=True)
class FastPath:
    name: str
    points: tuple[str, ...]
    check: Callable  # check(mech) -> "" when it reproduces the model, else why not
    plugins: object = None  # sewtol.protocol.Plugins: its fused kernel and exact adjuster


@cache
def fast_paths() -> dict[str, FastPath]:
    """Every built-in fast path by name, from the mechanism folders' FAST_PATHS (once)."""
    import importlib

    from sewtol.mechanisms import declared

    return {name: importlib.import_module(module).FAST_PATH
            for name, module in declared("FAST_PATHS").items()}
