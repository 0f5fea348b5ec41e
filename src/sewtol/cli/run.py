"""`sewtol run FILE.toml STUDY`: the studies of sewtol.studies.generic on a mechanism file.

A file that names `fast_path = "needle_208"` (and passed the loader's check that it reproduces
the built-in needle drive) runs scan, worst-case, montecarlo, sobol, ppm, allocation and
strategies (and settings without --set SETTING:..., the guide's settings) on the needle's exact
model (cli.needle.FAST_PATH) unless `--path generic` is given or a flag asks what the fast path
cannot answer (`_fast_path_refusal`; the mapping is `_needle_namespace`, documented in
docs/mechanism_files.md). `sewtol needle STUDY ARGS` is `sewtol run needle_208 STUDY ARGS`
(needle_aliases: the same parser, the same function; `needle guides` is `settings`).
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

from sewtol.cli import needle as N
from sewtol.cli.common import (
    FLAGS,
    as_flags,
    check_out,
    check_study,
    check_study_folder,
    emit,
    parse_sets,
    plots,
    progress_option,
    save_figure,
    scan_figure,
    wide_option,
    write_outputs,
)
from sewtol.errors import ParameterError

RUN_FORMATS = ("text", "table", "json", "csv")
DEFAULT_N = {"montecarlo": 2000, "strategies": 2000, "sobol": 256, "ppm": 20000,
             "allocation": 2000, "report": 1000, "shapley": 200, "clearance": 400,
             "least-cost": 2000, "settings": 2000}
# --target: the smallest probability ppm must resolve; the yield allocation must keep
DEFAULT_TARGET = {"ppm": 1e-6, "allocation": 0.9973, "least-cost": 0.9973}
# the studies whose limits default to the file's [[specs]] (--limit/--lower-limit override them)
SPEC_STUDIES = ("montecarlo", "ppm", "allocation", "report", "strategies", "least-cost",
                "settings")
# which flags each study reads (any other given flag is refused in one line); its keys: STUDIES
USES = {"nominal": (), "scan": ("output", "tolerances", "adjust", "objective", "plot"),
        "montecarlo": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "n_jobs",
                       "adjust", "clearances", "objective", "plot"),
        "sobol": ("output", "tolerances", "n", "seed", "clearances", "plot"),
        "worst-case": ("output", "tolerances", "adjust", "objective"),
        "ppm": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "method", "target",
                "adjust", "n_jobs", "clearances", "objective"),
        "allocation": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "target",
                       "weight", "adjust", "shape", "objective"),
        "report": ("output", "tolerances", "n", "seed", "limit", "lower_limit"),
        # any of these turns on the settings' yields (sewtol.studies.settings.yield_figures)
        "settings": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "adjust",
                     "strategy", "n_jobs", "objective"),
        "strategies": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "n_jobs",
                       "strategy", "clearances", "objective"),
        "shapley": ("output", "tolerances", "n", "seed", "adjust", "clearances"),
        "refine": ("output", "tolerances", "seed", "adjust", "vary", "keep", "require",
                   "restarts", "popsize", "maxiter", "plot"),
        "clearance": ("output", "tolerances", "n", "seed", "limit", "adjust", "target",
                      "guide_diameter", "play_limit", "guide_fit"),
        "least-cost": ("output", "tolerances", "n", "seed", "limit", "lower_limit", "target",
                       "adjust", "cost", "confidence", "check_n", "restarts", "popsize",
                       "maxiter"),
        "largest-tolerances": ("output", "tolerances", "limit", "adjust")}
STUDIES = tuple(USES)
# the studies that adjust the file's [defaults] adjust when --adjust is not given (the ones
# with a `sewtol needle` form; refine adjusts every compensator by default, shapley, clearance
# and least-cost none); `--adjust none` adjusts nothing
DEFAULT_ADJUST_STUDIES = ("scan", "worst-case", "montecarlo", "ppm", "allocation",
                          "largest-tolerances")
# the columns a table prints without --wide (JSON and CSV keep every column); `failed` sums
# the failure counts where the table has no such column, so ok + out_of_spec + failed = n
COMPACT = {"montecarlo": ("output", "case", "n", "ok", "out_of_spec", "failed", "mean", "std",
                          "min", "max"),
           "strategies": ("strategy", "compensators", "resolution", "setting_error", "n", "ok",
                          "out_of_spec", "failed", "yield", "yield_ci_low", "yield_ci_high",
                          "p95")}
# the library's keyword arguments named as `run`'s flags in its errors
RUN_FLAGS = {**FLAGS, "adjust": "--adjust", "limit": "--limit", "lower_limit": "--lower-limit",
             "target": "--target", "weights": "--weight", "costs": "--cost",
             "confidence": "--confidence", "check_n": "--check-n", "objective": "--objective"}


def add_run(sub) -> None:
    p = sub.add_parser("run", help="a study of a mechanism file (docs/mechanism_files.md)")
    p.add_argument("file", metavar="FILE.toml",
                   help="mechanism file (format sewtol-mechanism/1), or the name of a built-in "
                        "mechanism (sewtol mechanisms)")
    p.add_argument("study", choices=STUDIES)
    run_options(p)


def needle_aliases(nsub) -> None:
    """`sewtol needle ALIAS ARGS`: `sewtol run needle_208 STUDY ARGS`'s parser and function."""
    for study in (*N.FAST_PATH, "largest-tolerances"):
        p = nsub.add_parser(NEEDLE_NAME.get(study, study),
                            help=f"the same as `sewtol run needle_208 {study}`")
        run_options(p)
        p.set_defaults(file="needle_208", study=study)


def run_options(p) -> None:
    """Every flag of `sewtol run` (the needle_208 plug-in's in one group, cli.needle)."""
    p.add_argument("--output", default=None, metavar="NAME",
                   help="the output studied (default: all for nominal/scan/montecarlo, the "
                        "first for worst-case/sobol)")
    p.add_argument("--tolerances", default=None, metavar="SET|FILE.toml[:SET]",
                   help="a [tolerances.SET] of the file (default: its first) or a tolerance file")
    p.add_argument("--n", type=int, default=None,
                   help="machines (montecarlo 2000, allocation 2000 per trial scale, report "
                        "1000), base samples (sobol, 256), model calls (ppm, 20000) or "
                        "permutations (shapley, 200)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--limit", type=float, default=None,
                   help="upper limit of --output (default the first output) for the yield; "
                        "replaces the file's [[specs]] entry of that output")
    p.add_argument("--n-jobs", type=int, default=None,
                   help="parallel workers on this machine (default 1)")
    p.add_argument("--adjust", default=None, metavar="COMPENSATOR[,COMPENSATOR...]|none",
                   help="add the adjusted case: --output (default the first) minimised over "
                        "this [compensators.NAME] of the file on each machine (default: the "
                        "file's [defaults] adjust for scan, worst-case, montecarlo, ppm, "
                        "allocation and largest-tolerances; none: no adjustment)")
    p.add_argument("--objective", default=None, metavar="minimise|target=T|centre=L,U",
                   help="scan, worst-case, montecarlo, ppm, allocation, strategies, settings: "
                        "what --adjust (strategies, settings: each --strategy) does with "
                        "--output on each machine: minimise it (default), bring it to T (an "
                        "eccentric pivot setting a swing back to 60 deg: target=60) or centre "
                        "it in [L, U] (settings: centred in a two-sided spec by default)")
    p.add_argument("--lower-limit", type=float, default=None,
                   help="lower limit of --output (montecarlo, ppm, allocation, report; with or "
                        "without --limit)")
    p.add_argument("--method", choices=("auto", "montecarlo", "mc", "subset", "nais"),
                   default=None,
                   help="ppm: auto (Monte-Carlo if n * target >= 10, else subset simulation), "
                        "montecarlo (or mc), subset or nais")
    p.add_argument("--target", type=float, default=None,
                   help="ppm: the smallest probability to resolve (default 1e-6); allocation: "
                        "the yield to keep (default 0.9973)")
    p.add_argument("--weight", action="append", default=None, metavar="NAME=W",
                   help="allocation: --shape cost: tolerance NAME's cost weight (cost W / "
                        "width); --shape set: NAME scales as W times the common scale "
                        "(repeatable; default 1)")
    p.add_argument("--shape", choices=("cost", "set"), default=None,
                   help="allocation: cost (default): each tolerance shaped by its cost and "
                        "its slope at the set's limits, (W / slope^2)^(1/3); set: the set's "
                        "own limits times one common scale")
    p.add_argument("--cost", action="append", default=None,
                   metavar="[NAME=]MODEL:a=A,b=B[,k=K|m=M]",
                   help="least-cost: the cost model of tolerance NAME (without NAME: of every "
                        "one the tolerance set's [cost] table leaves out); MODEL reciprocal "
                        "(a + b/t), power (a + b/t^k) or exponential (a + b exp(-m t)), t the "
                        "half-width (repeatable)")
    p.add_argument("--confidence", type=float, default=None,
                   help="least-cost: the target must hold with this one-sided confidence "
                        "(Clopper-Pearson) on the search's machines (default 0.95; 0: the "
                        "plain share)")
    p.add_argument("--check-n", type=int, default=None,
                   help="least-cost: fresh machines (seed --seed + 1) that re-estimate the "
                        "allocated yield (default 10 x --n; 0: no check)")
    p.add_argument("--strategy", action="append", default=None, metavar="NAME=C1,C2",
                   help="strategies, settings: a row (settings: a case) NAME adjusting these "
                        "[compensators.NAME] of the file together (repeatable; strategies' "
                        "default none, each compensator alone and all)")
    p.add_argument("--vary", action="append", default=None, metavar="NAME[=LOW,HIGH]",
                   help="refine: a parameter refined, with its absolute bounds (default box: a "
                        "length +-10 %%, a frame coordinate +-2 mm, an angle +-0.5 deg); "
                        "repeatable, NAME,NAME,... allowed (default: the links and the pivots)")
    p.add_argument("--keep", action="append", default=None, metavar="OUTPUT=TOL",
                   help="refine: hold OUTPUT within +-TOL of today's value (repeatable)")
    p.add_argument("--require", action="append", default=None, metavar="OUTPUT>=V|OUTPUT<=V",
                   help="refine: a limit on an output of the refined design (repeatable; every "
                        "transmission output >= 40 deg is always required)")
    p.add_argument("--restarts", type=int, default=None,
                   help="refine, least-cost: differential-evolution restarts that must agree "
                        "(default 3; least-cost 2)")
    p.add_argument("--popsize", type=int, default=None,
                   help="refine: population per refined parameter (default 10); least-cost: "
                        "per searched variable (default 5)")
    p.add_argument("--maxiter", type=int, default=None,
                   help="refine, least-cost: generations of each restart (default 400; "
                        "least-cost 40)")
    p.add_argument("--plot", default=None, metavar="FILE",
                   help="the study's figure (.png/.svg/.pdf), a panel per output: scan, each "
                        "tolerance's change at its limits; montecarlo, each output's histogram "
                        "with its spec limits; sobol, S1 and ST with their intervals; refine, "
                        "the objective's curve today and refined; on the needle_208 fast path "
                        "also worst-case, allocation, strategies (the yield of each "
                        "strategy with its 95 %% interval) and settings (the guide's yields)")
    p.add_argument("--guide-diameter", type=float, default=None, metavar="MM",
                   help="clearance: the guide rod's diameter for its ISO 286 fits (default 8)")
    p.add_argument("--play-limit", type=float, default=None, metavar="UM",
                   help="clearance: the largest lateral play at the stitch (default 20 um)")
    p.add_argument("--guide-fit", action="append", default=None, metavar="FIT",
                   help="clearance: a guide fit to rate, e.g. H7/g6 (repeatable; default "
                        "H6/h5 ... H11/c11)")
    p.add_argument("--clearances", choices=("disc", "rim"), default=None,
                   help="montecarlo, sobol, shapley, ppm, strategies: the journals of the file's "
                        "revolute [[clearances]] as further variables beside the tolerances "
                        "(disc: uniform over the clearance's disc; rim: on its rim)")
    p.add_argument("--format", choices=RUN_FORMATS, default="text")
    wide_option(p)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write the tables, the result and run.json here")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override a nominal value of the file (repeatable); `run settings`: "
                        "--set SETTING:NAME=VALUE[,NAME=VALUE...] names a setting to compare")
    p.add_argument("--path", choices=("auto", "generic"), default="auto",
                   help="auto: a file with fast_path = \"needle_208\" runs scan, worst-case, "
                        "montecarlo, sobol, ppm and allocation as `sewtol needle STUDY` does "
                        "(exact SumDelta, beta searched by the needle's optimiser) where its "
                        "flags allow; generic: always the sampled studies of the file")
    progress_option(p)
    N.needle_flags(p)
    p.set_defaults(func=cmd_run)


def _settings(args) -> list:
    """The settings of `run settings` (--set SETTING:NAME=VALUE[,...], taken out of args.set;
    the other --set items override the file's nominals for every setting)."""
    if args.study != "settings":
        return []
    from sewtol.studies.settings import Setting

    items = [i for i in args.set or [] if ":" in i.partition("=")[0]]
    args.set = [i for i in args.set or [] if i not in items]
    return [Setting(name.strip(), parse_sets(body.split(",")))
            for name, _, body in (i.partition(":") for i in items)]


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
    for key in dict.fromkeys(k for keys in USES.values() for k in keys):  # every study flag
        value = getattr(args, key)
        if value is not None and key not in USES[args.study] \
                and args.study not in N.NEEDLE_FLAGS.get(key, ()):  # _check_needle_flags
            raise ParameterError("--" + key.replace("_", "-"), f"is not used by `run "
                                 f"{args.study}`", value)
    _needle_synonyms(args)
    if args.objective is not None:
        from sewtol.adjuster import Objective

        if args.adjust is None and args.strategy is None and args.study != "strategies":
            raise ParameterError("--objective", "needs --adjust, the compensators that reach it",
                                 args.objective)
        _as_flags(Objective.parse, args.objective)
    # `run settings` draws machines only when given one of its yield flags
    if args.n is None and args.study in DEFAULT_N and (args.study != "settings" or any(
            getattr(args, k) is not None for k in USES["settings"])):
        args.n = DEFAULT_N[args.study]
    args.seed = 0 if args.seed is None else args.seed
    args.n_jobs_given, args.n_jobs = args.n_jobs, 1 if args.n_jobs is None else args.n_jobs
    _check_yield_flags(args)


def _check_yield_flags(args) -> None:
    """The flags of montecarlo, ppm, allocation and report, before anything runs."""
    import math

    if args.study not in SPEC_STUDIES or args.n is None:
        return
    if args.study in DEFAULT_TARGET:
        if args.target is None:
            args.target = DEFAULT_TARGET[args.study]
        if not (math.isfinite(args.target) and 0 < args.target < 1):
            what = "probability" if args.study == "ppm" else "yield"
            raise ParameterError("--target", f"must be a {what} strictly between 0 and 1",
                                 args.target)
    for flag, v in (("--limit", args.limit), ("--lower-limit", args.lower_limit)):
        if v is not None and not math.isfinite(v):
            raise ParameterError(flag, "must be a finite number", v)
    if args.limit is not None and args.lower_limit is not None \
            and not args.lower_limit < args.limit:
        raise ParameterError("--lower-limit", f"must be below --limit {args.limit:g}",
                             args.lower_limit)
    minimum = {"montecarlo": 2, "ppm": 100, "allocation": 10, "report": 2,
               "strategies": 2, "least-cost": 10, "settings": 2}[args.study]
    if args.n < minimum:  # in the words the user gave: needle ppm's --budget is its --n
        flag = "--budget" if getattr(args, "budget", None) is not None else "--n"
        raise ParameterError(flag, f"must be >= {minimum} for `run {args.study}`", args.n)
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
    from sewtol.mechanism.loader import builtin, loads

    p = Path(text)
    if p.exists() or p.suffix or len(p.parts) > 1:
        return load(p, overrides)
    if text in M.names():  # parsed once: the needle and presser tables use the same object
        return loads(M.mechanism_file(text).read_text(), f"sewtol/mechanisms/{text}/{M.FILE}",
                     overrides) if overrides else builtin(text)
    raise ParameterError("FILE.toml", "is neither a file nor a built-in mechanism ("
                         + ", ".join(M.names()) + ")", text)


def cmd_run(args) -> None:
    _check_flags(args)
    check_study(args)
    settings = _settings(args)
    mech = load_mechanism(args.file, parse_sets(args.set))
    fmt = "table" if args.format == "text" else args.format
    if args.output is not None:
        mech.output(args.output)
    args.adjust_given = args.adjust
    _default_adjust(args, mech)
    args.spec = args.spec_source = None
    if args.study in SPEC_STUDIES and args.n is not None:  # the limits: the flags', else the file's
        args.spec_output, args.spec, args.spec_source = mech.resolve_spec(
            args.output, args.limit, args.lower_limit)
    args.path_reason = _fast_path_refusal(args, mech, settings)  # None: the needle_208 fast path
    _check_needle_flags(args, mech)
    if args.study == "nominal":
        from sewtol.studies.generic import nominal

        check_study_folder(args, _inputs(args, mech, None), chunked=False)
        res = nominal(mech)
        return _finish(args, fmt, mech, None, res.to_dict(), {"nominal": res.to_dataframe()},
                       res.to_dataframe())
    if args.study == "settings" and args.path_reason is not None:  # else the guide's (needle)
        from sewtol.studies import settings as SE
        from sewtol.studies.strategies import parse_strategies

        if not settings:  # on the needle file: why the guide's settings are not compared
            raise ParameterError("--set", "`run settings` needs at least one SETTING:NAME=VALUE"
                                 "[,NAME=VALUE...]" + (f" ({args.path_reason})" if mech.header
                                                       .fast_path == "needle_208" else ""), None)
        check_study_folder(args, _inputs(args, mech, None), chunked=False)
        figures = tolerances = None
        if args.n is not None:  # the same machines on every setting, per case
            cases = parse_strategies(args.strategy, mech) if args.strategy else {
                "fixed": (), **({"adjusted": args.adjust.split(",")} if args.adjust else {})}
            tolerances = resolve_tolerances(mech, args.tolerances)
            figures = SE.yield_figures(tolerances, args.n, args.seed, cases, args.spec_output,
                                       args.spec, fast=args.path != "generic", n_jobs=args.n_jobs,
                                       **_goal(args))
        res = as_flags(SE.compare, mech, settings, figures, flags={
            **RUN_FLAGS, "strategy": "--adjust" if args.strategy is None else "--strategy"})
        return _finish(args, fmt, mech, tolerances, res.to_dict(), {"settings": res.rows},
                       res.rows)
    if args.study == "refine":
        return _refine(args, fmt, mech)
    tolerances = resolve_tolerances(mech, args.tolerances)
    if args.clearances is not None:
        from sewtol.studies.clearance import clearance_variables

        mech, tolerances = clearance_variables(mech, tolerances, args.clearances)
        args.path_reason = (f"--clearances {args.clearances}: the journals are inputs the "
                            "fast path does not have")
    if args.path_reason is None:
        args.path_reason = _tolerances_refusal(tolerances)
    _check_needle_flags(args, mech)
    if args.path_reason is None:  # the needle command (cli.needle.FAST_PATH) checks its folder
        ns = _needle_namespace(args, mech, tolerances)
        return ns.func(ns)
    if args.study == "settings":  # the guide's settings, on a set the needle model lacks
        raise ParameterError("--tolerances", f"{args.path_reason} (`needle guides`)", None)
    check_study_folder(args, _inputs(args, mech, tolerances), chunked=False)
    if mech.header.fast_path == "needle_208" and args.path == "auto" \
            and args.study in N.FAST_PATH:
        print(f"sewtol: note: `run {args.study}` takes the generic sampled path, not the "
              f"needle_208 fast path: {args.path_reason}", file=sys.stderr)
    outputs = None if args.output is None else [args.output]
    fast = _kernel_path(args, mech)
    goal = _goal(args)
    if args.study == "scan":
        from sewtol.studies.scan import scan

        res = _as_flags(partial(scan, fast=fast, **goal), mech, tolerances, outputs,
                        args.adjust)
        _finish(args, fmt, mech, tolerances, res.to_dict(), {"scan": res.rows}, res.rows)
        return _figure(args, res.rows["output"], partial(_scan_panel, mech, res.rows))
    if args.study == "worst-case":
        from sewtol.studies.worst_case import worst_case

        res = _as_flags(partial(worst_case, fast=False, **goal), mech, tolerances,
                        args.output or mech.output_names[0], 100, args.adjust)
        return _finish(args, fmt, mech, tolerances, res.to_dict(), {"worst_case": res.rows},
                       res.rows)
    if args.study == "sobol":
        from sewtol.studies.sobol import sobol

        res = _as_flags(partial(sobol, fast=False), mech, tolerances,
                        args.output or mech.output_names[0], args.n, args.seed)
        obj = {"mechanism": mech.name, "tolerances": tolerances.name, "n": res.n,
               "seed": res.seed, "output": args.output or mech.output_names[0],
               "rows": res.to_records(), "convergence": res.convergence.to_dict("records"),
               **({"assembly": res.assembly()} if res.has_failures else {})}
        table = res.to_dataframe()
        _finish(args, fmt, mech, tolerances, obj, {**res.frames(), "indices": res.indices},
                table)
        return _figure(args, table["case"], lambda name, ax: plots().sobol_bars(
            table[table["case"] == name], ax=ax, title=f"Sobol indices of {name}"))
    if args.study == "shapley":
        from sewtol.studies.shapley import shapley

        res = _as_flags(partial(shapley, adjust=args.adjust, fast=args.path != "generic"), mech,
                        tolerances, args.output or mech.output_names[0], args.n, args.seed)
        return _finish(args, fmt, mech, tolerances, res.to_dict(),
                       {"shapley": res.to_dataframe()}, res.to_dataframe())
    if args.study in ("ppm", "allocation", "report"):
        return _yield_study(args, fmt, mech, tolerances)
    if args.study == "strategies":
        return _strategies(args, fmt, mech, tolerances)
    if args.study == "clearance":
        return _clearance(args, fmt, mech, tolerances)
    if args.study == "least-cost":
        return _least_cost(args, fmt, mech, tolerances)
    if args.study == "largest-tolerances":
        return _largest_tolerances(args, fmt, mech, tolerances)
    from sewtol.studies import montecarlo as MC

    res = _as_flags(partial(MC.montecarlo, fast=fast, **goal), mech, tolerances, args.n, args.seed,
                    outputs, args.limit, args.output, args.n_jobs, False, MC.CHUNK, args.adjust,
                    args.lower_limit)
    _finish(args, fmt, mech, tolerances, res.to_dict(),
            {"machines": res.machines, "summary": res.summary_frame()}, res.summary_frame())
    from sewtol.reports.generic_report import output_histogram

    spec = {s.output: (s.lower, s.upper) for s in res.specs}  # the adjusted case: the output's
    return _figure(args, [*res.outputs, *([res.adjusted_output] if res.adjust else [])],
                   lambda name, ax: output_histogram(
                       res.values(name), ax, f"{name} ({_unit(mech, name)})",
                       spec.get(name.removesuffix("_adjusted"), ()), None,
                       f"{name}: {res.n} machines, seed {res.seed}"))


def _figure(args, outputs, draw) -> None:
    """--plot of the generic scan, montecarlo and sobol: draw(output, ax) on a panel per output
    (in the order given, each once)."""
    if args.plot is not None:
        save_figure(args, plots().panels(list(dict.fromkeys(outputs)), draw))


def _scan_panel(mech, rows, name, ax):
    """One output's change at each tolerance's upper and lower limit."""
    scan_figure(rows[rows["output"] == name], "change", ax, f"change ({_unit(mech, name)})")
    ax.set_title(f"{name}: each tolerance at its limits", fontsize=9)
    return ax


def _unit(mech, name: str) -> str:
    """An output's unit, of its adjusted case (OUTPUT_adjusted) too."""
    return mech.output(name.removesuffix("_adjusted")).unit


def _goal(args) -> dict:
    """--objective as the studies' keyword (none given: theirs, the minimum)."""
    return {} if args.objective is None else {"objective": args.objective}


def _default_adjust(args, mech) -> None:
    """--adjust as the studies take it: not given, the file's [defaults] adjust (for the
    DEFAULT_ADJUST_STUDIES); `none`, no adjustment (None; refine keeps "none": it adjusts every
    compensator when given nothing)."""
    given = args.adjust
    if given is not None and given.strip() == "none" and args.study != "refine":
        args.adjust = None
    elif given is None and args.study in DEFAULT_ADJUST_STUDIES and mech.default_adjust:
        args.adjust = ",".join(mech.default_adjust)


def _least_cost(args, fmt, mech, tolerances) -> None:
    """`run FILE least-cost` (sewtol.studies.least_cost): the zones of least cost for the
    target, today's common scale of the set beside them, both checked on fresh machines."""
    import math

    from sewtol import costs as C
    from sewtol.studies import least_cost as LC

    given = {}
    for item in args.cost or []:
        name, model = C.parse_flag(item)
        if name is not None and name not in tolerances.params:
            raise ParameterError("--cost", "must name a tolerance of set "
                                 f"'{tolerances.name}' ({', '.join(tolerances.params)})", name)
        if (name or "*") in given:
            raise ParameterError("--cost", "gives the same parameter twice", name or "every")
        given[name or "*"] = model
    confidence = 0.95 if args.confidence is None else args.confidence
    if not (math.isfinite(confidence) and 0 <= confidence < 1):
        raise ParameterError("--confidence", "must be in [0, 1) (0: the plain share)",
                             confidence)
    if args.check_n is not None and args.check_n < 0:
        raise ParameterError("--check-n", "must be a whole number >= 0", args.check_n)
    fast = _plugin_path(args, mech)
    spec = args.spec
    upper, lower = (None, None) if spec is None else (spec.upper, spec.lower)
    res = _as_flags(partial(LC.least_cost, fast=fast, confidence=confidence or None,
                            restarts=2 if args.restarts is None else args.restarts,
                            popsize=5 if args.popsize is None else args.popsize,
                            maxiter=40 if args.maxiter is None else args.maxiter,
                            check_n=args.check_n),
                    mech, tolerances, args.spec_output, args.target, upper, lower, args.n,
                    args.seed, args.adjust, given)
    _finish(args, fmt, mech, tolerances, res.to_dict(),
            {"least_cost": res.table, "compare": res.compare, "restarts": res.restarts},
            res.table)
    if fmt == "table":
        emit("table", frame=res.compare)
        check = res.check
        print(f"\nleast cost {res.cost:.6g} for yield >= {res.target:g} ({res.failures} of "
              f"{res.n} machines fail, {res.allowed_failures} allowed)"
              + ("" if check is None else
                 f"; fresh machines: {check.yield_:.4f} [{check.ci_low:.4f}, "
                 f"{check.ci_high:.4f}] of {check.n} (seed {check.seed}), "
                 + ("meets the target" if check.meets else "BELOW the target")))


# the largest deviation `run largest-tolerances` tries, in each parameter's own unit
LARGEST_MAX_DEVIATION = 1.0


def _largest_tolerances(args, fmt, mech, tolerances) -> None:
    """`run FILE largest-tolerances` (sewtol.studies.scan.largest_tolerances): per toleranced
    parameter and side, alone (the others nominal), the largest deviation that keeps --output
    (default the first output with a spec) at or below its upper limit, after --adjust; the
    tolerance set's own limit on that side beside it."""
    import math

    import pandas as pd

    from sewtol.studies import scan as S
    from sewtol.studies.adjusting import adjusted, evaluated

    if args.limit is not None and not math.isfinite(args.limit):
        raise ParameterError("--limit", "must be a finite number", args.limit)
    output, spec, args.spec_source = mech.resolve_spec(args.output, args.limit, None)
    if spec is None or spec.upper is None:
        raise ParameterError("--limit", f"must be given: `run largest-tolerances` keeps {output} "
                             "at or below an upper limit and the file's [[specs]] gives it none",
                             None)
    if spec.lower is not None:
        raise ParameterError(f"[[specs]] {output}", "must have no lower limit for `run "
                             "largest-tolerances`, which searches an upper limit (--limit "
                             "replaces the spec)", spec.lower)
    fast = _plugin_path(args, mech)
    adjust = args.adjust
    set_by = set() if adjust is None else {mech.compensators[c].parameter for c in
                                           adjust.split(",") if c in mech.compensators}
    params = [p for p in tolerances.active().params if p not in set_by]
    if not params:
        raise ParameterError("--tolerances", "must tolerance a parameter that --adjust does not "
                             "set", tolerances.name)
    nominal = float((evaluated(mech, None, output, fast=fast) if adjust is None else
                     _as_flags(partial(adjusted, fast=fast), mech, None, adjust, output).value)[0])
    if not nominal <= spec.upper:
        raise ParameterError("--limit", f"must be at or above the nominal machine's {output} "
                             f"({nominal:.6g}{' adjusted' if adjust else ''})", spec.upper)
    # a positive parameter (a length, a mass) is searched down to half its nominal value at most
    rule = {q.name: q for q in mech.parameters}
    reach = {p: min(LARGEST_MAX_DEVIATION, 0.5 * rule[p].nominal)
             if rule[p].rule == "positive" else LARGEST_MAX_DEVIATION for p in params}
    frame = pd.concat([_as_flags(partial(S.largest_tolerances, fast=fast), mech, [p], output,
                                 spec.upper, adjust, reach[p]) for p in params],
                      ignore_index=True)
    frame.insert(4, "max_deviation", [reach[p] for p in frame["param"]])
    own = dict(zip(zip(*tolerances.limit_variants()[:2], strict=True),
                   tolerances.limit_variants()[2], strict=True))
    frame.insert(3, "set_deviation", [own[(p, s)] for p, s in zip(frame["param"], frame["side"],
                                                                 strict=True)])
    unit = mech.output(output).unit
    obj = {"mechanism": mech.name, "tolerances": tolerances.name, "output": output,
           "unit": unit, "limit": spec.upper, "nominal": nominal,
           "method": "each toleranced parameter alone, the others nominal"
                     + ("" if adjust is None else f", {output} after --adjust {adjust}")
                     + ": a geometric grid of deviations from 1e-3 to max_deviation (1 in the "
                     "parameter's unit, at most half the nominal value of a positive one), "
                     "then bisection to 1e-5; reaches_max marks sides where even max_deviation "
                     "keeps the limit; set_deviation is the tolerance set's own limit on that "
                     "side",
           "rows": frame.to_dict("records")}
    return _finish(args, fmt, mech, tolerances, obj, {"largest_tolerances": frame}, frame)


def _strategies(args, fmt, mech, tolerances) -> None:
    """`run FILE strategies` (sewtol.studies.strategies): the same machines under each strategy,
    through the file's plug-ins unless --path generic."""
    from sewtol.studies import strategies as ST

    rows = None if args.strategy is None else ST.parse_strategies(args.strategy, mech)
    fast = _plugin_path(args, mech)
    res = _as_flags(partial(ST.strategies, fast=fast, n_jobs=args.n_jobs, per_machine=False,
                            **_goal(args)), mech,
                    tolerances, args.n, args.seed, rows, args.spec_output, args.spec)
    frame = res.to_dataframe()
    return _finish(args, fmt, mech, tolerances, res.to_dict(), {"strategies": frame}, frame)


def _clearance(args, fmt, mech, tolerances) -> None:
    """`run FILE clearance` (sewtol.studies.clearance): the pins' share of the output after
    --adjust, and with a line_deviation output the guide pair as the criterion."""
    import math

    from sewtol.studies import clearance as K

    K.revolute(mech)  # refused in one line when the file declares no revolute clearance
    if args.n < 2:
        raise ParameterError("--n", "must be >= 2 for `run clearance`", args.n)
    target = 0.95 if args.target is None else args.target
    if not (math.isfinite(target) and 0 < target < 1):
        raise ParameterError("--target", "must be a yield strictly between 0 and 1", target)
    adjust = tuple(a.strip() for a in args.adjust.split(",")) if args.adjust else ()
    for a in adjust:
        if a not in mech.compensators:
            raise ParameterError("--adjust", "must name a compensator of the file ("
                                 + (", ".join(mech.compensators) or "it has none") + ")", a)
    diameter = 8.0 if args.guide_diameter is None else args.guide_diameter
    play = 20.0 if args.play_limit is None else args.play_limit
    fits = tuple(args.guide_fit) if args.guide_fit else K.GUIDE_FITS
    for f in fits:  # a fit outside ISO 286's scope, or not a clearance fit: named as a flag
        try:
            K.fit_gap_um(f, diameter)
        except ParameterError as exc:
            flag = "--guide-diameter" if "diameter" in exc.field else "--guide-fit"
            raise ParameterError(flag, exc.rule, exc.value) from None
    if not (math.isfinite(play) and play > 0):
        raise ParameterError("--play-limit", "must be positive (um)", play)
    output = args.output
    share = _as_flags(partial(K.clearance_share, output=output, adjust=adjust,
                              limit=args.limit), mech, tolerances, args.n, args.seed)
    frames = {"clearance_share": share.cases, "clearance_worst": share.worst}
    obj = {"mechanism": mech.name, "tolerances": tolerances.name, "n": args.n,
           "seed": args.seed, "output": share.output, "strategy": share.strategy,
           "limit": share.limit, "pins": share.pins,
           "share": share.cases.to_dict("records"), "worst": share.worst.to_dict("records")}
    frame = share.cases
    line = next((o.name for o in mech.outputs if o.type == "line_deviation"), None)
    guide_output = output if output is not None and mech.output(output).type == \
        "line_deviation" else line
    if guide_output is not None:
        g = _as_flags(partial(K.guide_criterion, output=guide_output, adjust=adjust,
                              guide_diameter_mm=diameter, fits=fits, play_limit_um=play,
                              target_yield=target), mech, tolerances, args.n, args.seed)
        tight, loose = g.fit_reaching("yield")
        runs = g.fit_reaching("runs_share")
        obj["guide"] = {"output": guide_output, "guide_diameter_mm": diameter,
                        "play_limit_um": play, "target_yield": target,
                        "tightest_fit_runs": runs[0], "tightest_fit": tight,
                        "loosest_fit": loose, "fits": g.fits.to_dict("records")}
        frames.update({"guide_fits": g.fits, "guide_machines": g.machines})
        frame = g.fits
    return _finish(args, fmt, mech, tolerances, obj, frames, frame)


def _as_flags(fn, *a):
    return as_flags(fn, *a, flags=RUN_FLAGS)


def _run_context(args, mech, tolerances) -> dict:
    """What decides a `run` study's numbers, carried by its JSON (its CSVs: run.json beside
    them); seed and n are null where the study draws nothing (nominal, scan, worst-case)."""
    draws = args.study in DEFAULT_N and args.n is not None
    return {"mechanism": mech.name, "mechanism_file": str(args.file),
            "tolerances": None if tolerances is None else tolerances.name,
            "seed": args.seed if draws else None, "n": args.n if draws else None,
            "strategy": args.adjust or "none", "output": args.output,
            "limit": args.limit, "lower_limit": args.lower_limit,
            "spec_source": getattr(args, "spec_source", None),
            "path": getattr(args, "path_used", "generic"),
            "path_reason": getattr(args, "path_reason", None),
            **({} if args.objective is None else {"objective": args.objective})}


def _inputs(args, mech, tolerances) -> dict:
    """What decides a `run` study's numbers, as its run.json records them."""
    from sewtol.provenance import version_record

    return {"study": f"run {args.study}", "mechanism_file": str(args.file),
            "mechanism": mech.name, "n": args.n, "seed": args.seed,
            "output": args.output, "limit": args.limit, "adjust": args.adjust,
            **{k: getattr(args, k) for k in ("lower_limit", "method", "target", "weight")
               if getattr(args, k, None) is not None},
            "params": mech.nominal_values(),
            "tolerances": None if tolerances is None else tolerances.as_record(),
            **version_record()}


def _finish(args, fmt, mech, tolerances, obj, frames, frame) -> None:
    from sewtol.provenance import now

    # a study's own context (strategies: its rows, output and spec) adds to the run's
    obj = {**obj, "context": {**_run_context(args, mech, tolerances), **obj.get("context", {})}}

    if args.out:
        write_outputs(args, args.study.replace("-", "_"), _inputs(args, mech, tolerances), now(),
                      obj, frames, None)
    emit(fmt, obj=obj, frame=frame, compact=COMPACT.get(args.study), wide=args.wide)

# `sewtol needle ALIAS` is `sewtol run needle_208 STUDY`: the fast path's studies and the generic
# largest-tolerances (on the needle's plug-in), under the study's name but for NEEDLE_NAME's
NEEDLE_NAME = {"settings": "guides"}
# the needle studies that report the fixed and the adjusted case by default
BOTH_CASES = ("worst-case", "montecarlo", "sobol")


# the studies a fast path other than needle_208's serves through its plug-ins (the m6 needle's
# exact travel), unless --path generic
KERNEL_STUDIES = ("scan", "montecarlo")


def _plugin_path(args, mech) -> bool:
    """True (the studies' `fast`) unless --path generic; the context names the path taken."""
    from sewtol.protocol import plugins

    fast = args.path != "generic"
    args.path_used = (plugins(mech).name or "generic") if fast else "generic"
    return fast


def _kernel_path(args, mech) -> bool:
    """True when `run scan|montecarlo` takes the file's own fast path (its kernel plug-in) and
    says so in the context; needle_208's runs the needle command instead (or stays generic)."""
    from sewtol.protocol import plugins

    name = mech.header.fast_path
    if args.path == "generic" or name in (None, "needle_208") or args.study not in KERNEL_STUDIES:
        return False
    own = plugins(mech).kernel_outputs
    if args.study == "montecarlo" and args.output not in own:  # its kernel gives all or none
        args.path_reason = f"the {name} kernel gives {', '.join(own)} alone (--output)"
        return False
    args.path_used, args.path_reason = name, None
    return True


def _fast_path_refusal(args, mech, settings=()) -> str | None:
    """None when `run FILE STUDY` runs on the needle_208 fast path, else why it does not."""
    from sewtol.mechanisms.needle_208 import beta as sb
    from sewtol.mechanisms.needle_208.fast_path import sumdelta_outputs

    if args.path == "generic":
        return "--path generic"
    if mech.header.fast_path != "needle_208":
        return ("the file declares no fast path" if mech.header.fast_path is None else
                f"the {mech.header.fast_path} fast path serves {' and '.join(KERNEL_STUDIES)}")
    if args.study not in N.FAST_PATH:
        return f"`run {args.study}` has no fast path"
    if args.output is not None and args.output not in sumdelta_outputs(mech):
        return (f"--output {args.output} is not the SumDelta output "
                f"({', '.join(sumdelta_outputs(mech))}) the needle commands compute")
    if args.objective not in (None, "minimise"):
        return f"--objective {args.objective}: the needle commands minimise SumDelta"
    reason = _needle_adjust_refusal(args, mech)
    if reason is not None:
        return reason
    if getattr(args, "lower_limit", None) is not None:
        return "--lower-limit: the needle commands limit SumDelta from above only"
    spec, flag = getattr(args, "spec", None), ("--limit" if args.limit is not None
                                                else "the file's [[specs]]")
    if spec is not None and spec.output not in sumdelta_outputs(mech):
        return f"the file's [[specs]] limits {spec.output}, not SumDelta"
    if spec is not None and spec.lower is not None:
        return "the file's [[specs]] gives SumDelta a lower limit: the needle commands limit it " \
               "from above only"
    upper = None if spec is None else spec.upper
    if upper is not None and not upper > 0:
        return f"{flag} {upper:g}: the needle's SumDelta limit is a positive number of um"
    if args.study in ("allocation", "strategies") and upper not in (None, sb.DEFAULT_LIMIT_UM):
        return (f"{flag} {upper:g}: `needle {args.study}` keeps SumDelta within "
                f"{sb.DEFAULT_LIMIT_UM:g} um")
    alias = NEEDLE_NAME.get(args.study, args.study)  # the study's `sewtol needle` command
    if args.study in ("strategies", "settings") and args.strategy is not None:
        return f"--strategy: `needle {alias}` compares its own rows"
    if settings:
        return "--set SETTING:...: `needle guides` compares the guide's own settings"
    if args.weight is not None:
        return "--weight: `needle allocation` weighs every tolerance alike"
    if args.shape == "set":
        return "--shape set: `needle allocation` shapes the tolerances by their slopes"
    if args.out and args.study in ("worst-case", "allocation", "settings"):
        return f"--out: `needle {alias}` writes no study folder"
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


def _needle_adjust_refusal(args, mech) -> str | None:
    """An --adjust given names the needle's compensators by parameter (its exact adjuster, the
    strategy's rows); not given, the file's [defaults] adjust must be the needle's own (beta)."""
    from sewtol.mechanisms.needle_208 import beta as sb
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.mechanisms.params import field_names

    given = args.adjust_given
    if given is not None and given.strip().lower() != "none":
        names = [a.strip() for a in given.split(",")]
        for name in names:
            if name and name not in mech.compensators and name not in field_names(Needle208):
                raise ParameterError("--adjust", "must name a compensator of the file ("
                                     f"{', '.join(mech.compensators)}) or, on the needle_208 "
                                     f"fast path, a parameter of the needle; unknown parameter "
                                     f"{name!r}", given)
            if name in mech.compensators and name not in field_names(Needle208):
                return (f"--adjust {given}: {name} is a compensator of the file; the needle "
                        f"commands name theirs by parameter ({mech.compensators[name].parameter})")
        if args.study == "ppm" and names != ["beta"]:
            return f"--adjust {given}: `needle ppm` adjusts beta alone"
        return None
    if given is None and args.adjust is not None:  # the file's [defaults] adjust
        for name in args.adjust.split(","):
            comp = mech.compensators[name]
            if comp.parameter != "beta":
                return (f"the file's [defaults] adjust {name} sets {comp.parameter}; the needle "
                        "commands adjust beta by default")
            if args.study == "allocation" and (comp.low, comp.high) != sb.DEFAULT_RANGE_DEG:
                return (f"[compensators.{name}] searches beta in [{comp.low:g}, {comp.high:g}] "
                        "deg; `needle allocation` searches 10 35")
    return None


def _check_needle_flags(args, mech) -> None:
    """The needle_208 plug-in's flags (cli.needle.NEEDLE_FLAGS), refused in one line by a study
    that does not read them, another mechanism, or a run that leaves the fast path."""
    for key, studies in N.NEEDLE_FLAGS.items():
        value = getattr(args, "n_jobs_given" if key == "n_jobs" else key)
        if value is None or key in USES[args.study]:
            continue
        flag = "--" + key.replace("_", "-")
        if args.study not in studies:
            raise ParameterError(flag, f"is not used by `run {args.study}`", value)
        if mech.header.fast_path != "needle_208":
            raise ParameterError(flag, f"is read by the needle_208 fast path only; `run "
                                 f"{args.file} {args.study}` has none", value)
        if args.path_reason is not None:
            raise ParameterError(flag, "is read by the needle_208 fast path only, which this "
                                 f"run leaves ({args.path_reason})", value)


def _needle_synonyms(args) -> None:
    """--limit-um is --limit, and ppm's --budget its --n, in the needle's words."""
    if args.limit_um is not None and not args.limit_um > 0:
        raise ParameterError("--limit-um", "must be a positive number of um", args.limit_um)
    for flag, key, same in (("--limit-um", "limit_um", "limit"), ("--budget", "budget", "n")):
        value = getattr(args, key)
        if value is not None and getattr(args, same) is not None:
            raise ParameterError(flag, f"is --{same} in the needle's words; give one of them",
                                 value)
        setattr(args, same, getattr(args, same) if value is None else value)


def _needle_namespace(args, mech, tolerances=None):
    """`run`'s arguments as cli.needle.FAST_PATH reads them: no seed or n where the study draws
    nothing, the SumDelta limit in force, --adjust as given, the file's nominal machine (unless
    --frame or --guide-shift-um) and its tolerance set."""
    from sewtol.mechanisms.needle_208 import beta as sb
    from sewtol.mechanisms.needle_208.fast_path import needle_params

    study, given = args.study, args.adjust_given
    ns = argparse.Namespace(**vars(args))
    if given is not None:
        ns.adjust = given
    elif args.adjust is None:  # no default adjustment in the file
        ns.adjust = None if study in (*BOTH_CASES, "strategies", "settings") else "none"
    else:  # the file's default: beta, the needle's own default
        ns.adjust = "beta" if study == "ppm" else None
        comp = mech.compensators[args.adjust]
        if study != "allocation" and args.beta_range is None:
            ns.beta_range = [float(comp.low), float(comp.high)]
    if study in ("scan", "worst-case"):
        ns.seed = None
    if study in ("scan", "worst-case", "ppm"):
        ns.n = None
    if study == "settings" and ns.n is None:  # the guide's settings always draw machines
        ns.n = DEFAULT_N[study]
    if study in ("montecarlo", "ppm", "settings"):
        # the limit in force; the file's spec of the needle's own default 10 um is passed as
        # the default, so `run` prints the bytes of the needle's default
        ns.limit_um = None if args.spec is None or (
            args.limit is None and args.spec.upper == sb.DEFAULT_LIMIT_UM) else args.spec.upper
        ns.spec_source = None if ns.limit_um is None else args.spec_source
    else:
        ns.limit_um, ns.spec_source = (args.limit if study in ("scan", "sobol") else None), None
    if study == "ppm":
        ns.budget = args.n
    ns.format = "table" if args.format == "text" else args.format
    ns.housing, ns.resume = bool(args.housing), bool(args.resume)
    ns.second_order = bool(args.second_order)
    own = args.frame is None and args.guide_shift_um is None
    ns.nominal_params, ns.tolerance_set = (needle_params(mech) if own else None), tolerances
    ns.file_inputs = {"mechanism_file": str(args.file), "fast_path": "needle_208"}
    ns.func = N.FAST_PATH[study]
    return ns


def _yield_study(args, fmt, mech, tolerances) -> None:
    """ppm, allocation and report (sewtol.studies.rare_event, allocation, sewtol.reports.generic_report)."""
    import numpy as np

    from sewtol.studies import allocation as AL
    from sewtol.studies import rare_event as PPM

    output, spec = args.spec_output, args.spec
    upper, lower = (None, None) if spec is None else (spec.upper, spec.lower)
    if args.study == "report":
        from sewtol.reports import generic_report as GR

        check_out(args)
        rep = _as_flags(GR.build, mech, tolerances, args.n, args.seed,
                        None if spec is None else output, upper, lower)
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
        if args.shape == "set":
            res = _as_flags(partial(AL.allocate, fast=False, **_goal(args)), mech, tolerances,
                            output, args.target, upper, lower, args.n, args.seed, weights,
                            args.adjust)
        else:
            res = as_flags(partial(AL.allocate_by_cost, fast=False, **_goal(args)), mech,
                           tolerances, output, args.target, upper, lower, args.n, args.seed,
                           weights, args.adjust, flags={**RUN_FLAGS, "costs": "--weight"})
        _finish(args, fmt, mech, tolerances, res.to_dict(),
                {"allocation": res.table, "trials": res.trials}, res.table)
        if fmt == "table":
            cond = PPM.limits_text(output, upper, lower, mech.output(output).unit)
            what = "" if args.shape == "set" else " of the cost shape (half-widths k a_i, the " \
                "largest a_i 1, each at most 1)"
            print(f"\nscale {res.scale:.6g}{what} of set '{tolerances.name}': yield {res.yield_:.4f} "
                  f"(target {args.target:g}) of {res.n} machines passing {cond}"
                  + (" (capped: the yield stays above the target up to this scale)"
                     if res.capped else ""))
        return None
    ls = _as_flags(partial(PPM.limit_state, fast=False, **_goal(args)), mech, tolerances, output,
                   upper, lower, args.adjust)
    res = _as_flags(PPM.estimate, ls, np.random.default_rng(args.seed), args.method, args.target,
                    args.n, args.n_jobs)
    cond = PPM.limits_text(output if args.adjust is None else f"{output}_adjusted", upper,
                          lower, mech.output(output).unit)
    obj = {**res.to_dict(), "mechanism": mech.name, "tolerances": tolerances.name,
           "pass_condition": cond, "lower_limit": lower, "upper_limit": upper,
           "adjust": args.adjust, "seed": args.seed, "target": args.target, "budget": args.n}
    _finish(args, fmt, mech, tolerances, obj,
            {"levels": res.levels, "failing_examples": res.examples},
            res.to_dataframe().assign(tolerances=tolerances.name))
    if fmt == "table":
        print(f"\nP(not {cond}, or the machine cannot run) = {res.statement}")
    return None


def _parse_vary(items, mech) -> dict | None:
    """--vary NAME[=LOW,HIGH] items as refine's parameters (None: its default)."""
    if not items:
        return None
    out = {}
    for item in items:
        name, eq, box = item.partition("=")
        names = [n.strip() for n in name.split(",") if n.strip()]
        if eq and len(names) != 1:
            raise ParameterError("--vary", "NAME=LOW,HIGH names one parameter", item)
        for n in names:
            if n not in mech.parameter_names:
                raise ParameterError("--vary", "must name parameters of the file ("
                                     + ", ".join(mech.parameter_names) + ")", n)
            if n in out:
                raise ParameterError("--vary", "names a parameter twice", n)
            out[n] = None
        if eq:
            try:
                lo, hi = (float(v) for v in box.split(","))
            except ValueError:
                raise ParameterError("--vary", "must be NAME=LOW,HIGH (numbers)", item) from None
            out[names[0]] = (lo, hi)
    return out


def _parse_constraints(args, mech, adjust, objective) -> list:
    """The transmission margin, --keep OUTPUT=TOL and --require OUTPUT>=V / OUTPUT<=V."""
    from sewtol.studies import refine as RF

    out = RF.default_constraints(mech)
    for item in args.keep or []:
        name, eq, tol = item.partition("=")
        mech.output(name.strip()) if eq else None
        try:
            value = float(tol)
        except ValueError:
            raise ParameterError("--keep", "must be OUTPUT=TOL (a number)", item) from None
        out.append(RF.keep(mech, name.strip(), value, adjust, objective))
    for item in args.require or []:
        for op, make in ((">=", RF.at_least), ("<=", RF.at_most)):
            if op in item:
                name, _, v = item.partition(op)
                mech.output(name.strip())
                try:
                    out.append(make(name.strip(), float(v)))
                except ValueError:
                    raise ParameterError("--require", f"must be OUTPUT{op}VALUE (a number)",
                                         item) from None
                break
        else:
            raise ParameterError("--require", "must be OUTPUT>=VALUE or OUTPUT<=VALUE", item)
    return out


def _refine(args, fmt, mech) -> None:
    """`run FILE refine` (sewtol.studies.refine): the design refined, today's beside it."""
    from sewtol.cli.common import save_plot
    from sewtol.studies import refine as RF

    tolerances = (resolve_tolerances(mech, args.tolerances)
                  if args.tolerances is not None or mech.tolerance_sets else None)
    adjust = None if args.adjust is None else (
        [] if args.adjust.strip() == "none" else [a.strip() for a in args.adjust.split(",")])
    objective = args.output or mech.output_names[0]
    params = _parse_vary(args.vary, mech)
    constraints = _parse_constraints(args, mech, adjust, objective)
    fast = _plugin_path(args, mech)
    check_study_folder(args, _inputs(args, mech, tolerances), chunked=False)
    res = RF.refine(mech, params, objective=objective, adjust=adjust, constraints=constraints,
                    seed=args.seed, restarts=args.restarts or 3, popsize=args.popsize or 10,
                    maxiter=args.maxiter or 400, tolerances=tolerances, fast=fast)
    frames = {"parameters": res.parameters, "outputs": res.outputs_frame(),
              "restarts": res.restarts, "influence": res.influence}
    if res.curves() is not None:
        frames["curves"] = res.curves()
    save_plot(args, res.plot)
    _finish(args, fmt, mech, tolerances, res.to_dict(), frames, res.parameters)
    if fmt == "table":
        emit("table", frame=res.outputs_frame())
        emit("table", frame=res.influence)
        print("\n".join(f"- {line}" for line in res.confirmation()))
