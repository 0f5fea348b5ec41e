"""The mechanism protocol: the one small interface every study takes.

A mechanism, for a study, is five things and nothing else:

1. **parameters** with nominal values, units and rules (`parameters`, `nominal_values()`),
   and, from a tolerance set, the **input law** of their deviations (`input_law(mech, set)`,
   a `sewtol.law.InputLaw`: a joint distribution, not independent columns);
2. **outputs** (`outputs`: name, unit) and **evaluate(values, outputs) -> Evaluation**: one
   number per output and machine, each machine's status ("ok", "cannot_close",
   "dead_point") and the group that failed, over arrays of m machines;
3. **specs**: limits on outputs, as data (`specs`; the needle's SumDelta_um <= 10 um);
4. **compensators**: what a fitter sets on each machine, with a box (low, high) and, where
   declared, steps, a resolution and a setting error (`compensators`);
5. optional **plug-ins** (`plugins(mech)`): a fused kernel that gives some outputs faster
   (or exactly where the generic path samples angles), with the bound within which it must
   equal the generic evaluation, and an exact adjuster for some sets of compensators.

`override(**nominals)` gives the same mechanism with other nominal values, so a study may vary
the design itself (refinement). A pair's clearance enters as parameters of the pair: a file's
revolute pair with a clearance has its journal's offset (`pair_parameters`, nominal 0), which
`evaluate` takes beside the parameters (sewtol.mechanism.clearance, sewtol.studies.clearance).

`sewtol.mechanism.FileMechanism` (any mechanism file, every built-in) implements it; a
mechanism folder adds plug-ins by declaring them in its fast path (``FAST_PATHS``). Every
implementation passes the one suite `sewtol.checks.check_mechanism`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from sewtol.errors import ParameterError
from sewtol.law import InputLaw
from sewtol.tolerances import ToleranceSet


@runtime_checkable
class Mechanism(Protocol):
    """What every study reads of a mechanism (see the module docstring)."""

    @property
    def name(self) -> str: ...

    @property
    def parameters(self) -> tuple: ...

    @property
    def outputs(self) -> tuple: ...

    @property
    def compensators(self) -> Mapping: ...

    @property
    def tolerance_sets(self) -> Mapping[str, ToleranceSet]: ...

    @property
    def specs(self) -> tuple: ...

    def nominal_values(self) -> dict[str, float]: ...

    def evaluate(self, values: dict | None = None, outputs=None): ...

    def override(self, **changes) -> Mechanism: ...


@dataclass(frozen=True)
class Plugins:
    """A mechanism's optional fast parts.

    Parameters
    ----------
    kernel : callable or None
        ``kernel(mech, values) -> dict`` output name -> array (one number per machine, NaN
        where the machine does not run): the outputs in `kernel_outputs`, computed by a fused
        or exact model instead of the generic sampled one.
    kernel_outputs : tuple of str
        The outputs the kernel gives.
    kernel_bound : callable or None
        ``kernel_bound(mech, values) -> dict`` output -> array: how far the generic evaluation
        may lie from the kernel's on each machine (the generic path samples the crank angle;
        the bound is derived, not tuned). The suite holds the two within it.
    adjuster : callable or None
        ``adjuster(mech, values, boxes, figures=True) -> dict`` with ``value`` (the optimum of
        the adjusted output per machine) and ``settings`` (compensator parameter -> array): the
        exact optimum over `boxes` (parameter -> (low, high), absolute settings). With
        ``figures=False`` the caller reads only ``value``, ``settings``, ``status``,
        ``at_bound``, ``low`` and ``high``, and the adjuster may leave out its further figures
        (the Monte-Carlo's chunks: the needle's exact figures at the settings cost more than
        the optimum); it may add ``as_built``, the kernel's outputs of the machines as given
        (what `kernel` gives), from the work the optimum shares with it.
    adjuster_sets : tuple of frozenset
        The sets of compensator parameters the adjuster solves exactly.
    adjusted_output : str or None
        The output the adjuster minimises.
    adjuster_tol : float
        How far above the true minimum the adjuster's value may lie (the output's unit): the
        width of the plateau it takes the centre of, plus its own approximation error.
    strategy_adjuster : callable or None
        ``strategy_adjuster(mech, values, compensators, **options) -> dict`` (the adjuster's
        keys): the mechanism's own adjuster of `adjusted_output` for compensators given as
        objects (name, low, high and, where declared, steps, resolution, mode), any subset of
        `strategy_parameters`; an outer search where it is not exact (not held to a grid).
        Its settings are in each compensator's own terms (an offset compensator's offset from
        the machine's as-built value, an absolute one's value).
    strategy_parameters : frozenset
        The compensator parameters the strategy adjuster takes.
    measured_adjuster : callable or None
        ``measured_adjuster(mech, values, compensators, phi_rad, noise, **options) -> dict``
        (the strategy adjuster's keys, settings in each compensator's own terms): the
        compensators set to the optimum of the adjusted output as MEASURED at the crank angles
        `phi_rad` with the reading errors `noise` (machines x angles, the output's unit;
        sewtol.measurement_error), the value the true output at those settings.
    failure_table : callable or None
        ``failure_table(mech, values) -> dict`` of arrays, every machine's first reason not to
        run at its values: ``status`` (the protocol's words), ``group`` and the mechanism's
        further figures (the needle: angle, gap, transmission angle). On the fast path the
        Monte-Carlo names each machine's status by it (`studies.montecarlo.named_failures`),
        Sobol, ppm and allocation their failures (`studies.adjusting.failures_of`).
    serial : callable or None
        ``serial()`` a context manager within which the mechanism's kernels run on the calling
        thread without numba where it can (the needle's: its kernels compiled ahead of time,
        when built); it yields whether they do. A worker process of the strategies study runs
        its chunk inside it (one thread each), so the worker never loads numba and LLVM.
    columns : mapping
        Study -> (generic column name -> the mechanism's name), in the order its tables show
        them: the source study's words for the generic results (data, not code).
    """

    kernel: Callable | None = None
    kernel_outputs: tuple[str, ...] = ()
    kernel_bound: Callable | None = None
    adjuster: Callable | None = None
    adjuster_sets: tuple[frozenset, ...] = ()
    adjusted_output: str | None = None
    adjuster_tol: float = 0.0
    strategy_adjuster: Callable | None = None
    strategy_parameters: frozenset = frozenset()
    measured_adjuster: Callable | None = None
    failure_table: Callable | None = None
    serial: Callable | None = None
    columns: Mapping[str, Mapping[str, str]] = field(default_factory=dict, hash=False)
    name: str = ""
    notes: tuple[str, ...] = field(default=())

    def adjusts(self, parameters) -> bool:
        """True when the exact adjuster solves exactly this set of compensator parameters."""
        return self.adjuster is not None and frozenset(parameters) in self.adjuster_sets

    def adjusts_strategy(self, parameters) -> bool:
        """True when the strategy adjuster takes this set of compensator parameters."""
        return self.strategy_adjuster is not None and \
            frozenset(parameters) <= self.strategy_parameters


NO_PLUGINS = Plugins()


def plugins(mech) -> Plugins:
    """The plug-ins a mechanism earned: those of the fast path its file names (the loader has
    already checked that the file reproduces the built-in model), else none."""
    name = getattr(getattr(mech, "header", None), "fast_path", None)
    if not name:
        return NO_PLUGINS
    from sewtol.mechanism.fast_paths import fast_paths

    fp = fast_paths().get(name)
    return getattr(fp, "plugins", None) or NO_PLUGINS


def tolerance_set(mech, tolerances: ToleranceSet | str) -> ToleranceSet:
    """A tolerance set of the mechanism, by name (one of its file's sets) or as given, its
    parameters checked against the mechanism's."""
    if isinstance(tolerances, str):
        sets = mech.tolerance_sets
        if tolerances not in sets:
            raise ParameterError("tolerances", "must name a tolerance set of the mechanism ("
                                 + (", ".join(sets) or "it has none") + ")", tolerances)
        tolerances = sets[tolerances]
    if not isinstance(tolerances, ToleranceSet):
        raise ParameterError("tolerances", "must be a ToleranceSet or the name of one",
                             type(tolerances).__name__)
    return tolerances.check_names([p.name for p in mech.parameters])


def input_law(mech, tolerances: ToleranceSet | str) -> InputLaw:
    """The joint law of the mechanism's deviations under a tolerance set (by name or given)."""
    return InputLaw.of(tolerance_set(mech, tolerances))


def machines(mech, deviations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Absolute parameter values of machines nominal + deviations (the rest nominal)."""
    nominal = mech.nominal_values()
    return {k: nominal[k] + np.asarray(v, float) for k, v in deviations.items()}


def words_of(vocabulary, codes) -> np.ndarray:
    """A column of words (a status, a failed group) per machine: vocabulary[code] as an object
    array pointing at one str object per word, 8 bytes a machine (a list of words, astype,
    np.full and np.where make a str object per machine: 60 MB a million machines, measured);
    np.zeros(shape, np.uint8) as codes gives a column of one word."""
    return np.array(list(vocabulary), object)[codes]
