"""Failures per million of any mechanism: one output, its limits and an optional adjustment as
a rare-event LimitState (sewtol.studies.rare_event estimates it).

`limit_state(mech, tolerances, output, upper, lower, adjust)` maps the tolerance set's
independent standard normals (rare_event.StandardNormalMap) to machines of the protocol
mechanism and gives their output: as evaluated (the plug-in kernel where the mechanism has one)
or minimised over the compensators `adjust` (`sewtol.studies.adjusting.adjusted`: the needle's
exact beta optimum). A machine fails when its value lies beyond a limit or when it gives no
value; a machine without a value is counted under a named failure mode, never dropped: by
default each group that can fail gives two modes, "cannot_close at G" and "dead_point at G" (the
group that failed first, in assembly order, at the nominal compensators); a mechanism's adapter
may name its failures in its own words (`modes`, a status -> word map, and `failures`: the
needle's "cannot assemble", "dead point"). Limits default to the output's [[specs]] entry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.studies.adjusting import adjusted, evaluated, evaluated_failures
from sewtol.studies.rare_event import LimitState, StandardNormalMap
from sewtol.studies.scan import checked
from sewtol.tolerances import ToleranceSet

FAILURE_STATUSES = ("cannot_close", "dead_point")


def check_limits(upper: float | None, lower: float | None) -> tuple[float | None, float | None]:
    """At least one finite limit; lower below upper when both are given (mechanism.spec.Spec's
    rules, named by the command line's flags)."""
    if upper is None and lower is None:
        raise ParameterError("limit", "give an upper limit (--limit) and/or a lower limit "
                             "(--lower-limit), or a [[specs]] entry of the output in the file",
                             None)
    try:
        spec = Spec("", upper, lower)
    except ParameterError as exc:
        raise ParameterError({"upper": "limit", "lower": "lower_limit"}[exc.field], exc.rule,
                             exc.value) from None
    return spec.upper, spec.lower


def limits_of(mech, output: str, upper: float | None, lower: float | None):
    """The limits of a study of `output`: those given, else the file's [[specs]] entry of it."""
    spec = mech.spec_of(output) if upper is None and lower is None else None
    if spec is not None:
        return spec.upper, spec.lower
    return check_limits(upper, lower)


def limits_text(output: str, upper: float | None, lower: float | None, unit: str = "") -> str:
    """The pass condition in words, e.g. "4.2 mm <= stroke_mm <= 4.4 mm"."""
    u = f" {unit}" if unit and unit != "1" else ""
    if lower is None:
        return f"{output} <= {upper:g}{u}"
    if upper is None:
        return f"{output} >= {lower:g}{u}"
    return f"{lower:g}{u} <= {output} <= {upper:g}{u}"


def check_adjust(mech, adjust) -> None:
    """A compensator given by name must be one of the mechanism's."""
    if isinstance(adjust, str) and adjust not in mech.compensators:
        raise ParameterError("adjust", "must name a compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")", adjust)


def output_of(mech, values: dict, output: str, adjust=None, fast: bool = True,
              **options) -> np.ndarray:
    """`output` of machines `values`: as evaluated, or minimised over the compensators
    `adjust` (as `adjusting.adjusted` takes them); NaN where a machine gives no value."""
    if adjust is None:
        return evaluated(mech, values, output, fast=fast)
    return adjusted(mech, values, adjust, output, fast=fast, **options).value


def group_modes(mech) -> tuple[str, ...]:
    """The failure modes "STATUS at GROUP": every status of FAILURE_STATUSES at every group that
    can fail (it carries a closure), in assembly order."""
    state = mech.state(q_rad=np.zeros(1))
    return tuple(f"{s} at {g.name}" for g in mech.groups if g.name in state.closures
                 for s in FAILURE_STATUSES)


@dataclass(frozen=True)
class _Response:
    """z (n, dim) -> (value, mode) of one output (picklable: joblib workers receive it)."""

    mech: object
    zmap: StandardNormalMap
    output: str
    upper: float | None
    lower: float | None
    adjust: object
    modes: tuple[str, ...]
    words: dict | None  # status -> mode (None: "STATUS at GROUP")
    failures: Callable
    fast: bool
    options: dict = field(default_factory=dict)

    def __call__(self, z):
        values = machines(self.mech, self.zmap.to_physical(z))
        y = output_of(self.mech, values, self.output, self.adjust, self.fast, **self.options)
        mode = np.zeros(y.size, dtype=int)
        bad = ~np.isfinite(y)
        if bad.any():
            status, group = self.failures(self.mech, {k: v[bad] for k, v in values.items()},
                                          self.output)
            code = {m: k for k, m in enumerate(self.modes, start=1)}
            mode[bad] = [code.get(f"{s} at {g}" if self.words is None else self.words.get(s), 0)
                         for s, g in zip(status, group, strict=True)]
        value = y if self.lower is None else Spec(self.output, self.upper, self.lower).excess(y)
        return np.where(mode == 0, value, np.nan), mode


def limit_state(mech, tolerances: ToleranceSet, output: str, upper: float | None = None,
                lower: float | None = None, adjust=None, *, name: str | None = None,
                modes: dict[str, str] | None = None, failures: Callable | None = None,
                fast: bool = True, **options) -> LimitState:
    """One output of a protocol mechanism as a LimitState (see the module docstring).

    With an upper limit only, the LimitState's value is the output itself (named `name`,
    default OUTPUT or OUTPUT_adjusted) and its limit the upper limit; with a lower limit, its
    value is the excess beyond the limits (output units, NAME_excess) and its limit 0.
    adjust: compensators as `adjusting.adjusted` takes them (a name, names, boxes or
    objects); options go to the mechanism's strategy adjuster. failures(mech, values, output)
    -> (status, group) of the machines without a value, as every study takes it (default
    adjusting.evaluated_failures); the failure mode of a machine is "STATUS at GROUP"
    (`group_modes`), or, with `modes` (status -> the mechanism's word for it), modes[STATUS].
    fast=False: the generic reference path.
    """
    mech.output(output)
    check_adjust(mech, adjust)
    upper, lower = limits_of(mech, output, upper, lower)
    zmap = StandardNormalMap(checked(mech, tolerances))
    name = name or (output if adjust is None else f"{output}_adjusted")
    limit, name = (upper, name) if lower is None else (0.0, f"{name}_excess")
    names = group_modes(mech) if modes is None else tuple(dict.fromkeys(modes.values()))
    return LimitState(_Response(mech, zmap, output, upper, lower, adjust, names, modes,
                                failures or evaluated_failures, fast, dict(options)),
                      zmap.dim, float(limit), names, name, zmap.to_physical)
