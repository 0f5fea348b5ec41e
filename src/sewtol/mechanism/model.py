"""A mechanism read from a file, and its generic evaluation over (machines, angles) arrays.

evaluate(values) builds the groups in assembly order with sewtol.engine, over m machines (the
values given per parameter; the rest nominal) and the file's `samples` driving angles, then
reduces each output to one number per machine. Every machine gets a status: "ok",
"cannot_close" (some group misses at some sampled angle) or "dead_point" (a group's
transmission angle -- an rrr dyad's, or a spatial group's 90 deg minus its pressure angle --
falls below DEAD_POINT_DEG, where the joint can flip to its other assembly), and
the name of the first group that failed (assembly order; cannot_close before dead_point).
Outputs of a failed machine are NaN: counted, never dropped.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sewtol import engine
from sewtol.errors import ParameterError
from sewtol.mechanism.clearance import DYADS, Clearance, offset_names, on_body_view, pair_offsets, shifted
from sewtol.mechanism.groups import GROUPS
from sewtol.mechanism.outputs import OUTPUT_TYPES, line_distance_um, provide
from sewtol.mechanism.spec import Compensator, Group, Header, Output, Parameter, Spec
from sewtol.mechanisms import params as P
from sewtol.tolerances import ToleranceSet

if TYPE_CHECKING:
    import pandas as pd

DEAD_POINT_DEG = 1.0
# machines evaluated together: a (block, samples) complex array of a joint stays near
# BLOCK_CELLS * 16 bytes (1.5 MB at 720 samples), whatever `samples` is
BLOCK, BLOCK_CELLS = 128, 92_160
STATUSES = ("ok", "cannot_close", "dead_point")


@dataclass(frozen=True)
class State:
    """Everything built for m machines over the sampled angles (shape (m, samples))."""

    points: dict
    angles: dict
    closures: dict
    values: dict
    q_rad: np.ndarray
    rpm: float | None
    shape: tuple


@dataclass(frozen=True)
class Evaluation:
    """Outputs per machine, each machine's status and the group that failed ("" when ok)."""

    outputs: dict[str, np.ndarray]
    status: np.ndarray
    failed_group: np.ndarray

    def counts(self) -> dict[str, int]:
        c = {s: int(np.sum(self.status == s)) for s in STATUSES}
        c["n"] = int(self.status.size)
        return c

    def to_dataframe(self) -> pd.DataFrame:
        import pandas as pd

        f = pd.DataFrame(dict(self.outputs))
        f["status"] = self.status
        f["failed_group"] = self.failed_group
        return f


@dataclass(frozen=True)
class FileMechanism:
    path: str
    header: Header
    parameters: tuple[Parameter, ...]
    groups: tuple[Group, ...]
    outputs: tuple[Output, ...]
    compensators: dict[str, Compensator] = field(default_factory=dict)
    tolerance_sets: dict[str, ToleranceSet] = field(default_factory=dict)
    specs: tuple[Spec, ...] = ()
    clearances: tuple[Clearance, ...] = ()  # [[clearances]]: their offsets are pair parameters
    # [defaults] adjust: the compensators `sewtol run` adjusts when --adjust is not given
    default_adjust: tuple[str, ...] = ()

    @property
    def pair_parameters(self) -> tuple[Parameter, ...]:
        """The offset of each revolute pair with a clearance: the journal's centre from the
        bearing's, in the frame's axes (``JOINT_dx_mm``, ``JOINT_dy_mm``; nominal 0, where the
        model is the ideal one). `evaluate` and `state` take them beside the parameters; see
        `sewtol.mechanism.clearance` for where each pair's offset enters."""
        out = []
        for c in self.clearances:
            if c.pair == "revolute":
                for name in offset_names(c.joint):
                    out.append(Parameter(name, 0.0, "mm", "finite",
                                         f"offset of the journal in pair {c.joint} ({name[-5:-3]})"))
        return tuple(out)

    @property
    def name(self) -> str:
        return self.header.name

    @property
    def samples(self) -> int:
        return self.header.samples

    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def output_names(self) -> list[str]:
        return [o.name for o in self.outputs]

    def nominal_values(self) -> dict[str, float]:
        return {p.name: p.nominal for p in self.parameters}

    def override(self, **changes) -> FileMechanism:
        """A copy with new nominal values (checked by each parameter's rule)."""
        P.check_names(changes, self.parameter_names)
        params = []
        for p in self.parameters:
            if p.name in changes:
                P.check_rule(p.name, p.rule, float(changes[p.name]))
                p = dataclasses.replace(p, nominal=float(changes[p.name]))
            params.append(p)
        return dataclasses.replace(self, parameters=tuple(params))

    def parameter_record(self):
        """The nominal machine as a frozen dataclass (fields = parameter names), so the generic
        study machinery (tolerances.check_against, montecarlo.sample_machines) can use it."""
        return parameter_class(self)(**self.nominal_values())

    def output(self, name: str) -> Output:
        for o in self.outputs:
            if o.name == name:
                return o
        raise ParameterError("--output", "must name an output of the file: "
                             + ", ".join(self.output_names), name)

    def spec_of(self, output: str) -> Spec | None:
        """The file's [[specs]] entry of an output, None when the file gives it no limits."""
        return next((s for s in self.specs if s.output == output), None)

    def resolve_spec(self, output: str | None = None, upper: float | None = None,
                     lower: float | None = None) -> tuple[str, Spec | None, str | None]:
        """(output, spec, source) of a yield study: limits given here (the command line's
        --limit/--lower-limit) replace the file's spec of that output (source "command line");
        else the file's spec (source "file"), else none. The output defaults to the first
        output with limits given, else the first output of the file's [[specs]], else the first
        output."""
        given = upper is not None or lower is not None
        if output is None:
            output = self.specs[0].output if self.specs and not given else self.output_names[0]
        self.output(output)
        if given:
            return output, Spec(output, upper, lower), "command line"
        spec = self.spec_of(output)
        return output, spec, None if spec is None else "file"

    def angles_rad(self) -> np.ndarray:
        return 2.0 * np.pi * np.arange(self.samples) / self.samples

    # --- evaluation -------------------------------------------------------------------------

    def columns(self, values: dict | None = None) -> tuple[dict, int]:
        """Every parameter as an (m, 1) column: the given values, nominal for the rest."""
        values = dict(values or {})
        pairs = self.pair_parameters
        P.check_names(values, self.parameter_names + [p.name for p in pairs])
        sizes = {np.size(v) for v in values.values() if np.ndim(v) > 0}
        if len(sizes) > 1:
            raise ParameterError("values", "all arrays must have the same length", sorted(sizes))
        m = sizes.pop() if sizes else 1
        cols = {}
        for p in self.parameters + pairs:
            v = np.asarray(values.get(p.name, p.nominal), float)
            P.check_rule(p.name, p.rule, v)
            cols[p.name] = np.broadcast_to(v.reshape(-1, 1) if v.ndim else v, (m, 1))
        return cols, m

    @np.errstate(invalid="ignore", divide="ignore", over="ignore")
    def state(self, values: dict | None = None, q_rad=None) -> State:
        """Every point, angle and closure for the machines of `values` at driving angles q_rad
        (default: the file's samples); shapes (m, len(q_rad))."""
        cols, m = self.columns(values)
        q_rad = self.angles_rad() if q_rad is None else np.asarray(q_rad, float)
        q = engine.driving_angle(q_rad)
        shape = (m, q_rad.size)
        points, angles, closures = {}, {}, {}
        offsets = pair_offsets(self.clearances, cols)
        link1 = {}  # a dyad's joint with a clearance, as its link 1 holds it (see clearance.py)
        for g in self.groups:
            gt = GROUPS[g.type]
            seen = points
            if link1 and g.type == "on_body":
                seen = on_body_view(g, points, link1, self.groups)
            fields = resolved(g.fields, gt.fields, seen, angles, cols)
            r = offsets.get(g.name)
            if r is not None and g.type in DYADS:
                # the journal of link 2 sits r from link 1's: link 1 turns about p1 + r
                fields["p1"] = shifted(fields["p1"], r)
            made, closure = gt.builder(q, **fields)
            if r is not None and gt.produces == "point":
                if g.type in DYADS:
                    link1[g.name] = shifted(made, -r)
                else:
                    made = shifted(made, r)  # the next link's journal, r from this body's
            # a Motion's arrays are complex, an Angle's float; each shaped (machines, angles)
            dtype = complex if gt.produces == "point" else float
            (points if gt.produces == "point" else angles)[g.name] = type(made)(
                *(np.broadcast_to(np.asarray(a, dtype), shape) for a in vars(made).values()))
            if closure is not None:
                closures[g.name] = closure
        return State(points, angles, closures, cols, q_rad, self.header.rpm, shape)

    def status_of(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        return statuses(state.closures, state.shape)  # built in assembly order

    def evaluate(self, values: dict | None = None, outputs=None) -> Evaluation:
        """Outputs (one number per machine), status and failed group of the machines given by
        `values` (parameter name -> array of m values; the others nominal)."""
        names = self.output_names if outputs is None else list(outputs)
        chosen = [self.output(n) for n in names]
        cols, m = self.columns(values)
        parts = []
        block = max(1, min(BLOCK, BLOCK_CELLS // self.samples))
        for a in range(0, m, block):
            sub = {k: np.asarray(v)[a:a + block, 0] for k, v in cols.items()}
            parts.append(self._evaluate_block(sub, chosen))
        out = {o.name: np.concatenate([p[0][o.name] for p in parts]) for o in chosen}
        return Evaluation(out, np.concatenate([p[1] for p in parts]),
                          np.concatenate([p[2] for p in parts]))

    def curve(self, output: str, values: dict | None = None, q_rad=None) -> np.ndarray:
        """The per-angle quantity a line_deviation output reduces (its signed distance d, um)
        for the machines of `values` at driving angles q_rad (default the file's samples):
        shape (machines, angles); NaN rows where a machine does not run."""
        o = self.output(output)
        if o.type != "line_deviation":
            raise ParameterError("output", "must be a line_deviation output to give a curve",
                                 output)
        state = self.state(values, q_rad)
        status, _ = self.status_of(state)
        kwargs = resolved(o.fields, OUTPUT_TYPES[o.type].fields, state.points, state.angles,
                           state.values)
        with np.errstate(invalid="ignore"):
            d = np.broadcast_to(line_distance_um(state, **kwargs), state.shape)
        return np.where((status == "ok")[:, None], d, np.nan)

    def _evaluate_block(self, values, chosen):
        state = self.state(values)
        status, failed = self.status_of(state)
        ok = status == "ok"
        out = {}
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for o in chosen:
                # provide: a worker process that unpickled the file imports the kind's module
                ot = provide(o.kind) if o.type == "custom" else OUTPUT_TYPES[o.type]
                kwargs = resolved(o.fields, ot.fields, state.points, state.angles, state.values)
                y = np.asarray(ot.fn(state, **kwargs), float).reshape(-1)
                y = np.broadcast_to(y, (state.shape[0],))
                out[o.name] = np.where(ok, y, np.nan)
        return out, status, failed


def statuses(closures: dict, shape: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Each machine's status and the group that failed ("" when ok), over (machines..., angles)
    `shape`, from `closures` (group name -> engine.Closure, in assembly order): the first group
    that misses at some angle makes it "cannot_close", else the first whose transmission angle
    falls below DEAD_POINT_DEG makes it "dead_point"."""
    status = np.full(shape[:-1], "ok", dtype=object)
    failed = np.full(shape[:-1], "", dtype=object)
    for name, cl in closures.items():
        bad = ~np.all(np.broadcast_to(cl.miss_mm, shape) == 0.0, axis=-1) & (status == "ok")
        status[bad], failed[bad] = "cannot_close", name
    for name, cl in closures.items():
        if cl.transmission_deg is not None:
            t = np.broadcast_to(cl.transmission_deg, shape)
            dead = (np.min(t, axis=-1) < DEAD_POINT_DEG) & (status == "ok")
            status[dead], failed[dead] = "dead_point", name
    return status, failed


def resolved(fields: dict, kinds: dict, points: dict, angles: dict, values: dict) -> dict:
    """A group's or an output's fields as its function takes them: points and angles by name,
    a direction as the angle of P -> Q, expressions evaluated on `values`, choices as given."""
    out = {}
    for k, v in fields.items():
        kind = kinds[k][0]
        if kind == "point":
            out[k] = points[v]
        elif kind == "angle":
            out[k] = angles[v]
        elif kind == "direction":
            out[k] = engine.direction(points[v[0]], points[v[1]])
        elif kind in ("expr", "branch"):
            out[k] = np.asarray(v(values), float)
        else:
            out[k] = v
    return out


_CLASSES: dict = {}


def parameter_class(mech: FileMechanism):
    """A frozen dataclass whose fields are the file's parameters, checked by their rules."""
    key = (mech.name, tuple((p.name, p.rule) for p in mech.parameters))
    if key in _CLASSES:
        return _CLASSES[key]
    rules = {p.name: p.rule for p in mech.parameters}

    def __post_init__(self):
        P.freeze(self)
        for name, rule in rules.items():
            P.check_rule(name, rule, getattr(self, name))

    def override(self, **changes):
        return P.override(self, changes)

    cls = dataclasses.make_dataclass(
        f"{mech.name}_parameters", [(p.name, float) for p in mech.parameters], frozen=True,
        namespace={"__post_init__": __post_init__, "override": override})
    _CLASSES[key] = cls
    return cls
