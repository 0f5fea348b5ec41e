"""`sewtol needle COMMAND`: the 208 needle drive's single-machine figures (nominal, deviation,
frames); and the needle_208 fast path of `sewtol run FILE STUDY` (FAST_PATH: scan, worst-case,
montecarlo, sobol, ppm, allocation, strategies, settings, with the plug-in's flags of
needle_flags), which `sewtol needle STUDY` reaches as an alias of `sewtol run needle_208 STUDY`
(cli.run.needle_aliases: `needle guides` is `run needle_208 settings`)."""

from __future__ import annotations

import sys

import numpy as np

from sewtol.cli.common import (
    FORMATS,
    Parser,
    as_flags,
    check_step,
    cluster,
    deviation_columns,
    emit,
    machine_context,
    machine_options,
    not_offered,
    open_store,
    parse_sets,
    plot_option,
    plots,
    print_notes,
    run_history,
    save_plot,
    scan_figure,
    study_inputs,
    write_outputs,
)
from sewtol.errors import ParameterError

BETA_LIMIT_DEG = 360.0
SOBOL_RESAMPLES, SOBOL_CONF_LEVEL = 200, 0.95
# the columns a table prints without --wide: what a decision needs (JSON and CSV keep every
# column; `failed` is the sum of the failure counts, so ok + out_of_spec + failed = n shows)
COMPACT = {
    "scan": ("param", "side", "delta_mm", "beta_deg", "plus_um", "minus_um", "total_um",
             "beta_at_bound"),
    "montecarlo": ("case", "n", "ok", "out_of_spec", "failed", "yield", "yield_ci_low",
                   "yield_ci_high", "p95_um"),
    "strategies": ("strategy", "resolution", "setting_error", "n", "ok", "out_of_spec", "failed",
                   "yield", "yield_ci_low", "yield_ci_high", "p95_um", "at_limit_share"),
    "guides": ("guide", "beta_opt_deg", "total_um", "window_width_deg", "yield_fixed_beta",
               "yield_adjusted_beta", "yield_adjusted", "failed"),
}


def _needle_params(args):
    from sewtol.mechanisms.needle_208.model import Needle208

    sets = parse_sets(args.set, Needle208)
    shift = getattr(args, "guide_shift_um", None)
    if shift is not None:
        if not np.isfinite(shift):
            raise ParameterError("--guide-shift-um", "must be a finite number of um", shift)
        if "guide_shift_um" in sets and sets["guide_shift_um"] != shift:
            raise ParameterError("--guide-shift-um", "gives the guide shift that --set "
                                 f"guide_shift_um={sets['guide_shift_um']:g} also gives; give "
                                 "one of them", shift)
        sets["guide_shift_um"] = float(shift)
    return Needle208.nominal(args.frame).override(**sets)


def _beta_options(p, limit=("--limit-um", "--limit")):
    """--beta-range LOW HIGH and --limit-um (defaults 10 35 and 10, resolved when checked)."""
    p.add_argument("--beta-range", nargs=2, type=float, default=None, metavar=("LOW", "HIGH"),
                   help="regulating range searched for beta* (deg); default 10 35")
    p.add_argument(*limit, type=float, default=None,
                   help="SumDelta limit (um) of the yield and the window; default 10 (`sewtol "
                        "run needle_208 STUDY`: the same as --limit)")


def _beta_search_range(args, strategy=None) -> tuple:
    """--beta-range (default 10 35); with a strategy that adjusts beta, the strategy's own range."""
    rng = getattr(args, "beta_range", None) or (10.0, 35.0)
    for c in getattr(strategy, "compensators", ()):
        if c.name == "beta":
            rng = (c.low, c.high)
    return tuple(rng)


def _beta_star_figures(args, params, strategy=None):
    """The nominal figures at beta* in the searched range (`_beta_search_range`), at --limit-um,
    without the window (what `needle nominal` prints; the studies hold beta* and ask whether
    it lies on a bound)."""
    from sewtol.mechanisms.needle_208.single import nominal_figures

    return nominal_figures(params, _beta_search_range(args, strategy),
                           getattr(args, "limit_um", None) or 10.0, window=False)


def _at_beta_star(args, params, strategy=None):
    """The nominal with beta at its beta* (`_beta_star_figures`): what "beta fixed" means in
    every needle study (montecarlo, sobol, guides, strategies, worst-case)."""
    return params.override(beta=_beta_star_figures(args, params, strategy).beta_opt_deg)


def _fixed_record(args, params, strategy=None) -> dict:
    """The fixed case's beta, what it means, and whether that beta* lies on a range bound."""
    from sewtol.tables.needle_208 import FIXED_BETA_MEANS

    return {"fixed_beta_deg": float(params.beta), "fixed_beta_means": FIXED_BETA_MEANS["optimum"],
            "fixed_beta_at_bound": _beta_star_figures(args, params, strategy).beta_at_bound}


def _fixed_notes(record) -> list[str]:
    if not record.get("fixed_beta_at_bound"):
        return []
    return [f"the fixed case's beta = {record['fixed_beta_deg']:.4f} deg, the nominal's beta*, "
            "reaches a bound of the searched range: the nominal's optimum may lie outside it"]


def _context(args, params, tolerances, strategy) -> dict:
    """What decides a study's numbers, carried by its JSON (its CSVs: run.json beside them)."""
    from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME

    return {"mechanism": "needle_208",
            "tolerances": None if tolerances is None else tolerances.name,
            "seed": getattr(args, "seed", None),
            "n": getattr(args, "n", None), "frame": getattr(args, "frame", None) or DEFAULT_FRAME,
            "guide_shift_um": float(params.guide_shift_um),
            "guide_angle_deg": float(params.guide_angle),
            "strategy": "beta" if strategy is None else strategy.name,
            "beta_search_range_deg": list(_beta_search_range(args, strategy)),
            "limit_um": getattr(args, "limit_um", None) or 10.0,
            # where limit_um comes from: "default" (10 um), "command line" or "file" (`run FILE`)
            "spec_source": getattr(args, "spec_source", None) or "default",
            # the model that computed the numbers (`run FILE` says "generic" on its sampled path)
            "path": "needle_208"}


def _check_beta_range(args):
    """--beta-range and --limit-um (defaults 10 35 and 10 um where a command takes them)."""
    from sewtol.mechanisms.needle_208 import beta as sb

    if getattr(args, "beta_range", None) is None:
        args.beta_range = list(sb.DEFAULT_RANGE_DEG)
    if getattr(args, "spec_source", None) is None:  # `run FILE` sets "file" or "command line"
        args.spec_source = "default" if getattr(args, "limit_um", None) is None else "command line"
    if getattr(args, "limit_um", None) is None:
        args.limit_um = sb.DEFAULT_LIMIT_UM
    lo, hi = args.beta_range
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ParameterError("--beta-range", "must be LOW HIGH with LOW < HIGH (deg)",
                             args.beta_range)
    if not (-BETA_LIMIT_DEG <= lo and hi <= BETA_LIMIT_DEG):
        raise ParameterError("--beta-range", f"must lie within +/-{BETA_LIMIT_DEG:g} deg",
                             args.beta_range)
    if not (np.isfinite(args.limit_um) and args.limit_um > 0):
        raise ParameterError("--limit-um", "must be a positive number of um", args.limit_um)


def _study_nominal(args):
    """The nominal machine of a study: it must assemble, or nothing is computed or written."""
    from sewtol.mechanisms.needle_208.model import check_assembly

    # `run FILE STUDY` on the needle fast path gives the file's nominal machine (nominal_params)
    given = getattr(args, "nominal_params", None)
    params = _needle_params(args) if given is None else given
    check_assembly(params)
    return params


def _tolerances(args):
    """`run`'s set, resolved (args.tolerance_set); --housing: plus the housing bores (a set that
    tolerances one already is refused)."""
    from sewtol.tolerances import with_housing

    return with_housing(args.tolerance_set) if args.housing else args.tolerance_set


def cmd_needle_frames(args):
    from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME, frames_table, list_frames

    # JSON: every record in full (the table: one summary row per frame), as the studies print it
    emit(args.format, frame=frames_table(),
         obj={"context": {"mechanism": "208 needle drive", "default_frame": DEFAULT_FRAME},
              "rows": [f.to_dict() for f in list_frames()]})


def cmd_needle_nominal(args):
    from sewtol.mechanisms.needle_208.single import nominal_figures

    _check_beta_range(args)
    params = _needle_params(args)
    fig = nominal_figures(params, tuple(args.beta_range), args.limit_um)
    # the nominal machine: no tolerance set, nothing drawn; beta* searched as in every study
    emit(args.format, obj={**fig.to_dict(), "context": _context(args, params, None, None)},
         frame=fig.to_dataframe())
    print_notes(args, fig.notes())

    def draw(ax):
        from sewtol.mechanisms.needle_208 import beta as sb
        from sewtol.mechanisms.needle_208 import metrics as nm

        betas = np.linspace(*args.beta_range, 201)
        totals = sb.totals_on_grid(nm.columns(params)[0], betas)[0]
        plots().sum_delta_vs_beta(betas, totals, fig.beta_opt_deg, fig.window_deg,
                                   fig.limit_um, ax=ax)

    save_plot(args, draw)


def cmd_needle_deviation(args):
    from sewtol.mechanisms.needle_208.single import deviation_table

    check_step(args.step_deg)
    p = _needle_params(args)
    if args.beta is not None:
        p = p.override(beta=args.beta)
    frame = deviation_table(p, args.step_deg)
    emit(args.format, obj={"context": machine_context(args, p, beta_deg=float(p.beta)),
                           "rows": frame.to_dict(orient="records")}, frame=frame)
    save_plot(args, lambda ax: plots().deviation_vs_crank(
        {f"beta = {float(p.beta):.4f} deg": frame}, ax=ax))


def cmd_needle_scan(args):
    from sewtol.tables.needle_208 import scan

    strategy = _strategy(args)
    _check_beta_range(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    rows = scan(params, tolerances, limit_um=args.limit_um, range_deg=tuple(args.beta_range),
                strategy=strategy)
    frame = rows.to_dataframe()
    context = _context(args, params, tolerances, strategy)
    obj = {"context": context, "rows": rows.to_records()}
    if args.out:
        from sewtol.provenance import now

        started = now()
        inputs = study_inputs(args, "scan", params, tolerances, limit_um=args.limit_um,
                         beta_search_range_deg=list(args.beta_range), context=context)
        write_outputs(args, "scan", inputs, started, obj, {"scan": frame},
                       [{"started_utc": started, "resumed": False}])
    compact = (*COMPACT["scan"], *[c for c in frame.columns if c.endswith("_setting")],
               "status")
    emit(args.format, obj=obj, frame=frame, compact=compact, wide=args.wide)
    if "beta_at_bound" in frame:
        print_notes(args, _plateau_notes(frame, list(args.beta_range)))
    save_plot(args, lambda ax: scan_figure(frame, "total_um", ax, "SumDelta at beta* (um)",
                                             args.limit_um))


def _plateau_notes(frame, range_deg) -> list[str]:
    """In words, the scan rows whose beta* is a plateau reaching an end of the searched range
    (beta_at_bound): the plateau's extent, the end it reaches, and what that means."""
    from sewtol.mechanisms.needle_208.adjust import PLATEAU_TOL_UM
    from sewtol.studies.montecarlo import PINNED_PLATEAU

    rows = frame[frame["beta_at_bound"].astype(bool)]
    if rows.empty:
        return []
    lo, hi = range_deg
    notes = [f"{len(rows)} of {len(frame)} rows have beta* on a bound of the searched range "
             f"{range_deg} deg (column beta_at_bound): SumDelta stays within "
             f"{PLATEAU_TOL_UM:g} um of its least value for every beta of a plateau that runs "
             "into an end of the range; beta_deg is the plateau's centre"]
    if "beta_low_deg" not in rows:
        return notes
    for r in rows.itertuples():
        a, b = float(r.beta_low_deg), float(r.beta_high_deg)
        end = lo if abs(a - lo) <= abs(hi - b) else hi
        where = f"{r.param} {r.side}: SumDelta {r.total_um:.4f} um for beta {a:.4f} ... {b:.4f} deg"
        if a <= lo + 1e-6 * (hi - lo) and b >= hi - 1e-6 * (hi - lo):
            notes.append(f"{where}, the whole searched range: beta does not change SumDelta "
                         "there")
        elif b - a < PINNED_PLATEAU:
            notes.append(f"{where}, pinned at the range's end {end:g} deg: SumDelta still falls "
                         "there, so the optimum lies outside the range (widen --beta-range)")
        else:
            notes.append(f"{where}, a flat plateau reaching the range's end {end:g} deg: any "
                         "beta on it does as well, and SumDelta may stay flat or fall beyond "
                         f"{end:g} deg (a wider --beta-range shows which)")
    return notes


def cmd_needle_montecarlo(args):
    """Beta fixed and adjusted per machine (tables.needle_208.montecarlo), or with --adjust the
    per-machine table of one strategy, each with its study folder and cluster. `run FILE
    montecarlo` on the needle fast path runs this command itself (args.file_inputs names the
    file in run.json), so both print the same bytes."""
    from sewtol.mechanisms.needle_208.kernels import ahead_of_time, runs_ahead
    from sewtol.studies.montecarlo import CHUNK, check_sampling, montecarlo_bytes
    from sewtol.tables.needle_208 import montecarlo

    strategy = _strategy(args)  # --n, --seed, --n-jobs, --out: checked by `run`
    _check_beta_range(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    limit, rng = args.limit_um, tuple(args.beta_range)
    if strategy is None:  # the machines held compactly; --out writes their table in chunks
        as_flags(check_sampling, params, tolerances, args.n, args.seed, CHUNK, None,
                 montecarlo_bytes(1, 1))
    else:
        as_flags(check_sampling, params, tolerances, args.n, args.seed, CHUNK)
    if strategy is not None:
        if args.plot is not None:
            raise ParameterError("--plot", "is not offered with --adjust (the histograms show "
                                 "beta fixed against beta adjusted)", args.plot)
        return _adjusted_montecarlo(args, params, tolerances, strategy, limit)
    inputs = study_inputs(args, "montecarlo", params, tolerances, limit_um=limit,
                          beta_search_range_deg=list(rng), chunk_size=CHUNK,
                          strategy="beta fixed at the nominal's beta* (fixed_beta=optimum) and "
                          "beta re-optimised per machine")

    def study(store, client):
        # a short run on one thread, numba never imported (needle_208.kernels.runs_ahead)
        with ahead_of_time(runs_ahead("montecarlo", args.n, args.n_jobs, client is not None)):
            res = montecarlo(params, tolerances, args.n, args.seed, limit_um=limit,
                             range_deg=rng, n_jobs=args.n_jobs, progress=args.progress,
                             store=store, chunk_size=CHUNK, scheduler=client)
            fixed = _beta_star_figures(args, params)
        record = res.to_dict()
        record["extra"]["fixed_beta_at_bound"] = fixed.beta_at_bound
        record["context"] = _context(args, params, tolerances, None)
        # the per-machine table only for --out (the summary and the JSON never need it)
        # written chunk by chunk: the whole table is never held
        return res, record, {"machines": (deviation_columns(f, res.params)
                                          for f in res.table.frames()),
                             "summary": res.summary_frame()} if args.out else {}

    res, record = _in_study_folder(args, inputs, study)
    emit(args.format, obj=record, frame=res.summary_rows(), compact=COMPACT["montecarlo"],
         wide=args.wide)
    print_notes(args, _montecarlo_notes(record))
    save_plot(args, lambda ax: plots().montecarlo_histograms(
        res.values("SumDelta_um"), res.values("SumDelta_um_adjusted"), limit,
        (res.yield_of("fixed"), res.yield_of("adjusted")), ax=ax))


def _in_study_folder(args, inputs, study):
    """(result, record) of study(store, client) -> (result, record, tables), run in its study
    folder (--out/--resume: chunks, runs.json, the tables, montecarlo.json, run.json) and on
    its cluster (--scheduler)."""
    from sewtol.provenance import now

    started = now()
    store = open_store(args, inputs)
    try:
        runs = run_history(store, started)
        with cluster(args) as client:
            res, record, tables = study(store, client)
        write_outputs(args, "montecarlo", inputs, started, record, tables, runs)
    finally:
        if store is not None:
            store.close()
    return res, record


def _montecarlo_notes(record) -> list[str]:
    extra = record["extra"]
    k, pinned = extra["beta_at_bound"], extra["beta_pinned_at_bound"]
    return ([f"yield intervals: {record['yield_ci']['method']}, 95 %"]
            + _fixed_notes({**extra, "fixed_beta_deg": extra["nominal_beta_deg"]})
            + ([f"{k} of {record['n']} machines have an adjusted beta* whose optimum reaches a "
                f"bound of the searched range {extra['beta_search_range_deg']} deg; {pinned} of "
                "them are pinned there (SumDelta still falling: the optimum lies outside the "
                "range), the others sit on a flat plateau"] if k else []))


def _strategy(args, setting_errors: bool = False):
    """The strategy of --adjust/--range/--step/--resolution/--setting-error (None without
    --adjust). Only the strategies study sets compensators with their setting errors
    (`setting_errors=True`); every other study sets them exactly, so --setting-error is refused
    there and the built-in errors are dropped from the strategy (and its record).

    --beta-range means the range searched for beta everywhere: with --adjust naming beta it is
    beta's --range (giving both is refused); with --adjust not naming beta nothing searches beta,
    so it is refused."""
    from sewtol.mechanisms.needle_208.compensators import Strategy, parse_cli
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.mechanisms.params import field_names

    adjust, ranges = getattr(args, "adjust", None), list(args.range or [])
    given = getattr(args, "beta_range", None)
    if adjust is not None and given is not None:
        names = [s.strip() for s in adjust.split(",")]
        if "beta" not in names:
            raise ParameterError("--beta-range", f"is the range searched for beta, which "
                                 f"--adjust {adjust} does not adjust", given)
        if any(r.partition("=")[0].strip() == "beta" for r in ranges):
            raise ParameterError("--beta-range", "gives beta's range, which --range beta=... "
                                 "also gives; give one of them", given)
        lo, hi = given
        ranges.append(f"beta={lo!r},{hi!r}")
    errors = getattr(args, "setting_error", None) or ()
    if errors and not setting_errors:
        raise ParameterError("--setting-error", "is applied by the strategies study only "
                             "(sewtol needle strategies); this study sets every compensator "
                             "exactly", errors[0])
    strategy = parse_cli(adjust, ranges, args.step, args.resolution,
                         valid=field_names(Needle208), setting_errors=errors)
    if strategy is not None and not setting_errors:
        strategy = Strategy(strategy.name, tuple(c.with_changes(setting_error=None)
                                                 for c in strategy.compensators))
    return strategy


def _strategy_record(strategy) -> dict:
    """{"compensators": each compensator's box, step, resolution, mode and setting error}, or
    {} without a strategy (the studies' JSON and run.json)."""
    return {} if strategy is None else {"compensators": {
        c.name: {"low": c.low, "high": c.high, "step": c.step, "resolution": c.resolution,
                 "mode": c.mode, **({} if c.setting_error is None else
                                    {"setting_error": c.setting_error.to_dict()})}
        for c in strategy.compensators}}


def _adjusted_montecarlo(args, params, tolerances, strategy, limit):
    """needle montecarlo --adjust: the per-machine table of one strategy and its summary."""
    from sewtol.studies.montecarlo import CHUNK, sample_machines
    from sewtol.tables.needle_208 import adjusted_montecarlo_model, adjusted_summary

    params = _at_beta_star(args, params, strategy)
    inputs = study_inputs(args, "montecarlo_adjusted", params, tolerances, limit_um=limit,
                          chunk_size=CHUNK, strategy=strategy.name, **_strategy_record(strategy))

    def study(store, client):
        machines = sample_machines(adjusted_montecarlo_model, params, tolerances, args.n,
                                   args.seed, args.n_jobs, args.progress, store=store,
                                   chunk_size=CHUNK, scheduler=client, strategy=strategy,
                                   limit_um=limit)
        summary = adjusted_summary(params, machines, strategy, limit)
        record = {**summary.iloc[0].to_dict(), "seed": args.seed, "tolerances": tolerances.name,
                  **_strategy_record(strategy), **_fixed_record(args, params, strategy),
                  "context": _context(args, params, tolerances, strategy)}
        return summary, record, {"machines": deviation_columns(
            machines, tolerances.active().params), "summary": summary}

    summary, record = _in_study_folder(args, inputs, study)
    emit(args.format, obj=record, frame=summary, compact=COMPACT["strategies"], wide=args.wide)
    print_notes(args, _fixed_notes(record))


def _measurement(args):
    """--measurement-error SD_UM [--measured-positions K]: None for none or 0."""
    from sewtol.measurement_error import DEFAULT_POSITIONS, parse_cli

    sd, k = getattr(args, "measurement_error", None), getattr(args, "measured_positions", None)
    if sd is None:
        if k is not None:
            raise ParameterError("--measured-positions", "needs --measurement-error (the sd "
                                 "of a reading)", k)
        return None
    return parse_cli(sd, DEFAULT_POSITIONS if k is None else k)


def cmd_needle_strategies(args):
    from sewtol.mechanisms.needle_208.compensators import Strategy, default_strategies
    from sewtol.mechanisms.needle_208.kernels import ahead_of_time, runs_ahead
    from sewtol.provenance import now
    from sewtol.tables.needle_208 import strategies_table

    not_offered(args, "needle strategies",
                 resume="it keeps no checkpoints; rerun with the same seed",
                 scheduler="it runs on this machine; use --n-jobs")
    strategy = _strategy(args, setting_errors=True)
    measurement = _measurement(args)
    rows = default_strategies()
    if strategy is not None:
        if strategy.name in {r.name for r in rows}:
            strategy = Strategy(strategy.name + " (given)", strategy.compensators)
        rows.append(strategy)
    # on workers (each on the compiled kernels) or a short run, this process never imports
    # numba: the nominal's beta* and its figures too
    with ahead_of_time(runs_ahead("strategies", args.n, args.n_jobs)):
        params, tolerances = _at_beta_star(args, _study_nominal(args)), _tolerances(args)
        started = now()
        # per machine only what the rows read, unless --out writes the per-machine tables
        res = as_flags(lambda: strategies_table(
            params, tolerances, args.n, args.seed, rows, n_jobs=args.n_jobs,
            progress=args.progress, measurement=measurement, per_machine=bool(args.out)))
        fixed = _fixed_record(args, params, strategy)
    table = res.to_dataframe()
    frames = {"strategies": table}
    for r in rows:
        safe = "".join(ch if ch.isalnum() else "_" for ch in r.name)
        # piece by piece, made only when --out writes it
        frames[f"machines_{safe}"] = (deviation_columns(f, res.params)
                                      for f in res.machine_chunks(r.name))
    reading = {} if measurement is None else {"measurement_error": measurement.to_dict()}
    inputs = study_inputs(args, "strategies", params, tolerances, limit_um=10.0,
                          strategies={r.name: _strategy_record(r)["compensators"] for r in rows}, **reading)
    context = {**_context(args, params, tolerances, strategy),
               "strategy": [r.name for r in rows], "limit_um": 10.0, **reading}
    obj = {"context": context, **fixed, "rows": table.to_dict(orient="records")}
    write_outputs(args, "strategies", inputs, started, obj, frames, [])
    emit(args.format, obj=obj, frame=table, compact=COMPACT["strategies"], wide=args.wide)
    save_plot(args, lambda ax: plots().grouped_bars(
        list(table["strategy"]), {"yield": table["yield"]}, ax=ax, ylabel="yield",
        errors={"yield": (table["yield_ci_low"], table["yield_ci_high"])},
        title=f"yield by adjustment strategy, {args.n} machines (95 % interval)"))


def _adjust_options(p):
    """--range, --step, --resolution and --setting-error of the needle's compensators."""
    p.add_argument("--range", action="append", metavar="NAME=LOW,HIGH",
                   help="a compensator's range (offset from as built; beta absolute, deg)")
    p.add_argument("--step", action="append", metavar="NAME=VALUE",
                   help="discrete settings low + k*VALUE (a shim set, a graduated clamp)")
    p.add_argument("--resolution", action="append", metavar="NAME=VALUE",
                   help="how finely the assembler sets it (strategies: the setting made is "
                        "rounded to a multiple of VALUE; achieved_um: the worst within "
                        "+/-VALUE/2)")
    p.add_argument("--setting-error", action="append", metavar="NAME=SD",
                   help="strategies: the error of a setting made, normal with this sd (or "
                        "NAME=uniform:HALF_WIDTH; 0: exact), in the compensator's unit; the "
                        "ones set after it are re-set (docs/adjustment.md)")


def cmd_needle_sobol(args):
    from sewtol.provenance import now
    from sewtol.studies.sobol import CHUNK, check_power_of_two, check_sobol
    from sewtol.tables.needle_208 import needle_sobol

    as_flags(check_power_of_two, args.n)  # its error names --n
    strategy = _strategy(args)
    _check_beta_range(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    as_flags(check_sobol, params, tolerances, args.n, args.seed, args.second_order)
    rng = tuple(args.beta_range)
    started = now()
    context = _context(args, params, tolerances, strategy)
    inputs = study_inputs(args, "sobol", params, tolerances, beta_search_range_deg=list(rng),
                     limit_um=args.limit_um, second_order=args.second_order, context=context,
                     chunk_size=CHUNK, resamples=SOBOL_RESAMPLES,
                     confidence_level=SOBOL_CONF_LEVEL,
                     strategy="beta fixed at the nominal's beta* (fixed_beta=optimum) and beta "
                     "re-optimised per sample" if strategy is None else "beta fixed at the "
                     f"nominal's beta* (fixed_beta=optimum) and {strategy.name} adjusted per "
                     "sample (exact joint optimum)", **_strategy_record(strategy))
    store = open_store(args, inputs)
    try:
        runs = run_history(store, started)
        with cluster(args) as client:
            res = needle_sobol(params, tolerances, args.n, args.seed, range_deg=rng,
                               n_jobs=args.n_jobs, progress=args.progress, store=store,
                               resamples=SOBOL_RESAMPLES, conf_level=SOBOL_CONF_LEVEL,
                               chunk_size=CHUNK, scheduler=client, strategy=strategy,
                               limit_um=args.limit_um, second_order=args.second_order)
        write_outputs(args, "sobol", inputs, started, _sobol_json(res, args.second_order, context),
                       res.frames(), runs)
    finally:
        if store is not None:
            store.close()
    emit(args.format, obj=_sobol_json(res, args.second_order, context), frame=res.to_dataframe())
    if args.second_order and args.format == "table":
        sys.stdout.write("\nsecond-order indices S2 (pairs; conf: half-width of the "
                         f"{SOBOL_CONF_LEVEL:.0%} bootstrap interval)\n")
        emit("table", frame=res.second_order_frame())
    print_notes(args, res.notes())
    save_plot(args, lambda ax: plots().sobol_bars(
        res.to_dataframe().query("case == 'adjusted_beta'") if strategy is None
        else res.to_dataframe()[res.to_dataframe()["case"] != "fixed_beta"], ax=ax,
        title="Sobol indices of SumDelta, adjusted"))


def _sobol_json(res, second_order: bool, context: dict):
    """One shape for both forms: the S1/ST records under "indices", the context, and with
    --second-order the S2 pairs under "second_order"."""
    return {"indices": res.to_records(),
            **({"second_order": res.second_order_frame().to_dict(orient="records")}
               if second_order else {}),
            "n": res.n, "seed": res.seed, "tolerances": res.tolerances,
            "model_runs_per_case": res.model_runs, "context": context,
            **({"assembly": res.assembly()} if res.has_failures else {})}


def _small_study(args):
    """The strategy, machine and set of settings/allocation (--n, --seed: checked by `run`)."""
    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    if not tolerances.active().items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(params)
    return strategy, params, tolerances


def cmd_needle_guides(args):
    from sewtol.tables.needle_208 import compare_guides

    strategy, params, tolerances = _small_study(args)
    _check_beta_range(args)
    table = compare_guides(params, tolerances, args.n, args.seed, strategy=strategy,
                           range_deg=tuple(args.beta_range), limit_um=args.limit_um,
                           n_jobs=args.n_jobs, progress=args.progress)
    obj = {"tolerances": tolerances.name, "n": args.n, "seed": args.seed,
           "fixed_beta_means": "each guide setting's own beta* (as `sewtol needle nominal` "
                               "prints it for that guide)",
           "context": _context(args, params, tolerances, strategy),
           "strategy": "fixed beta and beta adjusted" if strategy is None else strategy.name,
           **_strategy_record(strategy),
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table, compact=COMPACT["guides"], wide=args.wide)
    save_plot(args, lambda ax: plots().grouped_bars(
        list(table["guide"]), {"beta fixed at the guide's beta*": table["yield_fixed_beta"],
                               **({"beta adjusted": table["yield_adjusted_beta"]}
                                  if strategy is None else
                                  {f"{strategy.name} adjusted": table["yield_adjusted"]})}, ax=ax,
        ylabel="yield", title=f"yield by guide setting, {args.n} machines"))


def cmd_needle_allocation(args):
    from sewtol.tables.needle_208 import allocate

    strategy, params, tolerances = _small_study(args)  # --target: checked by `run`
    res = allocate(params, tolerances, args.target, args.n, args.seed, strategy=strategy)
    table = res.to_dataframe()
    if strategy is None:
        table["lower_mm"], table["upper_mm"] = -table["tolerance_mm"], table["tolerance_mm"]
    obj = {"tolerances": tolerances.name, "strategy": res.adjust, "target": res.target,
           "yield_adjusted": res.yield_, "n": res.n, "seed": res.seed,
           "scale": res.scale,
           "cost_model": "reciprocal: sum c_i / width_i; shape (c_i / s_i^2)^(1/3), common "
                         "scale by bisection on the Monte-Carlo yield (common random numbers)",
           **_strategy_record(strategy),
           "context": _context(args, params, tolerances, strategy),
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)
    save_plot(args, lambda ax: allocation_figure(table, tolerances.name, res.target, ax))


def allocation_figure(table, reference: str, target: float, ax):
    """Each tolerance's width (upper - lower, um) in the reference set and as allocated."""
    widths = {f"set {reference}": 1000 * (table["reference_upper_mm"] - table["reference_lower_mm"]),
              f"allocated (yield {target:g})": 1000 * (table["upper_mm"] - table["lower_mm"])}
    ax = plots().grouped_bars(list(table["param"]), widths, ax=ax,
                               ylabel="tolerance width (\u00b5m, log scale)",
                               title="Tolerance allocation: widths before and after")
    ax.set_yscale("log")  # the widths span two decades (LM about 1 mm, AB about 10 um)
    return ax


def cmd_needle_worst_case(args):
    from sewtol.tables.needle_208 import MAX_CORNER_PARAMS, worst_case_table

    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    active = tolerances.active()
    if not active.items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    if len(active.items) > MAX_CORNER_PARAMS:
        raise ParameterError("--tolerances", "worst case enumerates corners; at most "
                             f"{MAX_CORNER_PARAMS} tolerances", len(active.items))
    tolerances.check_against(params)
    _check_beta_range(args)
    params = _at_beta_star(args, params, strategy)
    table = worst_case_table(params, tolerances, tuple(args.beta_range), strategy=strategy)
    obj = {"tolerances": tolerances.name, **_fixed_record(args, params, strategy),
           "context": _context(args, params, tolerances, strategy),
           "strategy": "beta" if strategy is None else strategy.name,
           **_strategy_record(strategy),
           "method": "every corner and the centre, the best 3 polished by L-BFGS-B in the box "
                     "(never below any evaluated point; not proven global)",
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)
    print_notes(args, _fixed_notes(obj) + [
        f"the worst machine's beta* in {r['case']} reaches a bound of the searched range: its "
        "optimum may lie outside it" for r in obj["rows"] if r.get("beta_at_bound")])
    save_plot(args, lambda ax: plots().grouped_bars(
        list(table["case"]), {"worst SumDelta in the box": table["total_um"]}, ax=ax,
        ylabel="SumDelta (um)", limit=_context(args, params, tolerances, strategy)["limit_um"],
        title=f"worst case over the tolerance box ({tolerances.name})"))


def cmd_needle_ppm(args):
    from sewtol.provenance import now
    from sewtol.studies import rare_event as R
    from sewtol.tables import needle_208 as NR

    _check_beta_range(args)
    not_offered(args, "needle ppm", resume="it keeps no checkpoints; rerun with the same seed",
                 scheduler="its levels run on this machine; use --n-jobs")
    as_flags(R.choose_method, args.target, args.budget,
             flags={"target": "--target", "budget": "--budget"})
    params, tolerances = _study_nominal(args), _tolerances(args)
    ls = NR.needle_limit_state(params, tolerances, args.limit_um, args.adjust,
                              tuple(args.beta_range))
    started = now()
    res = R.estimate(ls, np.random.default_rng(args.seed), args.method, args.target,
                     args.budget, n_jobs=args.n_jobs, progress=args.progress)
    obj = {**res.to_dict(), "tolerances": tolerances.name, "adjust": args.adjust,
           "seed": args.seed, "target": args.target, "budget": args.budget,
           "context": _context(args, params, tolerances, None)}
    inputs = study_inputs(args, "ppm", params, tolerances, method=args.method,
                          target=args.target, budget=args.budget, adjust=args.adjust,
                          limit_um=args.limit_um, beta_search_range_deg=list(args.beta_range))
    write_outputs(args, "ppm", inputs, started, obj,
                  {"levels": res.levels, "failing_examples": res.examples}, None)
    frame = res.to_dataframe().assign(tolerances=tolerances.name, adjust=args.adjust)
    emit(args.format, obj=obj, frame=frame)
    if args.format == "table":
        print(f"\nP(SumDelta > {args.limit_um:g} um or no value) = {res.statement}")


def _needle_options(p, machine=True, housing=False):
    """--set and --format (machine), --frame and --guide-shift-um: every needle command on one
    machine; --housing, with housing (the studies' flag)."""
    from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME

    if machine:
        machine_options(p, **({} if machine is True else {"formats": machine}))
    p.add_argument("--frame", default=None, metavar="NAME",
                   help=f"named frame of the 208 (default {DEFAULT_FRAME}); "
                        "list them with `sewtol needle frames`")
    p.add_argument("--guide-shift-um", type=float, default=None, metavar="UM",
                   help="move the fixed guide along its normal (um); the same as --set "
                        "guide_shift_um=UM")
    if not housing:
        return
    p.add_argument("--housing", action="store_true", default=None,
                   help="add the housing tolerances to the set (bores A, D and the guide: "
                        "+/-0.02 mm per coordinate, the guide's direction +/-0.0229 deg; "
                        "assumed, docs/needle_208.md); the set is named SET_housing")


def needle_flags(p) -> None:
    """The needle_208 plug-in's flags, which `sewtol run` offers (and `sewtol needle STUDY`, its
    alias): NEEDLE_FLAGS says which study of the fast path reads each."""
    g = p.add_argument_group("the needle_208 fast path (sewtol run needle_208 STUDY, sewtol "
                             "needle STUDY)")
    _needle_options(g, machine=False, housing=True)
    _beta_options(g, limit=("--limit-um",))
    _adjust_options(g)
    g.add_argument("--measurement-error", default=None, metavar="SD_UM",
                   help="strategies: set the compensators from a reading of the needle bar's "
                        "deviation with a normal error of this sd (um) at each measured "
                        "position (0: from the true deviation; docs/adjustment.md)")
    g.add_argument("--measured-positions", type=int, default=None, metavar="K",
                   help="with --measurement-error: the handwheel positions read, equally "
                        "spaced over a turn (default 36, every 10 deg)")
    g.add_argument("--second-order", action="store_true", default=None,
                   help="sobol: also the second-order indices S2 of every pair")
    g.add_argument("--budget", type=int, default=None, help="ppm: model calls; the same as --n")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="montecarlo, sobol: a Dask cluster, e.g. tcp://host:8786 (default: "
                        "$SEWTOL_SCHEDULER, else this machine); same numbers as a local run")
    g.add_argument("--resume", action="store_true", default=None,
                   help="montecarlo, sobol: continue the interrupted study in --out")


_ALL = ("scan", "worst-case", "montecarlo", "sobol", "ppm", "allocation", "strategies",
        "settings")
_ADJUSTING = tuple(s for s in _ALL if s != "ppm")  # ppm reads no compensator flag
# the fast path's studies that read each flag of needle_flags (and --limit, --adjust, --plot,
# --n-jobs where the generic study does not); `run` refuses the others in one line
NEEDLE_FLAGS = {"frame": _ALL, "guide_shift_um": _ALL, "housing": _ALL,
                "beta_range": ("scan", "worst-case", "montecarlo", "sobol", "ppm", "settings"),
                "limit_um": ("scan", "montecarlo", "sobol", "ppm", "settings"),
                "limit": ("scan", "sobol"),
                "adjust": ("sobol", "strategies"), "n_jobs": ("sobol",),
                "range": _ADJUSTING, "step": _ADJUSTING, "resolution": _ADJUSTING,
                "setting_error": _ADJUSTING, "measurement_error": ("strategies",),
                "measured_positions": ("strategies",), "second_order": ("sobol",),
                "budget": ("ppm",), "scheduler": ("montecarlo", "sobol", "ppm", "strategies"),
                "resume": ("montecarlo", "sobol", "ppm", "strategies"),
                "plot": ("scan", "worst-case", "montecarlo", "sobol", "allocation", "strategies",
                         "settings")}


def add_needle(sub):
    """`sewtol needle COMMAND`: one sub-parser per command without a run form; the studies are
    added by sewtol.cli.run.needle_aliases to the sub-parsers returned."""
    needle = sub.add_parser("needle", help="208-class needle drive")
    nsub = needle.add_subparsers(dest="command", required=True, parser_class=Parser)

    p = nsub.add_parser("nominal", help="beta*, deviation figures, window, guide, stroke")
    _needle_options(p, machine=("table", "json"))
    _beta_options(p)
    plot_option(p, "SumDelta against beta with beta* and the window")
    p.set_defaults(func=cmd_needle_nominal)

    p = nsub.add_parser("deviation", help="E and d(phi) over one crank turn")
    _needle_options(p)
    p.add_argument("--beta", type=float, default=None, help="beta (deg); default: the nominal")
    p.add_argument("--step-deg", type=float, default=1.0, help="crank-angle step (deg)")
    plot_option(p, "d(phi) over the crank turn")
    p.set_defaults(func=cmd_needle_deviation)

    p = nsub.add_parser("frames", help="the named frames of the 208 with their residuals")
    p.add_argument("--format", choices=FORMATS, default="table")
    p.set_defaults(func=cmd_needle_frames)
    return nsub


# the needle_208 fast path of `sewtol run` (and `sewtol needle STUDY`): each study's command;
# settings without named settings (--set SETTING:...) compares the guide's (`needle guides`)
FAST_PATH = {"scan": cmd_needle_scan, "worst-case": cmd_needle_worst_case,
             "montecarlo": cmd_needle_montecarlo, "sobol": cmd_needle_sobol, "ppm": cmd_needle_ppm,
             "allocation": cmd_needle_allocation, "strategies": cmd_needle_strategies,
             "settings": cmd_needle_guides}
