"""`sewtol feed COMMAND`: the 131-42+3 feed's single machine (trajectory, metrics, regulator);
its tolerance studies `sewtol feed scan|montecarlo|sobol` are `sewtol run feed_131 STUDY`, with
the same flags and output (docs/cli.md)."""

from __future__ import annotations

import numpy as np

from sewtol.cli.common import (
    Parser,
    check_step,
    emit,
    machine_context,
    machine_options,
    parse_sets,
    plot_option,
    plots,
    save_plot,
)
from sewtol.cli.run import run_options
from sewtol.errors import ParameterError

MAX_SWEEP_POINTS = 100_000
# the feed commands that are `sewtol run feed_131 STUDY` under another name
RUN_STUDIES = {"scan": "each tolerance at its limits, others nominal",
               "montecarlo": "outputs of N machines drawn from the tolerances",
               "sobol": "Sobol indices of --output over the tolerances (SALib)"}


def _feed_params(args):
    from sewtol.mechanisms.feed_131.model import Feed131

    return Feed131().override(**parse_sets(args.set, Feed131))


def cmd_feed_trajectory(args):
    from sewtol.mechanisms.feed_131.analysis import trajectory

    check_step(args.step_deg)
    params = _feed_params(args)
    traj = trajectory(params, args.step_deg)
    emit(args.format, obj={"context": machine_context(args, params),
                           "rows": traj.to_dict(orient="records")}, frame=traj)
    save_plot(args, lambda ax: plots().tooth_paths(traj, params.plate_mm, params.material_mm,
                                                     ax=ax))


def cmd_feed_metrics(args):
    from sewtol.mechanisms.feed_131.analysis import metrics

    params = _feed_params(args)
    m = metrics(params)
    if args.format == "csv":
        emit("csv", frame=m.to_dataframe())
    else:
        emit(args.format, obj={**m.to_dict(), "context": machine_context(args, params)},
             frame=m.to_dataframe())


def cmd_feed_regulator(args):
    from sewtol.mechanisms.feed_131.analysis import regulator_sweep

    lo, hi, step = args.b_range
    if not (np.isfinite([lo, hi, step]).all() and lo < hi and step > 0):
        raise ParameterError("--b-range", "must be finite LOW HIGH STEP with LOW < HIGH and "
                             "STEP > 0", args.b_range)
    if (hi - lo) / step + 1 > MAX_SWEEP_POINTS:
        raise ParameterError("--b-range", f"gives more than {MAX_SWEEP_POINTS} settings; use a "
                             "larger STEP", args.b_range)
    params = _feed_params(args)
    sweep = regulator_sweep(params, np.arange(lo, hi + 1e-9, step))
    emit(args.format, obj={"context": machine_context(args, params, b_range_deg=[lo, hi, step]),
                           "rows": sweep.to_dict(orient="records")}, frame=sweep)
    save_plot(args, lambda ax: plots().regulator_curve(sweep, params.b, ax=ax))


def add_feed(sub) -> None:
    """`sewtol feed COMMAND`: the single-machine commands, then the studies of `sewtol run
    feed_131` under their own names."""
    feed = sub.add_parser("feed", help="131-42+3 feed chains (lower and upper dog)")
    fsub = feed.add_subparsers(dest="command", required=True, parser_class=Parser)
    p = fsub.add_parser("trajectory", help="both middle teeth over one turn")
    machine_options(p, example="b=25")
    p.add_argument("--step-deg", type=float, default=1.0, help="main-shaft angle step (deg)")
    plot_option(p, "both middle-tooth paths")
    p.set_defaults(func=cmd_feed_trajectory)
    p = fsub.add_parser("metrics", help="feed step, rise, phases, travel; differential ratio")
    machine_options(p, example="b=25")
    p.set_defaults(func=cmd_feed_metrics)
    p = fsub.add_parser("regulator", help="feed steps and ratio against the regulator setting b")
    machine_options(p, example="b=25")
    p.add_argument("--b-range", nargs=3, type=float, default=[0.0, 60.0, 2.0],
                   metavar=("LOW", "HIGH", "STEP"), help="b values swept (deg)")
    plot_option(p, "the feed steps against b")
    p.set_defaults(func=cmd_feed_regulator)
    for study, text in RUN_STUDIES.items():
        p = fsub.add_parser(study, help=f"{text} (= sewtol run feed_131 {study})")
        run_options(p)
        p.set_defaults(file="feed_131", study=study)
