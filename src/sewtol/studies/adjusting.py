"""Adjustment at assembly, for every study: one dispatch from a mechanism and its compensators to
the per-machine optimum of one output.

    a = adjusted(mech, values, ["beta"], "SumDelta_um")
    a.value, a.settings["beta"], a.status, a.at_bound["beta"]

`compensators` names the compensators of the mechanism (its [compensators.NAME], boxes from the
file), or maps parameters to boxes (low, high), or is a sequence of compensator objects (name,
low, high and, where declared, steps, resolution, mode), or a strategy holding them. The
optimum comes from the mechanism's plug-ins (sewtol.protocol.Plugins) where they take that set
and output (the exact adjuster for boxes, the strategy adjuster for objects), otherwise from
the generic optimiser (one call: sewtol.studies.generic.optimise_compensator). `fast=False`
takes the generic one always (the reference path of `sewtol run FILE --path generic`).

`evaluated(mech, values, output)` is the same choice for a plain evaluation: the plug-in kernel
where it gives the output, else mech.evaluate.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from sewtol.errors import ParameterError
from sewtol.protocol import plugins


@dataclass(frozen=True)
class Adjusted:
    """Per machine: the adjusted output (`value`), each compensator parameter's setting, the
    status (the plug-in's words, or the generic "ok"/"cannot_close"/"dead_point"), whether
    each setting lies on an end of its box, and the plug-in's extra figures (`extras`)."""

    value: np.ndarray
    settings: dict[str, np.ndarray]
    status: np.ndarray
    at_bound: dict[str, np.ndarray]
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    path: str = "generic"


def _boxes(mech, compensators) -> dict[str, tuple[float, float]]:
    if isinstance(compensators, Mapping):
        return {k: tuple(map(float, v)) for k, v in compensators.items()}
    names = [compensators] if isinstance(compensators, str) else list(compensators)
    out = {}
    for name in names:
        if name not in mech.compensators:
            raise ParameterError("adjust", "must name a compensator of the file ("
                                 + (", ".join(mech.compensators) or "it has none") + ")", name)
        c = mech.compensators[name]
        out[c.parameter] = (float(c.low), float(c.high))
    return out


def _objects(compensators) -> bool:
    return not isinstance(compensators, (str, Mapping)) and \
        all(hasattr(c, "low") and not isinstance(c, str) for c in compensators)


def adjusted(mech, values: dict | None, compensators, output: str, *, fast: bool = True,
             **options) -> Adjusted:
    """Each machine of `values` (absolute parameter values; the rest nominal) adjusted: `output`
    minimised over the compensators (see the module docstring). `options` go to the plug-in
    (e.g. limit_um, plateaus for the needle's strategy adjuster)."""
    mech.output(output)
    pl = plugins(mech) if fast else None
    compensators = getattr(compensators, "compensators", compensators)  # a strategy's
    objects = _objects(compensators)
    if objects:
        names = [c.name for c in compensators]
        if pl is not None and output == pl.adjusted_output and pl.adjusts_strategy(names):
            return _of(pl.strategy_adjuster(mech, values or {}, tuple(compensators), **options),
                       pl.name)
        compensators = {c.name: (c.low, c.high) for c in compensators}
    boxes = _boxes(mech, compensators)
    if pl is not None and output == pl.adjusted_output and pl.adjusts(boxes):
        return _of(pl.adjuster(mech, values or {}, boxes), pl.name)
    return _generic(mech, values, boxes, output)


def _of(r: dict, path: str) -> Adjusted:
    known = ("value", "settings", "status", "at_bound")
    return Adjusted(r["value"], dict(r["settings"]), r["status"], dict(r.get("at_bound", {})),
                    {k: v for k, v in r.items() if k not in known}, path)


def _generic(mech, values, boxes, output) -> Adjusted:
    from sewtol.studies.generic import optimise_compensator

    by_param = {c.parameter: name for name, c in mech.compensators.items()}
    if len(boxes) != 1 or next(iter(boxes)) not in by_param:
        raise ParameterError("adjust", "the generic adjuster sets one compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")",
                             ",".join(boxes))
    (param, (lo, hi)), = boxes.items()
    comp = mech.compensators[by_param[param]]
    if (lo, hi) != (float(comp.low), float(comp.high)):
        raise ParameterError("adjust", f"the generic adjuster takes the file's box of {param} "
                             f"({comp.low:g}, {comp.high:g})", (lo, hi))
    a = optimise_compensator(mech, values, output, by_param[param])
    eps = 1e-9 * (hi - lo)
    at = (a.setting <= lo + eps) | (a.setting >= hi - eps)
    return Adjusted(a.value, {param: a.setting}, a.status, {param: at},
                    {"failed_group": a.failed_group})


def evaluated(mech, values: dict | None, output: str, *, fast: bool = True) -> np.ndarray:
    """`output` of machines `values`: the plug-in kernel where it gives it, else evaluate."""
    pl = plugins(mech) if fast else None
    if pl is not None and pl.kernel is not None and output in pl.kernel_outputs:
        return pl.kernel(mech, values or {})[output]
    return mech.evaluate(values, [output]).outputs[output]


def evaluated_failures(mech, values: dict, output: str) -> tuple[np.ndarray, np.ndarray]:
    """(status, failed group) of machines `values` as the mechanism's evaluation gives them:
    why a machine gives no value of `output` ("ok" where it runs)."""
    ev = mech.evaluate(values, [output])
    return ev.status, ev.failed_group
