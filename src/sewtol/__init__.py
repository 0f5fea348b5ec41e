"""sewtol: tolerance and design-sensitivity analysis of sewing-machine mechanisms.

The public namespace, loaded lazily (importing sewtol is cheap; numba compiles on first use):

    from sewtol import Needle208, tolerance_set, montecarlo
    res = montecarlo(Needle208.nominal(), tolerance_set("recommended"), n=10_000, seed=2026)

Mechanisms: Needle208 (frames: load_frame, list_frames), Feed131. Tolerances: Tolerance,
ToleranceSet, tolerance_set, NEEDLE_208_SETS. Single machines: nominal_figures, deviation_table.
Studies: scan, largest_tolerances, worst_case_table, montecarlo, needle_sobol, allocate,
compare_guides, strategies_table, optimise (the exact joint optimum), adjust, Compensator,
Strategy, estimate and needle_limit_state (rare events), refine (nominal refinement of any
mechanism file). Errors: ParameterError, AssemblyError.
"""

from __future__ import annotations

import importlib
import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sewtol.tolerances import ToleranceSet

__version__ = "0.1.0"

# public name -> (module, attribute)
_PUBLIC = {
    "Needle208": ("sewtol.mechanisms.needle_208.model", "Needle208"),
    "Feed131": ("sewtol.mechanisms.feed_131.model", "Feed131"),
    "load_frame": ("sewtol.mechanisms.needle_208.frames", "load_frame"),
    "list_frames": ("sewtol.mechanisms.needle_208.frames", "list_frames"),
    "Tolerance": ("sewtol.tolerances", "Tolerance"),
    "ToleranceSet": ("sewtol.tolerances", "ToleranceSet"),
    "NEEDLE_208_SETS": ("sewtol.tolerances", "NEEDLE_208_SETS"),
    "nominal_figures": ("sewtol.mechanisms.needle_208.single", "nominal_figures"),
    "deviation_table": ("sewtol.mechanisms.needle_208.single", "deviation_table"),
    "scan": ("sewtol.tables.needle_208", "scan"),
    "largest_tolerances": ("sewtol.tables.needle_208", "largest_tolerances"),
    "worst_case_table": ("sewtol.tables.needle_208", "worst_case_table"),
    "montecarlo": ("sewtol.tables.needle_208", "montecarlo"),
    "needle_sobol": ("sewtol.tables.needle_208", "needle_sobol"),
    "allocate": ("sewtol.tables.needle_208", "allocate"),
    "compare_guides": ("sewtol.tables.needle_208", "compare_guides"),
    "strategies_table": ("sewtol.tables.needle_208", "strategies_table"),
    "optimise": ("sewtol.mechanisms.needle_208.adjust", "optimise"),
    "adjust": ("sewtol.mechanisms.needle_208.adjustment", "adjust"),
    "Compensator": ("sewtol.mechanisms.needle_208.compensators", "Compensator"),
    "Strategy": ("sewtol.mechanisms.needle_208.compensators", "Strategy"),
    "estimate": ("sewtol.studies.rare_event", "estimate"),
    "refine": ("sewtol.studies.refine", "refine"),
    "needle_limit_state": ("sewtol.tables.needle_208", "needle_limit_state"),
    "ParameterError": ("sewtol.errors", "ParameterError"),
    "AssemblyError": ("sewtol.errors", "AssemblyError"),
}

__all__ = ["__version__", "tolerance_set", *_PUBLIC]


def tolerance_set(name_or_path: str | os.PathLike | ToleranceSet) -> ToleranceSet:
    """A needle tolerance set from a name, a TOML file, or a set: the string shortcut.

    The same strings the command line's ``--tolerances`` takes.

    Parameters
    ----------
    name_or_path : str, os.PathLike or ToleranceSet
        ``"base"`` or ``"recommended"`` (the source study's sets, lengths in mm);
        ``"FILE.toml"`` (a file holding one ``[sets.NAME]`` table) or ``"FILE.toml:NAME"``;
        or a `ToleranceSet`, returned as it is.

    Returns
    -------
    ToleranceSet
        The set, its parameter names checked against `Needle208`'s.

    Raises
    ------
    ParameterError
        For an unknown name, an unreadable or invalid file, or a parameter the needle drive
        does not have (the message lists the valid ones).

    Examples
    --------
    >>> import sewtol
    >>> sewtol.tolerance_set("recommended").params
    ['LF', 'LM', 'AM', 'AB', 'BC', 'BE', 'CD']
    """
    from sewtol.tolerances import needle_set

    return needle_set(os.fspath(name_or_path) if isinstance(name_or_path, os.PathLike)
                      else name_or_path)


def __getattr__(name: str):
    if name in _PUBLIC:
        module, attr = _PUBLIC[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sewtol' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
