"""The `sewtol` command: a thin layer over the library. Only this and study scripts write files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .errors import AssemblyError, ParameterError

FORMATS = ("table", "json", "csv")


class CliError(Exception):
    pass


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the flag, like every other refusal."""

    def error(self, message):
        self.exit(2, f"sewtol: error: {message} (see {self.prog} --help)\n")


def parse_sets(items, cls) -> dict:
    """--set NAME=VALUE pairs checked against the parameter names of `cls`."""
    from .mechanisms.params import field_names

    valid = field_names(cls)
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError("--set", "must be NAME=VALUE", item)
        name, _, text = item.partition("=")
        name = name.strip()
        if name not in valid:
            raise ParameterError(name, f"unknown parameter; valid names are {', '.join(valid)}",
                                 name)
        try:
            value = float(text)
        except ValueError:
            raise ParameterError(name, "must be a number", text) from None
        out[name] = value
    return out


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def emit(fmt: str, *, obj=None, frame=None) -> None:
    if fmt == "json":
        data = obj if obj is not None else frame.to_dict(orient="records")
        sys.stdout.write(json.dumps(data, indent=2, default=_json_default, allow_nan=True) + "\n")
    elif fmt == "csv":
        sys.stdout.write(frame.to_csv(index=False, float_format="%.9g", lineterminator="\n"))
    else:
        sys.stdout.write(frame.to_markdown(index=False, floatfmt=".4f") + "\n")


def _needle_params(args):
    from .mechanisms.needle_208 import Needle208

    return Needle208.nominal().override(**parse_sets(args.set, Needle208))


def cmd_needle_nominal(args):
    from .needle import nominal_figures

    _check_beta_range(args)
    fig = nominal_figures(_needle_params(args), tuple(args.beta_range), args.limit_um)
    if args.format == "csv":
        raise CliError("--format: nominal prints json or table, not csv")
    emit(args.format, obj=fig.to_dict(), frame=fig.to_dataframe())


def cmd_needle_deviation(args):
    from .needle import deviation_table

    if not (0 < args.step_deg <= 90):
        raise ParameterError("--step-deg", "must be in (0, 90]", args.step_deg)
    p = _needle_params(args)
    if args.beta is not None:
        p = p.override(beta=args.beta)
    frame = deviation_table(p, args.step_deg)
    emit(args.format, frame=frame)


def _study_nominal(args):
    """The nominal machine of a study: it must assemble, or nothing is computed or written."""
    from .mechanisms.needle_208 import check_assembly

    params = _needle_params(args)
    check_assembly(params)
    return params


def _tolerances(args):
    from .mechanisms.needle_208 import Needle208
    from .mechanisms.params import field_names
    from .tolerances import NEEDLE_208_SETS, resolve

    return resolve(args.tolerances, NEEDLE_208_SETS, field_names(Needle208))


def _check_n(value, name="--n", minimum=2):
    if value < minimum:
        raise ParameterError(name, f"must be >= {minimum}", value)


def _check_study(args):
    """Every study flag is checked before anything is computed or written."""
    if getattr(args, "seed", 0) < 0:
        raise ParameterError("--seed", "must be a whole number >= 0", args.seed)
    if getattr(args, "n_jobs", 1) == 0 or getattr(args, "n_jobs", 1) < -1:
        raise ParameterError("--n-jobs", "must be a positive number of workers or -1 (all cores)",
                             args.n_jobs)
    if getattr(args, "resume", False) and not getattr(args, "out", None):
        raise ParameterError("--resume", "needs --out, the folder of the interrupted study",
                             True)


def _check_beta_range(args):
    lo, hi = args.beta_range
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ParameterError("--beta-range", "must be LOW HIGH with LOW < HIGH (deg)",
                             args.beta_range)
    if not (np.isfinite(args.limit_um) and args.limit_um > 0):
        raise ParameterError("--limit-um", "must be a positive number of um", args.limit_um)


def _store(args, kind: str, params, tolerances):
    """The checkpoint folder of a study run with --out (None without)."""
    if not args.out:
        return None
    from .mechanisms.params import as_dict
    from .studies.checkpoint import ChunkStore

    manifest = {"study": kind, "n": args.n, "seed": args.seed, "params": as_dict(params),
                "tolerances": {"name": tolerances.name, "items": tolerances.as_dict()}}
    return ChunkStore(Path(args.out) / "chunks", manifest, args.resume, label=str(args.out))


def _write_outputs(args, kind, params, tolerances, started, result_obj, frames):
    """Results, machine tables and run.json into --out, each file atomically."""
    if not args.out:
        return
    from .io import write_text_atomic
    from .mechanisms.params import as_dict
    from .provenance import run_record

    out = Path(args.out)
    write_text_atomic(out / f"{kind}.json", json.dumps(result_obj, indent=2,
                                                       default=_json_default) + "\n")
    for name, frame in frames.items():
        write_text_atomic(out / f"{name}.csv", frame.to_csv(index=False, float_format="%.9g",
                                                          lineterminator="\n"))
    inputs = {"study": kind, "n": args.n, "seed": args.seed, "n_jobs": args.n_jobs,
              "params": as_dict(params),
              "tolerances": {"name": tolerances.name, "items": tolerances.as_dict()}}
    write_text_atomic(out / "run.json", json.dumps(run_record(started, inputs), indent=2) + "\n")


def cmd_needle_scan(args):
    from .studies.scan import scan

    rows = scan(_study_nominal(args), _tolerances(args), guide_shift_um=args.guide_shift_um)
    frame = rows.to_dataframe()
    emit(args.format, obj=rows.to_records(), frame=frame)


def cmd_needle_montecarlo(args):
    from .provenance import now
    from .studies.montecarlo import montecarlo

    _check_n(args.n)
    _check_study(args)
    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    if strategy is not None:
        return _adjusted_montecarlo(args, params, tolerances, strategy)
    started = now()
    store = _store(args, "montecarlo", params, tolerances)
    res = montecarlo(params, tolerances, args.n, args.seed, n_jobs=args.n_jobs,
                     progress=args.progress, store=store)
    _write_outputs(args, "montecarlo", params, tolerances, started, res.to_dict(),
                   {"machines": res.machines, "summary": res.summary_frame()})
    emit(args.format, obj=res.to_dict(), frame=res.summary_frame())


# --- adjustment strategies (issue 13): --adjust/--range/--step/--resolution, `needle strategies`


def _strategy(args):
    """The strategy of --adjust/--range/--step/--resolution (None without --adjust)."""
    from .mechanisms.needle_208 import Needle208
    from .mechanisms.params import field_names
    from .studies.compensators import parse_cli

    return parse_cli(getattr(args, "adjust", None), args.range, args.step, args.resolution,
                     valid=field_names(Needle208))


def _adjusted_montecarlo(args, params, tolerances, strategy):
    """needle montecarlo --adjust: the per-machine table of one strategy and its summary."""
    from .provenance import now
    from .studies.montecarlo import sample_machines
    from .studies.strategies import adjusted_montecarlo_model, summarise_frame

    started = now()
    store = _store(args, "montecarlo_adjusted", params, tolerances)
    machines = sample_machines(adjusted_montecarlo_model, params, tolerances, args.n, args.seed,
                               args.n_jobs, args.progress, store=store, strategy=strategy,
                               limit_um=10.0)
    summary = summarise_frame(machines, strategy, 10.0)
    record = {**summary.iloc[0].to_dict(), "seed": args.seed, "tolerances": tolerances.name,
              "compensators": {c.name: {"low": c.low, "high": c.high, "step": c.step,
                                        "resolution": c.resolution, "mode": c.mode}
                               for c in strategy.compensators}}
    _write_outputs(args, "montecarlo", params, tolerances, started, record,
                   {"machines": machines, "summary": summary})
    emit(args.format, obj=record, frame=summary)


def cmd_needle_strategies(args):
    from .provenance import now
    from .studies.compensators import Strategy
    from .studies.strategies import default_strategies, strategies_table

    _check_n(args.n)
    _check_study(args)
    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    rows = default_strategies()
    if strategy is not None:
        if strategy.name in {r.name for r in rows}:
            strategy = Strategy(strategy.name + " (given)", strategy.compensators)
        rows.append(strategy)
    started = now()
    res = strategies_table(params, tolerances, args.n, args.seed, rows)
    table = res.to_dataframe()
    frames = {"strategies": table}
    for r in rows:
        safe = "".join(ch if ch.isalnum() else "_" for ch in r.name)
        frames[f"machines_{safe}"] = res.machines(r.name)
    _write_outputs(args, "strategies", params, tolerances, started,
                   table.to_dict(orient="records"), frames)
    emit(args.format, obj=table.to_dict(orient="records"), frame=table)


def _adjust_options(p):
    p.add_argument("--adjust", default=None, metavar="NAMES",
                   help="compensators the assembler sets per machine, e.g. beta,guide_shift_um "
                        "(built in: beta, guide_shift_um, guide_angle, CD; none: no adjustment)")
    p.add_argument("--range", action="append", metavar="NAME=LOW,HIGH",
                   help="a compensator's range (offset from as built; beta absolute, deg)")
    p.add_argument("--step", action="append", metavar="NAME=VALUE",
                   help="discrete settings low + k*VALUE (a shim set, a graduated clamp)")
    p.add_argument("--resolution", action="append", metavar="NAME=VALUE",
                   help="how finely the assembler sets it (report the worst within +/-VALUE/2)")


def cmd_needle_sobol(args):
    from .provenance import now
    from .studies.sobol import _check_n as check_power_of_two
    from .studies.sobol import needle_sobol

    try:
        check_power_of_two(args.n)
    except ParameterError as exc:
        raise ParameterError("--n", exc.rule, args.n) from None
    _check_study(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    started = now()
    store = _store(args, "sobol", params, tolerances)
    res = needle_sobol(params, tolerances, args.n, args.seed, n_jobs=args.n_jobs,
                       progress=args.progress, store=store)
    _write_outputs(args, "sobol", params, tolerances, started, res.to_records(),
                   {"indices": res.to_dataframe(), "convergence": res.convergence})
    emit(args.format, obj=res.to_records(), frame=res.to_dataframe())


def _feed_params(args):
    from .mechanisms.feed_131 import Feed131

    return Feed131().override(**parse_sets(args.set, Feed131))


def cmd_feed_trajectory(args):
    from .feed import trajectory

    emit(args.format, frame=trajectory(_feed_params(args), args.step_deg))


def cmd_feed_metrics(args):
    from .feed import metrics

    m = metrics(_feed_params(args))
    if args.format == "csv":
        emit("csv", frame=m.to_dataframe())
    else:
        emit(args.format, obj=m.to_dict(), frame=m.to_dataframe())


def cmd_feed_regulator(args):
    from .feed import regulator_sweep

    lo, hi, step = args.b_range
    if not (lo < hi and step > 0):
        raise ParameterError("--b-range", "must be LOW HIGH STEP with LOW < HIGH and STEP > 0",
                             args.b_range)
    emit(args.format, frame=regulator_sweep(_feed_params(args), np.arange(lo, hi + 1e-9, step)))


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(prog="sewtol", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="group", required=True, parser_class=Parser)
    needle = sub.add_parser("needle", help="208-class needle drive")
    nsub = needle.add_subparsers(dest="command", required=True, parser_class=Parser)

    def common(p):
        p.add_argument("--set", action="append", metavar="NAME=VALUE",
                       help="override a parameter (repeatable), e.g. --set LF=6.8")
        p.add_argument("--format", choices=FORMATS, default="table")

    p = nsub.add_parser("nominal", help="beta*, deviation figures, window, guide, stroke")
    common(p)
    p.add_argument("--beta-range", nargs=2, type=float, default=[10.0, 35.0],
                   metavar=("LOW", "HIGH"), help="regulating range searched for beta* (deg)")
    p.add_argument("--limit-um", type=float, default=10.0, help="SumDelta limit of the window")
    p.set_defaults(func=cmd_needle_nominal)

    p = nsub.add_parser("deviation", help="E and d(phi) over one crank turn")
    common(p)
    p.add_argument("--beta", type=float, default=None, help="beta (deg); default: the nominal")
    p.add_argument("--step-deg", type=float, default=1.0, help="crank-angle step (deg)")
    p.set_defaults(func=cmd_needle_deviation)

    def study(p, seed=True):
        p.add_argument("--tolerances", default="base",
                       help="base, recommended, FILE.toml or FILE.toml:SET (default base)")
        if seed:
            p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
            p.add_argument("--n-jobs", type=int, default=1, help="parallel workers (joblib)")
            p.add_argument("--progress", action="store_true", help="progress bar on stderr")
            p.add_argument("--out", default=None, metavar="DIR",
                           help="write results, machines, run.json and checkpoints here")
            p.add_argument("--resume", action="store_true",
                           help="continue the interrupted study in --out without recomputing "
                                "its finished chunks")

    p = nsub.add_parser("scan", help="each tolerance at its limits, beta re-optimised")
    common(p)
    study(p, seed=False)
    p.add_argument("--guide-shift-um", type=float, default=0.0,
                   help="move the fixed guide along its normal (um)")
    p.set_defaults(func=cmd_needle_scan)

    p = nsub.add_parser("montecarlo", help="yield with beta fixed and adjusted per machine")
    common(p)
    study(p)
    p.add_argument("--n", type=int, default=2000, help="machines (default 2000)")
    p.set_defaults(func=cmd_needle_montecarlo)

    _adjust_options(p)

    p = nsub.add_parser("strategies", help="yield by adjustment strategy on the same machines")
    common(p)
    study(p)
    p.add_argument("--n", type=int, default=500, help="machines (default 500)")
    _adjust_options(p)
    p.set_defaults(func=cmd_needle_strategies)

    p = nsub.add_parser("sobol", help="Sobol indices of SumDelta (SALib)")
    common(p)
    study(p)
    p.add_argument("--n", type=int, default=256, help="base samples, a power of two")
    p.set_defaults(func=cmd_needle_sobol)

    feed = sub.add_parser("feed", help="131-42+3 feed chains (lower and upper dog)")
    fsub = feed.add_subparsers(dest="command", required=True, parser_class=Parser)
    p = fsub.add_parser("trajectory", help="both middle teeth over one turn")
    common(p)
    p.add_argument("--step-deg", type=float, default=1.0, help="main-shaft angle step (deg)")
    p.set_defaults(func=cmd_feed_trajectory)
    p = fsub.add_parser("metrics", help="feed step, rise, phases, travel; differential ratio")
    common(p)
    p.set_defaults(func=cmd_feed_metrics)
    p = fsub.add_parser("regulator", help="feed steps and ratio against the regulator setting b")
    common(p)
    p.add_argument("--b-range", nargs=3, type=float, default=[0.0, 60.0, 2.0],
                   metavar=("LOW", "HIGH", "STEP"), help="b values swept (deg)")
    p.set_defaults(func=cmd_feed_regulator)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ParameterError, AssemblyError, CliError) as exc:
        print(f"sewtol: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        where = getattr(args, "out", None)
        hint = (f"; finished chunks are saved in {where}/chunks: rerun the same command with "
                "--resume" if where else "; nothing was saved (use --out DIR to keep chunks)")
        print(f"sewtol: interrupted{hint}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
