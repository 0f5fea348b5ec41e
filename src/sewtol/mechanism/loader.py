"""Read and check a mechanism file (format sewtol-mechanism/1; docs/mechanism_files.md).

Every refusal is one ParameterError whose field reads FILE:LINE: WHERE, e.g.
"m.toml:31: [[groups]] M.r1: names 'LMX', which is not a parameter of the file (got 'LMX')".
Nothing in the file is executed: expressions go through mechanism.expressions.
"""

from __future__ import annotations

import functools
import importlib
import re

import numpy as np

from sewtol import costs, dependence, relations, selective, setting_error
from sewtol.errors import ParameterError, real
from sewtol.mechanism import expressions as X
from sewtol.mechanism.clearance import offset_names, parse_clearances
from sewtol.mechanism.groups import GROUPS
from sewtol.mechanism.lines import Locator
from sewtol.mechanism.outputs import OUTPUT_TYPES, OUTPUTS, provide, providers
from sewtol.mechanism.spec import (
    FORMAT,
    MODES,
    RULES,
    UNITS,
    Compensator,
    Group,
    Header,
    Output,
    Parameter,
    Spec,
)
from sewtol.mechanisms.params import check_names, check_rule
from sewtol.tolerances import Tolerance, ToleranceSet, parse_item, parse_toml, read_toml_text

MAX_BYTES = 1 << 20
NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MECH_NAME = re.compile(r"^[a-z0-9_]+$")
# groups whose Closure carries a transmission angle (a transmission output may name them)
TRANSMISSION_GROUPS = ("rrr", "spatial_rocker", "spatial_slider")
TOP_KEYS = ("format", "mechanism", "parameters", "groups", "outputs", "specs", "compensators",
            "tolerances", "clearances", "defaults")
DEFAULTS_KEYS = ("adjust",)
SPEC_KEYS = ("output", "upper", "lower", "doc")
MECH_KEYS = ("name", "title", "source", "assumptions", "samples", "rpm", "driver", "fast_path")
PARAM_KEYS = ("nominal", "unit", "rule", "doc")
MIN_SAMPLES, MAX_SAMPLES = 8, 100_000
RESERVED = set(X.FUNCTIONS) | set(X.CONSTANTS)


class _Ctx:
    def __init__(self, path: str, text: str):
        self.path = path
        self.text = text

    @functools.cached_property
    def loc(self) -> Locator:  # built only to place a refusal, after TOML has parsed
        return Locator(self.text)

    def fail(self, where_path: tuple, where: str, rule: str, value):
        raise ParameterError(f"{self.path}:{self.loc.line(*where_path)}: {where}", rule, value)


def load(path, overrides: dict | None = None):
    """The FileMechanism of a file; `overrides` (name -> value) replace nominal values."""
    return loads(read_toml_text(path, MAX_BYTES, "a mechanism file is a few pages"), str(path),
                 overrides)


@functools.cache
def builtin(name: str):
    """The FileMechanism of the built-in mechanism `name`, parsed once per process and named by
    its place in the package (the same on every machine); `override` makes changed copies."""
    from sewtol import mechanisms as M

    return loads(M.mechanism_file(name).read_text(), f"sewtol/mechanisms/{name}/{M.FILE}")


def loads(text: str, path: str = "<text>", overrides: dict | None = None):
    from sewtol.mechanism.model import FileMechanism

    ctx = _Ctx(path, text)
    data = parse_toml(text, lambda line: f"{path}:{line}")
    _known(ctx, data, (), "", TOP_KEYS)
    if data.get("format") != FORMAT:
        ctx.fail(("format",), "format", f'must be "{FORMAT}"', data.get("format"))
    header = _header(ctx, data.get("mechanism"))
    params = _parameters(ctx, data.get("parameters"), overrides or {})
    pnames = {p.name: p for p in params}
    groups = _groups(ctx, data.get("groups"), pnames)
    if header.driver is not None and not any(g.name == header.driver and g.type == "crank"
                                             for g in groups):
        ctx.fail(("mechanism", "driver"), "[mechanism] driver", "must name a crank group",
                 header.driver)
    outputs = _outputs(ctx, data.get("outputs"), pnames, groups, header)
    specs = _specs(ctx, data.get("specs", []), outputs)
    comps = _compensators(ctx, data.get("compensators", {}), pnames)
    default_adjust = _defaults(ctx, data.get("defaults", {}), comps)
    sets = _tolerance_sets(ctx, data.get("tolerances", {}), pnames)
    clearances = parse_clearances(data.get("clearances"), groups,
                                  lambda p: (f"{path}:{ctx.loc.line(*p)}: ", ctx.loc.line(*p)))
    for i, c in enumerate(clearances):
        taken = [n for n in offset_names(c.joint) if n in pnames] if c.pair == "revolute" else []
        if taken:  # a revolute pair's offsets are its pair parameters (clearance.py)
            ctx.fail(("clearances", i, "joint"), f"[[clearances]] #{i + 1}.joint",
                     f"its offset parameter {taken[0]} is a name of [parameters] already", c.joint)
    mech = FileMechanism(path=path, header=header, parameters=tuple(params),
                         groups=tuple(groups), outputs=tuple(outputs), compensators=comps,
                         tolerance_sets=sets, specs=specs, clearances=clearances,
                         default_adjust=default_adjust)
    if header.fast_path is not None:
        from sewtol.mechanism.fast_paths import fast_paths

        known = fast_paths()
        if header.fast_path not in known:
            ctx.fail(("mechanism", "fast_path"), "[mechanism] fast_path",
                     f"must name a built-in kernel: {', '.join(known)}", header.fast_path)
        problem = known[header.fast_path].check(mech)
        if problem:
            ctx.fail(("mechanism", "fast_path"), "[mechanism] fast_path",
                     f"the file does not reproduce the built-in {header.fast_path} model "
                     f"({problem}); remove fast_path or fix the file", header.fast_path)
    return mech


def _known(ctx, table, path, prefix, allowed, what="unknown key"):
    """Refuse the first key of `table` not in `allowed` (its place reads prefix + key)."""
    for k in table:
        if k not in allowed:
            ctx.fail(path + (k,), f"{prefix}{k}", f"{what}; allowed: {', '.join(allowed)}", k)


def _str(ctx, path, where, v, pattern=None, what="a string"):
    if not isinstance(v, str) or (pattern is not None and not pattern.match(v)):
        ctx.fail(path, where, f"must be {what}", v)
    return v


def _number(ctx, path, where, v):
    if not real(v, finite=True):
        ctx.fail(path, where, "must be a finite number", v)
    return float(v)


def _header(ctx, m) -> Header:
    if not isinstance(m, dict):
        ctx.fail(("mechanism",), "[mechanism]", "must be a table with at least name", m)
    _known(ctx, m, ("mechanism",), "[mechanism] ", MECH_KEYS)
    if "name" not in m:
        ctx.fail(("mechanism",), "[mechanism] name", "is required", None)
    name = _str(ctx, ("mechanism", "name"), "[mechanism] name", m["name"], MECH_NAME,
                "an identifier of [a-z0-9_]")
    for k in ("title", "source"):
        if k in m:
            _str(ctx, ("mechanism", k), f"[mechanism] {k}", m[k])
    assumptions = m.get("assumptions", [])
    if not isinstance(assumptions, list) or not all(isinstance(a, str) for a in assumptions):
        ctx.fail(("mechanism", "assumptions"), "[mechanism] assumptions",
                 "must be a list of strings", assumptions)
    samples = m.get("samples", 720)
    if isinstance(samples, bool) or not isinstance(samples, int) \
            or not MIN_SAMPLES <= samples <= MAX_SAMPLES:
        ctx.fail(("mechanism", "samples"), "[mechanism] samples",
                 f"must be a whole number in [{MIN_SAMPLES}, {MAX_SAMPLES}]", samples)
    rpm = m.get("rpm")
    if rpm is not None and not (_number(ctx, ("mechanism", "rpm"), "[mechanism] rpm", rpm) > 0):
        ctx.fail(("mechanism", "rpm"), "[mechanism] rpm", "must be positive", rpm)
    driver = m.get("driver")
    if driver is not None:
        _str(ctx, ("mechanism", "driver"), "[mechanism] driver", driver, NAME, "a group name")
    fast = m.get("fast_path")
    if fast is not None:
        _str(ctx, ("mechanism", "fast_path"), "[mechanism] fast_path", fast)
    return Header(name, m.get("title", ""), m.get("source", ""), tuple(assumptions), samples,
                  None if rpm is None else float(rpm), driver, fast)


def _parameters(ctx, table, overrides) -> list[Parameter]:
    if not isinstance(table, dict) or not table:
        ctx.fail(("parameters",), "[parameters]", "must be a table of at least one parameter",
                 table)
    out = []
    for name, spec in table.items():
        path = ("parameters", name)
        where = f"[parameters] {name}"
        if not NAME.match(name) or name in RESERVED:
            ctx.fail(path, where, "must be an identifier that is not a function or constant name "
                     f"({', '.join(sorted(RESERVED))})", name)
        if not isinstance(spec, dict):
            ctx.fail(path, where, "must be a table { nominal = ..., unit = ..., rule = ..., "
                     "doc = ... }", spec)
        _known(ctx, spec, path, f"{where}.", PARAM_KEYS)
        if "nominal" not in spec:
            ctx.fail(path, f"{where}.nominal", "is required", None)
        nominal = _number(ctx, path + ("nominal",), f"{where}.nominal", spec["nominal"])
        unit = spec.get("unit")
        if unit not in UNITS:
            ctx.fail(path + ("unit",), f"{where}.unit", f"must be one of {', '.join(UNITS)}",
                     unit)
        rule = spec.get("rule", "finite")
        if rule not in RULES:
            ctx.fail(path + ("rule",), f"{where}.rule", f"must be one of {', '.join(RULES)}",
                     rule)
        doc = spec.get("doc", "")
        _str(ctx, path + ("doc",), f"{where}.doc", doc)
        try:
            check_rule(name, rule, nominal)
        except ParameterError as exc:
            ctx.fail(path + ("nominal",), f"{where}.nominal", exc.rule, nominal)
        out.append(Parameter(name, nominal, unit, rule, doc, ctx.loc.line(*path)))
    check_names(overrides, [p.name for p in out])
    fixed = []
    for p in out:
        if p.name in overrides:
            v = float(overrides[p.name])
            check_rule(p.name, p.rule, v)
            p = Parameter(p.name, v, p.unit, p.rule, p.doc, p.line)
        fixed.append(p)
    return fixed


def _expr(ctx, path, where, v, pnames, kind="expr"):
    try:
        e = X.parse(v, pnames)
    except X.ExpressionError as exc:
        ctx.fail(path, where, f"{exc.rule}; allowed: {X.ALLOWED}" if "not allowed" in exc.rule
                 or "not an allowed" in exc.rule else exc.rule, v)
    with np.errstate(all="ignore"):
        at_nominal = e({n: pnames[n].nominal for n in e.names})
    if not np.isfinite(at_nominal):
        ctx.fail(path, where, f"must be finite; it is {at_nominal} at the nominal values", v)
    if kind == "branch":
        for n in e.names:
            if pnames[n].rule != "branch":
                ctx.fail(path, where, "must be +1, -1 or a parameter with rule = \"branch\"", v)
        if e.constant and e({}) not in (1.0, -1.0):
            ctx.fail(path, where, "must be +1 (left) or -1 (right)", v)
    return e


def _reference(ctx, fpath, where, kind, v, defined, earlier):
    """A point, angle or direction field: names `defined` (name -> "point" | "angle") by the
    groups (`earlier`: by the groups before this one)."""
    by, many = ("an earlier group", "earlier groups") if earlier else ("a group", "groups")
    if kind == "direction":
        if not (isinstance(v, list) and len(v) == 2
                and all(isinstance(s, str) and defined.get(s) == "point" for s in v)):
            ctx.fail(fpath, where, f"must be [P, Q], two points defined by {many}", v)
        if earlier and v[0] == v[1]:
            ctx.fail(fpath, where, "must join two different points", v)
        return tuple(v)
    if not isinstance(v, str) or defined.get(v) != kind:
        what = ""
        if earlier:
            what = (f" (no earlier group defines {v!r})" if not isinstance(v, str) or v not in defined
                    else f" ({v} is a {defined[v]}, not a {kind})")
        ctx.fail(fpath, where, f"must name a {kind} defined by {by}{what}", v)
    return v


def _fields(ctx, path, where, entry, type_name, spec, one_of, value) -> dict:
    """The fields of a [[groups]] or [[outputs]] entry by its type's `spec` (name -> (kind,
    default[, choices])): exactly one of each `one_of`, every required one given, defaults
    filled in; value(path, where, kind, v[, choices]) checks and resolves a given one."""
    for group_of in one_of:
        given = [k for k in group_of if k in entry]
        if len(given) != 1:
            ctx.fail(path, where, f"give exactly one of {', '.join(group_of)}", given)
    fields = {}
    for k, (kind, default, *choices) in spec.items():
        if k in entry:
            fields[k] = value(path + (k,), f"{where}.{k}", kind, entry[k], *choices)
        elif default is None and not any(k in o for o in one_of):
            ctx.fail(path, f"{where}.{k}", f"is required for type {type_name}", None)
        elif default is not None:
            fields[k] = X.parse(default) if kind in ("expr", "branch") else default
    return fields


def _groups(ctx, table, pnames) -> list[Group]:
    if not isinstance(table, list) or not table:
        ctx.fail(("groups",), "[[groups]]", "at least one [[groups]] table is required", table)
    points: dict[str, str] = {}  # defined name -> "point" | "angle"
    out = []
    cranks = 0
    for i, g in enumerate(table):
        path = ("groups", i)
        if not isinstance(g, dict):
            ctx.fail(path, f"[[groups]] #{i + 1}", "must be a table", g)
        gtype = g.get("type")
        if gtype not in GROUPS:
            ctx.fail(path + ("type",), f"[[groups]] #{i + 1}.type",
                     f"must be one of {', '.join(GROUPS)}", gtype)
        gt = GROUPS[gtype]
        if gt.requires:
            try:
                importlib.import_module(gt.requires)
            except ImportError:
                ctx.fail(path + ("type",), f"[[groups]] #{i + 1}.type", f"needs {gt.requires}, "
                         "which this build of sewtol does not have", gtype)
        name = g.get("name")
        if not isinstance(name, str) or not NAME.match(name):
            ctx.fail(path + ("name",), f"[[groups]] #{i + 1}.name", "must be an identifier",
                     name)
        where = f"[[groups]] {name}"
        if name in points or name in pnames:
            ctx.fail(path + ("name",), f"{where}.name", "is already defined (point, angle or "
                     "parameter names must be unique)", name)
        _known(ctx, g, path, f"{where}.", ("type", "name", *gt.fields),
               f"unknown key for type {gtype}")

        def value(fpath, fwhere, kind, v):
            if kind in ("point", "angle", "direction"):
                return _reference(ctx, fpath, fwhere, kind, v, points, earlier=True)
            return _expr(ctx, fpath, fwhere, v, pnames, kind)

        fields = _fields(ctx, path, where, g, gtype, gt.fields, gt.one_of, value)
        if gtype == "crank":
            cranks += 1
        out.append(Group(gtype, name, fields, ctx.loc.line(*path)))
        points[name] = gt.produces
    if cranks == 0:
        ctx.fail(("groups",), "[[groups]]", "at least one crank group is required (it carries "
                 "the driving angle q)", [g.type for g in out])
    return out


def _outputs(ctx, table, pnames, groups, header) -> list[Output]:
    if table is None:
        table = []
    if not isinstance(table, list):
        ctx.fail(("outputs",), "[[outputs]]", "must be an array of tables", table)
    defined = {g.name: "angle" if GROUPS[g.type].produces == "angle" else "point"
               for g in groups}
    closures = {g.name for g in groups if g.type in TRANSMISSION_GROUPS}
    out = []
    for i, o in enumerate(table):
        path = ("outputs", i)
        if not isinstance(o, dict):
            ctx.fail(path, f"[[outputs]] #{i + 1}", "must be a table", o)
        name = o.get("name")
        if not isinstance(name, str) or not NAME.match(name):
            ctx.fail(path + ("name",), f"[[outputs]] #{i + 1}.name",
                     "must be an identifier with its unit suffix, e.g. SumDelta_um", name)
        where = f"[[outputs]] {name}"
        if any(x.name == name for x in out):
            ctx.fail(path + ("name",), f"{where}.name", "is already used by another output",
                     name)
        otype = o.get("type")
        if otype == "custom":
            kind = o.get("kind")
            ot = provide(kind) if isinstance(kind, str) else None
            if ot is None:
                ctx.fail(path + ("kind",), f"{where}.kind", "must name a registered output kind ("
                         + (", ".join(sorted(set(OUTPUTS) | set(providers())))
                            or "none registered") + ")", kind)
        elif otype in OUTPUT_TYPES:
            kind = ""
            ot = OUTPUT_TYPES[otype]
        else:
            ctx.fail(path + ("type",), f"{where}.type",
                     f"must be one of {', '.join((*OUTPUT_TYPES, 'custom'))}", otype)
        base = ("name", "unit", "type", "doc") + (("kind",) if otype == "custom" else ())
        _known(ctx, o, path, f"{where}.", (*base, *ot.fields), f"unknown key for type {otype}")
        unit = _str(ctx, path + ("unit",), f"{where}.unit", o.get("unit"),
                    what="a string (the unit)")
        doc = o.get("doc", "")
        _str(ctx, path + ("doc",), f"{where}.doc", doc)
        if ot.needs_rpm and header.rpm is None:
            ctx.fail(path + ("type",), f"{where}.type", "needs rpm in [mechanism]", otype)

        def value(fpath, fwhere, kind, v, choices):
            if kind in ("point", "angle", "direction"):
                return _reference(ctx, fpath, fwhere, kind, v, defined, earlier=False)
            if kind == "group" and v not in closures:
                ctx.fail(fpath, fwhere, "must name a group with a transmission angle, an rrr, "
                         f"spatial_rocker or spatial_slider group ({', '.join(sorted(closures))})",
                         v)
            if kind == "choice" and v not in choices:
                ctx.fail(fpath, fwhere, f"must be one of {', '.join(choices)}", v)
            return v if kind in ("group", "choice") else _expr(ctx, fpath, fwhere, v, pnames)

        fields = _fields(ctx, path, where, o, otype, ot.fields, ot.one_of, value)
        out.append(Output(name, unit, otype, doc, fields, kind, ctx.loc.line(*path)))
    return out


def _specs(ctx, table, outputs) -> tuple[Spec, ...]:
    if not isinstance(table, list):
        ctx.fail(("specs",), "[[specs]]", "must be an array of tables", table)
    names = [o.name for o in outputs]
    out = []
    for i, s in enumerate(table):
        path = ("specs", i)
        if not isinstance(s, dict):
            ctx.fail(path, f"[[specs]] #{i + 1}", "must be a table", s)
        _known(ctx, s, path, f"[[specs]] #{i + 1}.", SPEC_KEYS)
        output = s.get("output")
        if output not in names:
            ctx.fail(path + ("output",), f"[[specs]] #{i + 1}.output", "must name an output of "
                     "the file (" + (", ".join(names) or "it has none") + ")", output)
        where = f"[[specs]] {output}"
        if any(x.output == output for x in out):
            ctx.fail(path + ("output",), f"{where}.output", "has a spec already (one [[specs]] "
                     "per output)", output)
        doc = _str(ctx, path + ("doc",), f"{where}.doc", s.get("doc", ""))
        try:
            out.append(Spec(output, s.get("upper"), s.get("lower"), doc, ctx.loc.line(*path)))
        except ParameterError as exc:
            key = exc.field if exc.field in s else None
            ctx.fail(path + ((key,) if key else ()), f"{where}.{exc.field}", exc.rule, exc.value)
    return tuple(out)


COMP_KEYS = ("parameter", "low", "high", "step", "resolution", "setting_error", "mode")
MAX_STEPS = 10_000


def _compensators(ctx, table, pnames) -> dict[str, Compensator]:
    if not isinstance(table, dict):
        ctx.fail(("compensators",), "[compensators]", "must be a table of [compensators.NAME]",
                 table)
    out = {}
    for name, c in table.items():
        path = ("compensators", name)
        where = f"[compensators.{name}]"
        if not isinstance(c, dict):
            ctx.fail(path, where, "must be a table with parameter, low, high", c)
        _known(ctx, c, path, f"{where} ", COMP_KEYS)
        p = c.get("parameter")
        if p not in pnames:
            ctx.fail(path + ("parameter",), f"{where} parameter", "must name a parameter", p)
        if pnames[p].rule == "branch":
            ctx.fail(path + ("parameter",), f"{where} parameter", "must not be a branch sign", p)
        low = _number(ctx, path + ("low",), f"{where} low", c.get("low"))
        high = _number(ctx, path + ("high",), f"{where} high", c.get("high"))
        if not low < high:
            ctx.fail(path + ("high",), f"{where} high", "must be above low", (low, high))
        step = c.get("step")
        if step is not None:
            step = _number(ctx, path + ("step",), f"{where} step", step)
            if not 0 < step <= high - low or (high - low) / step > MAX_STEPS:
                ctx.fail(path + ("step",), f"{where} step", "must be positive, at most "
                         f"high - low = {high - low:g} and give at most {MAX_STEPS} settings",
                         step)
        extra = {}
        if "resolution" in c:
            extra["resolution"] = _number(ctx, path + ("resolution",), f"{where} resolution",
                                          c["resolution"])
            if extra["resolution"] < 0:
                ctx.fail(path + ("resolution",), f"{where} resolution", "must be >= 0",
                         extra["resolution"])
        if "setting_error" in c:
            err = c["setting_error"]
            if not isinstance(err, dict):
                err = _number(ctx, path + ("setting_error",), f"{where} setting_error", err)
            try:
                extra["setting_error"] = setting_error.parse(err, f"{where} setting_error")
            except ParameterError as exc:
                ctx.fail(path + ("setting_error",), exc.field, exc.rule, exc.value)
        mode = c.get("mode", "absolute")
        if mode not in MODES:
            ctx.fail(path + ("mode",), f"{where} mode", f"must be one of {', '.join(MODES)}",
                     mode)
        out[name] = Compensator(name, p, low, high, ctx.loc.line(*path), step, mode=mode,
                                **extra)
    return out


def _defaults(ctx, table, comps) -> tuple[str, ...]:
    """[defaults] adjust = ["NAME", ...]: the compensators `sewtol run` adjusts on each machine
    when --adjust is not given (`--adjust none`: none); distinct names of [compensators.NAME]."""
    if not isinstance(table, dict):
        ctx.fail(("defaults",), "[defaults]", "must be a table", table)
    _known(ctx, table, ("defaults",), "[defaults] ", DEFAULTS_KEYS)
    if "adjust" not in table:
        return ()
    names = table["adjust"]
    where, path = "[defaults] adjust", ("defaults", "adjust")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        ctx.fail(path, where, "must be a list of one or more [compensators.NAME] names", names)
    for n in names:
        if n not in comps:
            ctx.fail(path, where, "must name compensators of the file ("
                     + (", ".join(comps) or "it has none") + ")", n)
    if len(set(names)) != len(names):
        ctx.fail(path, where, "names a compensator twice", names)
    return tuple(names)


def _tolerance_sets(ctx, table, pnames) -> dict[str, ToleranceSet]:
    if not isinstance(table, dict):
        ctx.fail(("tolerances",), "[tolerances]", "must be a table of [tolerances.NAME]", table)
    out = {}
    for set_name, body in table.items():
        path = ("tolerances", set_name)
        if not isinstance(body, dict):
            ctx.fail(path, f"[tolerances.{set_name}]", "must be a table", body)
        items = []
        desc = ""
        for param, spec in body.items():
            where = f"[tolerances.{set_name}] {param}"
            if param == "description":
                desc = _str(ctx, path + (param,), where, spec)
                continue
            if param in dependence.KEYS or param in (relations.KEY, selective.KEY, costs.KEY):
                continue
            if param not in pnames:
                ctx.fail(path + (param,), where, "must name a parameter of the file", param)
            if pnames[param].rule == "branch":
                ctx.fail(path + (param,), where, "a branch sign is never toleranced", param)
            try:
                if isinstance(spec, list):
                    if len(spec) != 2:
                        raise ParameterError(param, "must be [lower, upper]", spec)
                    items.append(Tolerance(param, *(_number(ctx, path + (param,), where, v)
                                                    for v in spec)))
                else:
                    items.append(parse_item(set_name, param, spec))
            except ParameterError as exc:
                ctx.fail(path + (param,), where, exc.rule, spec)
        try:
            tied = dependence.parse(set_name, body, [t.param for t in items])
            limited = relations.parse(set_name, body, [t.param for t in items])
            sorted_ = selective.parse(set_name, body, [t.param for t in items])
            priced = costs.parse(set_name, body, [t.param for t in items])
        except ParameterError as exc:
            ctx.fail(path, f"[tolerances.{set_name}]", f"{exc.field}: {exc.rule}", exc.value)
        out[set_name] = ToleranceSet(set_name, tuple(items), desc, dependence=tied,
                                     relations=limited, selective=sorted_, cost=priced)
    return out
