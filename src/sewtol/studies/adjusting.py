"""Adjustment at assembly, for every study: one dispatch from a mechanism and its compensators
to the per-machine optimum of one output.

    a = adjusted(mech, values, ["beta"], "SumDelta_um")
    a.value, a.settings["beta"], a.status, a.at_bound["beta"]

The optimum comes from the mechanism's plug-ins (sewtol.protocol.Plugins) where they take that
set and output, else from the generic adjuster (sewtol.adjuster.adjust); `fast=False` takes the
generic one always. `evaluated(mech, values, output)` is the same choice for a plain
evaluation.
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
    each setting lies on an end of its box, and the plug-in's extra figures (`extras`).
    `terms`: ``"absolute"`` (settings are the parameters' values) or ``"own"`` (each
    compensator's own terms, as a plug-in's strategy adjuster gives them: an offset
    compensator's offset from the as-built value)."""

    value: np.ndarray
    settings: dict[str, np.ndarray]
    status: np.ndarray
    at_bound: dict[str, np.ndarray]
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    path: str = "generic"
    terms: str = "absolute"


def boxes_of(mech, compensators) -> dict[str, tuple[float, float]]:
    """The compensators' boxes as absolute (low, high) per parameter (an offset compensator's
    box added to the nominal): names of the mechanism's compensators, or parameter -> box."""
    if isinstance(compensators, Mapping):
        return {k: tuple(map(float, v)) for k, v in compensators.items()}
    if isinstance(compensators, str):
        compensators = [compensators]
    compensators = [c.strip() for name in compensators for c in name.split(",")]
    out = {}
    for name in compensators:
        if name not in mech.compensators:
            raise ParameterError("adjust", "must name a compensator of the file ("
                                 + (", ".join(mech.compensators) or "it has none") + ")", name)
        c = mech.compensators[name]
        lo, hi = float(c.low), float(c.high)
        if getattr(c, "mode", "absolute") == "offset":  # the plug-ins take absolute boxes
            own = float(mech.nominal_values()[c.parameter])
            lo, hi = own + lo, own + hi
        out[c.parameter] = (lo, hi)
    return out


def _objects(compensators) -> bool:
    return not isinstance(compensators, (str, Mapping)) and \
        all(hasattr(c, "low") and not isinstance(c, str) for c in compensators)


def adjusted(mech, values: dict | None, compensators, output: str, *, fast: bool = True,
             objective=None, figures: bool = True, **options) -> Adjusted:
    """Each machine of `values` (absolute parameter values; the rest nominal) adjusted: `output`
    minimised over the compensators, or brought to a target or
    centred in a spec (`objective`: sewtol.adjuster.Objective or "target=T", "centre=L,U";
    the plug-ins minimise, so another objective takes the generic adjuster). `options` go to
    the plug-in (e.g. limit_um, plateaus for the needle's strategy adjuster); figures=False
    tells the exact adjuster that only the value, settings, status, bounds and plateaus are
    read (Plugins.adjuster), so it may skip its further figures.

    `compensators` names compensators of the mechanism (boxes from the file), or maps
    parameters to boxes (low, high), or is a sequence of compensator objects (name, low, high
    and, where declared, steps, resolution, mode), or a strategy holding them; the plug-in's
    exact adjuster takes boxes, its strategy adjuster objects, the generic adjuster 1 to 3
    compensators jointly."""
    from sewtol.adjuster import Objective

    mech.output(output)
    objective = Objective.parse(objective)
    compensators = getattr(compensators, "compensators", compensators)  # a strategy's
    # with nothing to set the objective does not matter: the plug-in gives the machine as built
    pl = plugins(mech) if fast and (objective.kind == "minimise" or not len(compensators)) \
        else None
    objects = _objects(compensators)
    if objects:
        names = [c.name for c in compensators]
        if pl is not None and output == pl.adjusted_output and pl.adjusts_strategy(names):
            return _of(pl.strategy_adjuster(mech, values or {}, tuple(compensators), **options),
                       pl.name, "own")
        compensators = {c.name: (c.low, c.high) for c in compensators}
    boxes = boxes_of(mech, compensators)
    if pl is not None and output == pl.adjusted_output and pl.adjusts(boxes):
        return _of(pl.adjuster(mech, values or {}, boxes, figures=figures), pl.name)
    return _generic(mech, values, boxes, output, objective)


def _of(r: dict, path: str, terms: str = "absolute") -> Adjusted:
    known = ("value", "settings", "status", "at_bound")
    return Adjusted(r["value"], dict(r["settings"]), r["status"], dict(r.get("at_bound", {})),
                    {k: v for k, v in r.items() if k not in known}, path, terms)


def _generic(mech, values, boxes, output, objective) -> Adjusted:
    """The generic adjuster (sewtol.adjuster: 1 to 3 of the file's compensators jointly,
    minimise, target or centre, checked against brute force) on the file's boxes; settings
    are absolute parameter values (an offset compensator's added to the machine's own)."""
    from sewtol.adjuster import adjust

    by_param = {c.parameter: name for name, c in mech.compensators.items()}
    unknown = [p for p in boxes if p not in by_param]
    if unknown:
        raise ParameterError("adjust", "the generic adjuster sets compensators of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")",
                             ",".join(unknown))
    names = [by_param[p] for p in boxes]
    if boxes_of(mech, names) != boxes:
        raise ParameterError("adjust", "the generic adjuster takes the file's boxes ("
                             + ", ".join(f"{n} {mech.compensators[n].low:g}.."
                                         f"{mech.compensators[n].high:g}" for n in names)
                             + ")", boxes)
    a = adjust(mech, values, output, names, objective)
    cols, _ = mech.columns(values)
    settings, at_bound, extras = {}, {}, {"failed_group": a.failed_group,
                                          "gap_bound": a.gap_bound, "loss": a.loss}
    for n, p in zip(a.names, a.parameters, strict=True):
        own = np.asarray(cols[p], float)[:, 0] if mech.compensators[n].mode == "offset" else 0.0
        settings[p] = own + a.settings[n]
        at_bound[p] = a.at_bound[n]
        extras[f"{p}_plateau_low"] = own + a.plateau_low[n]
        extras[f"{p}_plateau_high"] = own + a.plateau_high[n]
    return Adjusted(a.value, settings, a.status, at_bound, extras)


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


def failures_of(mech, fast: bool, failures=None):
    """Who names why a machine does not run: `failures` as given, else on the fast path the
    mechanism's plug-in (`Plugins.failure_table`), else `evaluated_failures`."""
    table = plugins(mech).failure_table if fast and failures is None else None
    if table is None:
        return failures or evaluated_failures

    def named(mech, values, output):
        why = table(mech, values)
        return why["status"], why["group"]
    return named
