"""`sewtol run FILE.toml STUDY`: the studies of sewtol.studies.generic on a mechanism file.

A file that names `fast_path = "needle_208"` (and passed the loader's check that it reproduces
the built-in needle drive) runs scan, worst-case, montecarlo, sobol, ppm and allocation through
the very code of `sewtol needle STUDY` (same bytes for the same flags) unless `--path generic`
is given or a flag asks what the needle command cannot answer (`_fast_path_refusal`; the flag
mapping is `_needle_namespace`, documented in docs/mechanism_files.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sewtol.errors import ParameterError

STUDIES = ("nominal", "scan", "montecarlo", "sobol", "worst-case", "ppm", "allocation", "report")
RUN_FORMATS = ("text", "table", "json", "csv")
DEFAULT_N = {"montecarlo": 2000, "sobol": 256, "ppm": 20000, "allocation": 2000, "report": 1000}
# --target: the smallest probability ppm must resolve; the yield allocation must keep
DEFAULT_TARGET = {"ppm": 1e-6, "allocation": 0.9973}
# which flags each study reads; any other given flag is refused in one line
USES = {"nominal": (), "scan": ("output", "tolerances", "adjust", "objective"),
        "worst-case": ("output", "tolerances", "adjust", "objective"),
        "montecarlo": ("output", "tolerances", "n", "seed", "limit", "n_jobs", "adjust",
                       "objective"),
        "sobol": ("output", "tolerances", "n", "seed"),
        "ppm": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "method", "target",
                "adjust", "n_jobs", "objective"),
        "allocation": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "target",
                       "weight", "adjust", "objective"),
        "report": ("output", "tolerances", "n", "seed", "limit", "lower_limit")}


def add_run(sub, parser_class=None) -> None:
    p = sub.add_parser("run", help="a study of a mechanism file (docs/mechanism_files.md)")
    p.add_argument("file", metavar="FILE.toml",
                   help="mechanism file (format sewtol-mechanism/1), or the name of a built-in "
                        "mechanism (sewtol mechanisms)")
    p.add_argument("study", choices=STUDIES)
    p.add_argument("--output", default=None, metavar="NAME",
                   help="the output studied (default: all for nominal/scan/montecarlo, the "
                        "first for worst-case/sobol)")
    p.add_argument("--tolerances", default=None, metavar="SET|FILE.toml[:SET]",
                   help="a [tolerances.SET] of the file (default: its first) or a tolerance file")
    p.add_argument("--n", type=int, default=None,
                   help="machines (montecarlo 2000, allocation 2000 per trial scale, report "
                        "1000), base samples (sobol, 256) or model calls (ppm, 20000)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--limit", type=float, default=None,
                   help="upper limit of --output (default the first output) for the yield")
    p.add_argument("--n-jobs", type=int, default=None, help="parallel workers (montecarlo)")
    p.add_argument("--adjust", default=None, metavar="COMPENSATOR[,COMPENSATOR...]",
                   help="add the adjusted case: --output (default the first) minimised over "
                        "these [compensators.NAME] of the file (1 to 3, jointly) on each machine")
    p.add_argument("--objective", default=None, metavar="minimise|target=T|centre=L,U",
                   help="with --adjust: minimise the output (default), bring it to T, or centre "
                        "it in [L, U]")
    p.add_argument("--lower-limit", type=float, default=None,
                   help="lower limit of --output (ppm, allocation, report; with or without "
                        "--limit)")
    p.add_argument("--method", choices=("auto", "montecarlo", "mc", "subset", "nais"),
                   default=None,
                   help="ppm: auto (Monte-Carlo if n * target >= 10, else subset simulation), "
                        "montecarlo (or mc), subset or nais")
    p.add_argument("--target", type=float, default=None,
                   help="ppm: the smallest probability to resolve (default 1e-6); allocation: "
                        "the yield to keep (default 0.9973)")
    p.add_argument("--weight", action="append", default=None, metavar="NAME=W",
                   help="allocation: tolerance NAME scales as W times the common scale "
                        "(repeatable; default 1)")
    p.add_argument("--format", choices=RUN_FORMATS, default="text")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write the tables, the result and run.json here")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override a nominal value of the file (repeatable)")
    p.add_argument("--path", choices=("auto", "generic"), default="auto",
                   help="auto: a file with fast_path = \"needle_208\" runs scan, worst-case, "
                        "montecarlo, sobol, ppm and allocation as `sewtol needle STUDY` does "
                        "(exact SumDelta, beta searched by the needle's optimiser) where its "
                        "flags allow; generic: always the sampled studies of the file")
    p.set_defaults(func=cmd_run, resume=False, progress=False, scheduler=None)


def parse_sets(items) -> dict:
    """--set NAME=VALUE pairs (the loader checks the names and each parameter's rule)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError("--set", "must be NAME=VALUE", item)
        name, _, text = item.partition("=")
        name = name.strip()
        try:
            out[name] = float(text)
        except ValueError:
            raise ParameterError(name, "must be a number", text) from None
    return out


def resolve_tolerances(mech, spec):
    """A set of the file by name (default its first), or FILE.toml / FILE.toml:SET."""
    from sewtol.tolerances import resolve

    sets = mech.tolerance_sets
    if spec is None:
        if not sets:
            raise ParameterError("--tolerances", "the file has no [tolerances.NAME] set; give a "
                                 "tolerance file FILE.toml", None)
        return next(iter(sets.values()))
    if spec in sets:
        return sets[spec]
    if ".toml" in spec:
        return resolve(spec, {}, mech.parameter_names)
    raise ParameterError("--tolerances", "must be a set of the file ("
                         + (", ".join(sets) or "it has none") + ") or FILE.toml[:SET]", spec)


def _check_flags(args) -> None:
    used = USES[args.study]
    for key, flag in (("output", "--output"), ("tolerances", "--tolerances"), ("n", "--n"),
                      ("seed", "--seed"), ("limit", "--limit"), ("n_jobs", "--n-jobs"),
                      ("adjust", "--adjust"), ("lower_limit", "--lower-limit"),
                      ("method", "--method"), ("target", "--target"), ("weight", "--weight"),
                      ("objective", "--objective")):
        value = getattr(args, key)
        if value is not None and key not in used:
            raise ParameterError(flag, f"is not used by `run {args.study}`", value)
    if args.objective is not None and args.adjust is None:
        raise ParameterError("--objective", "needs --adjust", args.objective)
    if args.n is None and args.study in DEFAULT_N:
        args.n = DEFAULT_N[args.study]
    args.seed = 0 if args.seed is None else args.seed
    args.n_jobs = 1 if args.n_jobs is None else args.n_jobs
    if args.study == "montecarlo" and args.n < 2:
        raise ParameterError("--n", "must be >= 2", args.n)
    _check_yield_flags(args)


def _check_yield_flags(args) -> None:
    """The flags of ppm, allocation and report, before anything runs."""
    import math

    if args.study not in ("ppm", "allocation", "report"):
        return
    if args.study in DEFAULT_TARGET:
        if args.target is None:
            args.target = DEFAULT_TARGET[args.study]
        if not (math.isfinite(args.target) and 0 < args.target < 1):
            what = "probability" if args.study == "ppm" else "yield"
            raise ParameterError("--target", f"must be a {what} strictly between 0 and 1",
                                 args.target)
        if args.limit is None and args.lower_limit is None:
            raise ParameterError("--limit", f"`run {args.study}` needs --limit and/or "
                                 "--lower-limit", None)
    for flag, v in (("--limit", args.limit), ("--lower-limit", args.lower_limit)):
        if v is not None and not math.isfinite(v):
            raise ParameterError(flag, "must be a finite number", v)
    if args.limit is not None and args.lower_limit is not None \
            and not args.lower_limit < args.limit:
        raise ParameterError("--lower-limit", f"must be below --limit {args.limit:g}",
                             args.lower_limit)
    minimum = {"ppm": 100, "allocation": 10, "report": 2}[args.study]
    if args.n < minimum:
        raise ParameterError("--n", f"must be >= {minimum} for `run {args.study}`", args.n)
    if args.study == "ppm":
        args.method = {None: "auto", "mc": "montecarlo"}.get(args.method, args.method)
    if args.study == "report" and not args.out:
        raise ParameterError("--out", "`run report` needs --out DIR, the report's folder", None)


def load_mechanism(text: str, overrides: dict | None = None):
    """The FileMechanism of FILE.toml as given, or of the built-in mechanism of that name: a
    path that exists, or has a suffix or a folder, is a path; anything else must be a built-in
    name. A built-in file is named by its place in the package (the same on every machine)."""
    from sewtol import mechanisms as M
    from sewtol.mechanism import load
    from sewtol.mechanism.loader import loads

    p = Path(text)
    if p.exists() or p.suffix or len(p.parts) > 1:
        return load(p, overrides)
    if text in M.names():
        return loads(M.mechanism_file(text).read_text(),
                     f"sewtol/mechanisms/{text}/{M.FILE}", overrides)
    raise ParameterError("FILE.toml", "is neither a file nor a built-in mechanism ("
                         + ", ".join(M.names()) + ")", text)


def add_mechanisms(sub) -> None:
    p = sub.add_parser("mechanisms", help="the built-in mechanisms: name, file, docs, fast path")
    p.add_argument("--format", choices=("text", "csv", "json"), default="text")
    p.set_defaults(func=cmd_mechanisms)


def mechanisms_table():
    """One row per built-in mechanism: its name, title, file, docs page, fast path and custom
    output kinds (what `sewtol mechanisms` prints)."""
    import tomllib

    import pandas as pd

    from sewtol import mechanisms as M

    root = Path(M.__file__).parent
    fast, kinds = M.declared("FAST_PATHS"), M.declared("OUTPUT_KINDS")
    rows = []
    for name in M.names():
        head = tomllib.loads(M.mechanism_file(name).read_text())["mechanism"]
        own = f"sewtol.mechanisms.{name}."
        rows.append({"name": name, "title": head.get("title", ""),
                     "file": str(M.mechanism_file(name).relative_to(root.parent.parent)),
                     "docs": str((M.folder(name) / M.DOCS).relative_to(root.parent.parent)),
                     "fast_path": ", ".join(k for k, v in fast.items() if v.startswith(own)),
                     "output_kinds": ", ".join(k for k, v in kinds.items()
                                               if v.startswith(own))})
    return pd.DataFrame(rows)


def cmd_mechanisms(args) -> None:
    from sewtol.cli import emit

    frame = mechanisms_table()
    fmt = "table" if args.format == "text" else args.format
    emit(fmt, obj={"mechanisms": frame.to_dict("records")}, frame=frame)


def cmd_run(args) -> None:
    from sewtol.cli import _check_study
    from sewtol.studies import generic as G

    _check_flags(args)
    _check_study(args)
    mech = load_mechanism(args.file, parse_sets(args.set))
    fmt = "table" if args.format == "text" else args.format
    if args.output is not None:
        mech.output(args.output)
    args.path_reason = _fast_path_refusal(args, mech)  # None: the needle_208 fast path
    if args.study == "nominal":
        res = G.nominal(mech)
        return _finish(args, fmt, mech, None, res.to_dict(), {"nominal": res.to_dataframe()},
                       res.to_dataframe())
    tolerances = resolve_tolerances(mech, args.tolerances)
    if args.path_reason is None:
        args.path_reason = _tolerances_refusal(tolerances)
    if args.path_reason is None:
        return _needle_study(args, mech, tolerances)
    if mech.header.fast_path == "needle_208" and args.path == "auto" \
            and args.study in FAST_PATH_STUDIES:
        print(f"sewtol: note: `run {args.study}` takes the generic sampled path, not the "
              f"needle_208 fast path: {args.path_reason}", file=sys.stderr)
    outputs = None if args.output is None else [args.output]
    if args.study == "scan":
        res = _as_flags(G.scan, mech, tolerances, outputs, args.adjust, args.objective)
        return _finish(args, fmt, mech, tolerances, res.to_dict(), {"scan": res.rows}, res.rows)
    if args.study == "worst-case":
        res = _as_flags(G.worst_case, mech, tolerances, args.output or mech.output_names[0],
                        100, args.adjust, args.objective)
        return _finish(args, fmt, mech, tolerances, res.to_dict(), {"worst_case": res.rows},
                       res.rows)
    if args.study == "sobol":
        res = _as_flags(G.sobol, mech, tolerances, args.output or mech.output_names[0], args.n,
                        args.seed)
        obj = {"mechanism": mech.name, "tolerances": tolerances.name, "n": res.n,
               "seed": res.seed, "output": args.output or mech.output_names[0],
               "rows": res.to_records(), "convergence": res.convergence.to_dict("records")}
        return _finish(args, fmt, mech, tolerances, obj,
                       {"indices": res.indices, "convergence": res.convergence},
                       res.to_dataframe())
    if args.study in ("ppm", "allocation", "report"):
        return _yield_study(args, fmt, mech, tolerances)
    res = _as_flags(G.montecarlo, mech, tolerances, args.n, args.seed, outputs, args.limit,
                    args.output, args.n_jobs, False, G.CHUNK, args.adjust, args.objective)
    return _finish(args, fmt, mech, tolerances, res.to_dict(),
                   {"machines": res.machines, "summary": res.summary_frame()},
                   res.summary_frame())


def _as_flags(fn, *a):
    from sewtol.cli import FLAGS

    flags = {**FLAGS, "adjust": "--adjust", "limit": "--limit", "lower_limit": "--lower-limit",
             "objective": "--objective",
             "target": "--target", "weights": "--weight"}
    try:
        return fn(*a)
    except ParameterError as exc:
        if exc.field in flags:
            raise ParameterError(flags[exc.field], exc.rule, exc.value) from None
        raise


def _run_context(args, mech, tolerances) -> dict:
    """What decides a `run` study's numbers, carried by its JSON (its CSVs: run.json beside
    them); seed and n are null where the study draws nothing (nominal, scan, worst-case)."""
    draws = args.study in DEFAULT_N
    return {"mechanism": mech.name, "mechanism_file": str(args.file),
            "tolerances": None if tolerances is None else tolerances.name,
            "seed": args.seed if draws else None, "n": args.n if draws else None,
            "strategy": args.adjust or "none", "output": args.output,
            "limit": args.limit, "lower_limit": args.lower_limit,
            "path": "generic", "path_reason": getattr(args, "path_reason", None)}


def _finish(args, fmt, mech, tolerances, obj, frames, frame) -> None:
    from sewtol.cli import _write_outputs, emit
    from sewtol.provenance import now, version_record

    obj = {**obj, "context": _run_context(args, mech, tolerances)}

    if args.out:
        inputs = {"study": f"run {args.study}", "mechanism_file": str(args.file),
                  "mechanism": mech.name, "n": args.n, "seed": args.seed,
                  "output": args.output, "limit": args.limit, "adjust": args.adjust,
                  **{k: getattr(args, k) for k in ("lower_limit", "method", "target", "weight",
                                                   "objective")
                     if getattr(args, k, None) is not None},
                  "params": mech.nominal_values(),
                  "tolerances": None if tolerances is None else
                  {"name": tolerances.name, "items": tolerances.as_dict()},
                  **version_record()}
        _write_outputs(args, args.study.replace("-", "_"), inputs, now(), obj, frames, None)
    emit(fmt, obj=obj, frame=frame)


# --- the needle_208 fast path ------------------------------------------------------------------

FAST_PATH_STUDIES = ("scan", "worst-case", "montecarlo", "sobol", "ppm", "allocation")
# the needle commands that report the fixed and the adjusted case together (so with and without
# --adjust beta); the others run `--adjust none` without --adjust and beta adjusted with it
BOTH_CASES = ("worst-case", "montecarlo", "sobol")


def sumdelta_outputs(mech) -> list[str]:
    """The file's SumDelta outputs (a line_deviation of E, sum_extremes): the loader checked
    each equals the built-in SumDelta, so the fast path answers --output NAME for these."""
    return [o.name for o in mech.outputs if o.type == "line_deviation"
            and o.fields["point"] == "E" and o.fields["measure"] == "sum_extremes"]


def _fast_path_refusal(args, mech) -> str | None:
    """None when `run FILE STUDY` runs on the needle_208 fast path, else why it does not."""
    from sewtol.adjuster import compensators_of
    from sewtol.mechanisms.needle_208 import beta as sb

    if args.path == "generic":
        return "--path generic"
    if mech.header.fast_path != "needle_208":
        return "the file declares no fast path"
    if args.study not in FAST_PATH_STUDIES:
        return f"`run {args.study}` has no fast path"
    if args.output is not None and args.output not in sumdelta_outputs(mech):
        return (f"--output {args.output} is not the SumDelta output "
                f"({', '.join(sumdelta_outputs(mech))}) the needle commands compute")
    if args.adjust is not None:
        comps = _as_flags(compensators_of, mech, args.adjust)  # as the generic studies refuse
        comp = comps[0]
        if len(comps) > 1:
            return f"--adjust {args.adjust}: the needle commands adjust beta alone"
        if args.objective not in (None, "minimise"):
            return f"--objective {args.objective}: the needle commands minimise SumDelta"
        if comp.parameter != "beta":
            return (f"--adjust {args.adjust} sets {comp.parameter}; the needle commands adjust "
                    "beta")
        if args.study == "allocation" and (comp.low, comp.high) != sb.DEFAULT_RANGE_DEG:
            return (f"--adjust {args.adjust} searches beta in [{comp.low:g}, {comp.high:g}] deg; "
                    "`needle allocation` searches 10 35")
    if getattr(args, "lower_limit", None) is not None:
        return "--lower-limit: the needle commands limit SumDelta from above only"
    if args.limit is not None and not args.limit > 0:
        return f"--limit {args.limit:g}: the needle's SumDelta limit is a positive number of um"
    if args.study == "allocation" and args.limit is not None \
            and args.limit != sb.DEFAULT_LIMIT_UM:
        return (f"--limit {args.limit:g}: `needle allocation` keeps SumDelta within "
                f"{sb.DEFAULT_LIMIT_UM:g} um")
    if args.weight is not None:
        return "--weight: `needle allocation` weighs every tolerance alike"
    if args.out and args.study in ("worst-case", "allocation"):
        return f"--out: `needle {args.study}` writes no study folder"
    return None


def _tolerances_refusal(tolerances) -> str | None:
    """The needle commands vary only the built-in model's parameters."""
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.mechanisms.params import field_names

    other = [p for p in tolerances.active().params if p not in field_names(Needle208)]
    if other:
        return (f"--tolerances {tolerances.name} varies {', '.join(other)}, which the built-in "
                "needle model does not have")
    return None


def _needle_namespace(args, mech, tolerances=None):
    """`run`'s flags as the arguments of `sewtol needle STUDY` (the file's nominal machine and
    tolerance set ride along as nominal_params and tolerance_set)."""
    from sewtol.mechanisms.needle_208.fast_path import _needle_params

    study = args.study
    beta_range = None
    if args.adjust is not None:
        comp = mech.compensators[args.adjust]
        beta_range = [float(comp.low), float(comp.high)]
    if study in BOTH_CASES:
        adjust = None  # the needle command's default: fixed and adjusted
    elif args.adjust is None:
        adjust = "none"
    else:  # beta adjusted: the default of needle scan and allocation, --adjust beta of ppm
        adjust = "beta" if study == "ppm" else None
    draws = study in ("montecarlo", "sobol", "ppm", "allocation")
    ns = argparse.Namespace(
        set=None, frame=None, guide_shift_um=None, tolerances=None,
        format="table" if args.format == "text" else args.format,
        seed=args.seed if draws else None,
        n=args.n if study in ("montecarlo", "sobol", "allocation") else None,
        n_jobs=args.n_jobs if study in ("montecarlo", "ppm") else 1,
        scheduler=None, progress=args.progress, out=args.out, resume=False, plot=None,
        beta_range=None if study == "allocation" else beta_range,
        limit_um=args.limit if study in ("montecarlo", "ppm") else None,
        adjust=adjust, range=None, step=None, resolution=None, second_order=False,
        method=args.method, target=args.target, budget=args.n if study == "ppm" else None,
        nominal_params=_needle_params(mech), tolerance_set=tolerances,
        file_inputs={"mechanism_file": str(args.file), "fast_path": "needle_208"})
    if study != "ppm":
        ns.budget = ns.method = None
        if study != "allocation":
            ns.target = None
    return ns


def _needle_study(args, mech, tolerances) -> None:
    """The needle_208 fast path: `sewtol needle STUDY` itself (cli.cmd_needle_*), on the file's
    nominal machine and tolerance set; see docs/mechanism_files.md for the flag mapping."""
    from sewtol import cli

    ns = _needle_namespace(args, mech, tolerances)
    cmd = {"scan": cli.cmd_needle_scan, "worst-case": cli.cmd_needle_worst_case,
           "montecarlo": cli.cmd_needle_montecarlo, "sobol": cli.cmd_needle_sobol,
           "ppm": cli.cmd_needle_ppm, "allocation": cli.cmd_needle_allocation}[args.study]
    cmd(ns)


def _yield_study(args, fmt, mech, tolerances) -> None:
    """ppm, allocation and report (sewtol.studies.generic_yield, sewtol.reports.generic_report)."""
    import numpy as np

    from sewtol.studies import generic_yield as GY
    from sewtol.studies import rare_event as R

    output = args.output or mech.output_names[0]
    if args.study == "report":
        from sewtol.cli import _check_out
        from sewtol.reports import generic_report as GR

        _check_out(args)
        rep = _as_flags(GR.build, mech, tolerances, args.n, args.seed,
                        output if args.limit is not None or args.lower_limit is not None
                        else None, args.limit, args.lower_limit)
        try:
            GR.write(rep, args.out)
        except OSError as exc:
            raise ParameterError("--out", f"cannot be written ({exc.strerror})",
                                 str(exc.filename or args.out)) from None
        obj = {"mechanism": mech.name, "tolerances": tolerances.name, "n": args.n,
               "seed": args.seed, "yield": rep.yield_row, "words": rep.words(),
               "index": str(args.out) + "/index.md", "html": str(args.out) + "/report.html"}
        _finish(args, fmt, mech, tolerances, obj, {}, rep.dominance[rep.dominance["rank"] <= 3])
        if fmt == "table":
            print(f"\nreport: {obj['index']} and {obj['html']}"
                  + ("" if rep.yield_row is None else
                     f"; yield {rep.yield_row['yield']:.4f} of {rep.yield_row['n']} machines "
                     f"passing {rep.yield_row['condition']}"))
        return None
    if args.study == "allocation":
        weights = parse_sets(args.weight)
        res = _as_flags(GY.allocate, mech, tolerances, output, args.target, args.limit,
                        args.lower_limit, args.n, args.seed, weights, args.adjust,
                        args.objective)
        _finish(args, fmt, mech, tolerances, res.to_dict(),
                {"allocation": res.table, "trials": res.trials}, res.table)
        if fmt == "table":
            cond = GY.limits_text(output, args.limit, args.lower_limit, mech.output(output).unit)
            print(f"\nscale {res.scale:.6g} of set '{tolerances.name}': yield {res.yield_:.4f} "
                  f"(target {args.target:g}) of {res.n} machines passing {cond}"
                  + (" (capped: the yield stays above the target up to this scale)"
                     if res.capped else ""))
        return None
    ls = _as_flags(GY.file_limit_state, mech, tolerances, output, args.limit, args.lower_limit,
                   args.adjust, args.objective)
    res = _as_flags(R.estimate, ls, np.random.default_rng(args.seed), args.method, args.target,
                    args.n, args.n_jobs)
    cond = GY.limits_text(output if args.adjust is None else f"{output}_adjusted", args.limit,
                          args.lower_limit, mech.output(output).unit)
    obj = {**res.to_dict(), "mechanism": mech.name, "tolerances": tolerances.name,
           "pass_condition": cond, "lower_limit": args.lower_limit, "upper_limit": args.limit,
           "adjust": args.adjust, "seed": args.seed, "target": args.target, "budget": args.n}
    _finish(args, fmt, mech, tolerances, obj,
            {"levels": res.levels, "failing_examples": res.examples},
            res.to_dataframe().assign(tolerances=tolerances.name))
    if fmt == "table":
        print(f"\nP(not {cond}, or the machine cannot run) = {res.statement}")
    return None
