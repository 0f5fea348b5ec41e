"""`sewtol feed scan | montecarlo | sobol`: the feed's tolerance studies with the needle studies'
flags (--tolerances, --set, --n, --seed, --n-jobs, --progress, --out, --format), each meaning
what it means there. The helpers they share (flag checks, outputs, context) live in sewtol.cli.
"""

from __future__ import annotations

import sys

from sewtol.cli import (
    _as_flags,
    _check_n,
    _check_study,
    _deviation_columns,
    _feed_params,
    _inputs,
    _plot_option,
    _plots,
    _print_notes,
    _progress_option,
    _save_plot,
    _scan_figure,
    _write_outputs,
    emit,
    save_figure,
)
from sewtol.errors import ParameterError

FEED_SCREEN_N = 1000  # machines of the Monte-Carlo that picks each output's parameters
# the quantile bins of studies.montecarlo.contributors: its bias correction divides by n - bins,
# so the contributor table needs more machines than bins (n = 20 divided by zero; n < 20 gave
# meaningless shares: at n = 10 every tolerance 100 % of the variance)
CONTRIBUTOR_BINS = 20


def _feed_tolerances(args, params):
    from sewtol.mechanisms.feed_131.model import Feed131
    from sewtol.mechanisms.feed_131.studies import default_tolerances
    from sewtol.mechanisms.params import field_names
    from sewtol.tolerances import resolve

    builtin = {"assumed": default_tolerances(params)}
    tolerances = resolve(args.tolerances, builtin, field_names(Feed131))
    if not tolerances.active().items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    return tolerances.check_against(params)


def _feed_study(args):
    """The feed's nominal (it must assemble) and tolerance set, every flag checked first."""
    from sewtol.mechanisms.feed_131.studies import metrics

    _check_study(args)
    params = _feed_params(args)
    metrics(params)  # refuses, in one line, a nominal feed that cannot run
    return params, _feed_tolerances(args, params)


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
    inputs = _inputs(args, f"feed_{kind}", params, tolerances, **extra)
    _write_outputs(args, kind, inputs, started, obj, frames, [{"started_utc": started,
                                                                "resumed": False}])


def cmd_feed_scan(args):
    from sewtol.mechanisms.feed_131.studies import scan
    from sewtol.provenance import now

    params, tolerances = _feed_study(args)
    started = now()
    frame = scan(params, tolerances)
    obj = {"context": _feed_context(args, params, tolerances),
           "rows": frame.to_dict(orient="records")}
    _feed_write(args, "scan", params, tolerances, started, obj, {"scan": frame})
    emit(args.format, obj=obj, frame=frame)
    _save_plot(args, lambda ax: _scan_figure(frame, "change_differential_ratio", ax,
                                             "change of the differential ratio"))


def cmd_feed_montecarlo(args):
    from sewtol.mechanisms.feed_131 import studies as feed
    from sewtol.provenance import now
    from sewtol.studies.montecarlo import check_sampling

    _check_n(args.n, minimum=CONTRIBUTOR_BINS + 1)
    params, tolerances = _feed_study(args)
    _as_flags(check_sampling, params, tolerances, args.n, args.seed)
    started = now()
    machines = feed.montecarlo(params, tolerances, args.n, args.seed, n_jobs=args.n_jobs,
                               progress=args.progress)
    summary = feed.montecarlo_summary(machines)
    contrib = feed.contributor_table(machines, tolerances)
    obj = {"context": _feed_context(args, params, tolerances),
           "summary": summary.to_dict(orient="records"),
           "contributors": contrib.to_dict(orient="records"),
           "contributors_measure": "bias-corrected eta^2 on 20 quantile bins; variance_pct: "
                                   "share of the output's variance, with the explained sum and "
                                   "the interaction remainder as the last two rows per output"}
    _feed_write(args, "montecarlo", params, tolerances, started, obj,
                {"machines": _deviation_columns(machines, tolerances.active().params),
                 "summary": summary, "contributors": contrib})
    emit(args.format, obj=obj, frame=summary)
    if args.format == "table":
        sys.stdout.write("\ncontributors (share of each output's variance, %)\n")
        emit("table", frame=contrib)
        over = sorted(set(contrib.loc[contrib["variance_pct"] < 0, "output"]))
        _print_notes(args, [f"the first-order shares of {', '.join(over)} add up to more than "
                            "100 %: with this --n the estimates' noise exceeds the interactions "
                            "(a larger --n settles them)"] if over else [])
    _save_plot(args, lambda ax: _contributor_figure(contrib, ax))


def _contributor_figure(contrib, ax):
    """Each output's share of variance (%) per tolerance (the single tolerances, not the sum
    and remainder rows)."""
    single = contrib[~contrib["param"].str.startswith("(")]
    table = single.pivot_table(index="param", columns="output", values="variance_pct",
                               sort=False).fillna(0.0)
    return _plots().grouped_bars(list(table.index), {c: table[c] for c in table.columns},
                                 ax=ax, ylabel="share of the output's variance (%)",
                                 title="contributors (bias-corrected eta^2)")


def cmd_feed_sobol(args):
    from sewtol.mechanisms.feed_131 import studies as feed
    from sewtol.provenance import now
    from sewtol.studies.sobol import check_power_of_two

    try:
        check_power_of_two(args.n)
    except ParameterError as exc:
        raise ParameterError("--n", exc.rule, args.n) from None
    _check_n(args.n_screen, "--n-screen", minimum=100)
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
           "convergence": res.convergence.to_dict(orient="records")}
    _feed_write(args, "sobol", params, tolerances, started, obj,
                {"indices": table, "convergence": res.convergence},
                screening_machines=args.n_screen)
    emit(args.format, obj=obj, frame=table)
    _save_sobol_panels(args, table)


def sobol_panels(table):
    """One panel per output of a feed Sobol table (column `output`): S1 and ST of the
    tolerances that output's indices were computed over, with their intervals."""
    import matplotlib.pyplot as plt

    outputs = list(dict.fromkeys(table["output"]))
    fig, axes = plt.subplots(len(outputs), 1, figsize=(7, 2.6 * len(outputs)), squeeze=False)
    for ax, name in zip(axes[:, 0], outputs, strict=True):
        _plots().sobol_bars(table[table["output"] == name], ax=ax,
                            title=f"Sobol indices of {name}")
    fig.tight_layout()
    return fig


def _save_sobol_panels(args, table) -> None:
    if getattr(args, "plot", None) is None:
        return
    save_figure(args, sobol_panels(table))


def add_feed_studies(fsub, common) -> None:
    """feed scan, montecarlo and sobol with the needle studies' flags."""
    def study(p, n=None, n_help=""):
        common(p, example="b=25")
        p.add_argument("--tolerances", default="assumed",
                       help="assumed (links and frame pivots +/-0.05 mm, uniform), FILE.toml or "
                            "FILE.toml:SET (default assumed)")
        if n is None:
            return
        p.add_argument("--n", type=int, default=n, help=n_help)
        p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
        p.add_argument("--n-jobs", type=int, default=1,
                       help="parallel workers on this machine (joblib)")
        _progress_option(p)
        p.add_argument("--out", default=None, metavar="DIR",
                       help="write the tables, the result and run.json here")

    p = fsub.add_parser("scan", help="each tolerance at its limits: steps, ratio and changes")
    study(p)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write scan.csv, scan.json and run.json here")
    _plot_option(p, "the change of the differential ratio at each tolerance's limits")
    p.set_defaults(func=cmd_feed_scan, seed=0, n_jobs=1)
    p = fsub.add_parser("montecarlo", help="feed outputs of N machines and their contributors")
    study(p, 2000, "machines (default 2000)")
    _plot_option(p, "each output's shares of variance by tolerance")
    p.set_defaults(func=cmd_feed_montecarlo)
    p = fsub.add_parser("sobol", help="Sobol indices of each feed output over the tolerances "
                        "that matter to it (SALib)")
    study(p, 256, "base samples, a power of two (default 256)")
    p.add_argument("--n-screen", type=int, default=FEED_SCREEN_N,
                   help="machines of the Monte-Carlo (same seed) that picks the tolerances "
                        f"each output's indices are computed over (default {FEED_SCREEN_N})")
    _plot_option(p, "S1 and ST of each output with their intervals, a panel per output")
    p.set_defaults(func=cmd_feed_sobol)


