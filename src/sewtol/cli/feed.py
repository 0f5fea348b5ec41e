"""`sewtol feed COMMAND`: the 131-42+3 feed's single machine (trajectory, metrics, regulator)
and its tolerance studies (scan, montecarlo, sobol) with the needle studies' flags
(--tolerances, --set, --n, --seed, --n-jobs, --progress, --out, --format), each meaning what it
means there."""

from __future__ import annotations

import sys

import numpy as np

from sewtol.cli.common import (
    Parser,
    as_flags,
    check_n,
    check_step,
    check_study,
    deviation_columns,
    emit,
    machine_context,
    machine_options,
    parse_sets,
    plot_option,
    plots,
    print_notes,
    progress_option,
    save_figure,
    save_plot,
    scan_figure,
    study_inputs,
    wide_option,
    write_outputs,
)
from sewtol.errors import ParameterError

MAX_SWEEP_POINTS = 100_000
FEED_SCREEN_N = 1000  # machines of the Monte-Carlo that picks each output's parameters
# the quantile bins of studies.montecarlo.contributors: its bias correction divides by n - bins,
# so the contributor table needs more machines than bins (n = 20 divided by zero; n < 20 gave
# meaningless shares: at n = 10 every tolerance 100 % of the variance)
CONTRIBUTOR_BINS = 20
# the columns a table prints without --wide (JSON and CSV keep every column): a scan's change
# of each output at each limit; each tolerance's share of an output's variance
COMPACT = {
    "scan": ("param", "side", "delta_mm", "change_lower_step_mm", "change_upper_step_mm",
             "change_differential_ratio"),
    "contributors": ("output", "param", "variance_pct", "cumulative_variance_pct"),
}


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


def _feed_study(args):
    """The feed's nominal (it must assemble) and tolerance set (a set of the feed's file, or
    FILE.toml[:SET]), every flag checked first."""
    from sewtol.cli.run import resolve_tolerances
    from sewtol.mechanisms.feed_131.analysis import metrics
    from sewtol.tables.feed_131 import as_mechanism

    args.seed = 0 if args.seed is None else args.seed
    args.n_jobs = 1 if args.n_jobs is None else args.n_jobs
    check_study(args)
    params = _feed_params(args)
    metrics(params)  # refuses, in one line, a nominal feed that cannot run
    tolerances = resolve_tolerances(as_mechanism(params), args.tolerances)
    if not tolerances.active().items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    return params, tolerances.check_against(params)


def _feed_context(args, params, tolerances) -> dict:
    return {"mechanism": "131-42+3 feed", "tolerances": tolerances.name,
            "tolerances_description": tolerances.description,
            # a scan draws nothing: no seed, no n
            "seed": getattr(args, "seed", None) if getattr(args, "n", None) is not None
            else None, "n": getattr(args, "n", None),
            "strategy": "none",  # the feed studies adjust nothing per machine
            "b_deg": float(params.b), "plate_mm": float(params.plate_mm),
            "material_mm": float(params.material_mm)}


def _feed_write(args, kind, params, tolerances, started, obj, frames, **extra):
    if not args.out:
        return
    inputs = study_inputs(args, f"feed_{kind}", params, tolerances, **extra)
    write_outputs(args, kind, inputs, started, obj, frames, [{"started_utc": started,
                                                                "resumed": False}])


def cmd_feed_scan(args):
    from sewtol.provenance import now
    from sewtol.tables.feed_131 import scan

    params, tolerances = _feed_study(args)
    started = now()
    frame = scan(params, tolerances)
    obj = {"context": _feed_context(args, params, tolerances),
           "rows": frame.to_dict(orient="records")}
    _feed_write(args, "scan", params, tolerances, started, obj, {"scan": frame})
    emit(args.format, obj=obj, frame=frame, compact=COMPACT["scan"], wide=args.wide)
    save_plot(args, lambda ax: scan_figure(frame, "change_differential_ratio", ax,
                                             "change of the differential ratio"))


def cmd_feed_montecarlo(args):
    from sewtol.provenance import now
    from sewtol.studies.montecarlo import check_sampling
    from sewtol.studies.summaries import contributor_table, output_summary
    from sewtol.tables import feed_131 as feed

    check_n(args.n, minimum=CONTRIBUTOR_BINS + 1)
    params, tolerances = _feed_study(args)
    as_flags(check_sampling, params, tolerances, args.n, args.seed)
    started = now()
    machines = feed.montecarlo(params, tolerances, args.n, args.seed, n_jobs=args.n_jobs,
                               progress=args.progress)
    summary = output_summary(machines, feed.OUTPUTS)
    contrib = contributor_table(machines, tolerances, feed.CONTRIBUTOR_OUTPUTS)
    obj = {"context": _feed_context(args, params, tolerances),
           "summary": summary.to_dict(orient="records"),
           "contributors": contrib.to_dict(orient="records"),
           "contributors_measure": "bias-corrected eta^2 on 20 quantile bins; variance_pct: "
                                   "share of the output's variance, with the explained sum and "
                                   "the interaction remainder as the last two rows per output"}
    _feed_write(args, "montecarlo", params, tolerances, started, obj,
                {"machines": deviation_columns(machines, tolerances.active().params),
                 "summary": summary, "contributors": contrib})
    emit(args.format, obj=obj, frame=summary)
    if args.format == "table":
        sys.stdout.write("\ncontributors (share of each output's variance, %)\n")
        emit("table", frame=contrib, compact=COMPACT["contributors"], wide=args.wide)
        over = sorted(set(contrib.loc[contrib["variance_pct"] < 0, "output"]))
        print_notes(args, [f"the first-order shares of {', '.join(over)} add up to more than "
                            "100 %: with this --n the estimates' noise exceeds the interactions "
                            "(a larger --n settles them)"] if over else [])
    save_plot(args, lambda ax: _contributor_figure(contrib, ax))


def _contributor_figure(contrib, ax):
    """Each output's share of variance (%) per tolerance (the single tolerances, not the sum
    and remainder rows)."""
    single = contrib[~contrib["param"].str.startswith("(")]
    table = single.pivot_table(index="param", columns="output", values="variance_pct",
                               sort=False).fillna(0.0)
    return plots().grouped_bars(list(table.index), {c: table[c] for c in table.columns},
                                 ax=ax, ylabel="share of the output's variance (%)",
                                 title="contributors (bias-corrected eta^2)")


def cmd_feed_sobol(args):
    from sewtol.provenance import now
    from sewtol.studies.sobol import check_power_of_two
    from sewtol.tables import feed_131 as feed

    as_flags(check_power_of_two, args.n)  # its error names --n
    check_n(args.n_screen, "--n-screen", minimum=100)
    params, tolerances = _feed_study(args)
    started = now()
    screen = feed.montecarlo(params, tolerances, args.n_screen, args.seed, n_jobs=args.n_jobs,
                             progress=args.progress)
    res, chosen = feed.sobol(params, tolerances, args.n, args.seed, screen, n_jobs=args.n_jobs,
                             progress=args.progress)
    table = res.to_dataframe().rename(columns={"case": "output"})
    obj = {"context": {**_feed_context(args, params, tolerances),
                       "screening_machines": args.n_screen},
           "parameters": chosen, "indices": table.to_dict(orient="records"),
           "convergence": res.convergence.to_dict(orient="records"),
           **({"assembly": res.assembly()} if res.has_failures else {})}
    _feed_write(args, "sobol", params, tolerances, started, obj,
                {**res.frames(), "indices": table},
                screening_machines=args.n_screen)
    emit(args.format, obj=obj, frame=table)
    if getattr(args, "plot", None) is not None:
        save_figure(args, sobol_panels(table))


def sobol_panels(table):
    """One panel per output of a feed Sobol table (column `output`): S1 and ST of the
    tolerances that output's indices were computed over, with their intervals."""
    import matplotlib.pyplot as plt

    outputs = list(dict.fromkeys(table["output"]))
    fig, axes = plt.subplots(len(outputs), 1, figsize=(7, 2.6 * len(outputs)), squeeze=False)
    for ax, name in zip(axes[:, 0], outputs, strict=True):
        plots().sobol_bars(table[table["output"] == name], ax=ax,
                            title=f"Sobol indices of {name}")
    fig.tight_layout()
    return fig


def add_feed(sub) -> None:
    """`sewtol feed COMMAND`: the single-machine commands, then the studies with the needle
    studies' flags."""
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

    def study(p, n=None, n_help=""):
        machine_options(p, example="b=25")
        p.add_argument("--tolerances", default="assumed",
                       help="a set of the feed's mechanism file: assumed (links and frame "
                            "pivots +/-0.05 mm, uniform) or links; FILE.toml or FILE.toml:SET "
                            "(default assumed)")
        if n is None:
            return
        p.add_argument("--n", type=int, default=n, help=n_help)
        # None: not given (as `sewtol run` has them), which _feed_study makes 0 and 1
        p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
        p.add_argument("--n-jobs", type=int, default=None,
                       help="parallel workers on this machine (joblib)")
        progress_option(p)
        p.add_argument("--out", default=None, metavar="DIR",
                       help="write the tables, the result and run.json here")

    p = fsub.add_parser("scan", help="each tolerance at its limits: steps, ratio and changes")
    study(p)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write scan.csv, scan.json and run.json here")
    plot_option(p, "the change of the differential ratio at each tolerance's limits")
    wide_option(p)
    p.set_defaults(func=cmd_feed_scan, seed=0, n_jobs=1)
    p = fsub.add_parser("montecarlo", help="feed outputs of N machines and their contributors")
    study(p, 2000, "machines (default 2000)")
    plot_option(p, "each output's shares of variance by tolerance")
    wide_option(p)
    p.set_defaults(func=cmd_feed_montecarlo)
    p = fsub.add_parser("sobol", help="Sobol indices of each feed output over the tolerances "
                        "that matter to it (SALib)")
    study(p, 256, "base samples, a power of two (default 256)")
    p.add_argument("--n-screen", type=int, default=FEED_SCREEN_N,
                   help="machines of the Monte-Carlo (same seed) that picks the tolerances "
                        f"each output's indices are computed over (default {FEED_SCREEN_N})")
    plot_option(p, "S1 and ST of each output with their intervals, a panel per output")
    p.set_defaults(func=cmd_feed_sobol)
