"""The `sewtol` command: a thin layer over the library. Only this and study scripts write files."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
from pathlib import Path

import numpy as np

from sewtol.errors import AssemblyError, ParameterError
from sewtol.io import strict, to_json  # noqa: F401  (strict is part of the CLI's API)

FORMATS = ("table", "json", "csv")
MIN_STEP_DEG = 1e-3  # 360 000 angles per turn; finer steps only fill memory
BETA_LIMIT_DEG = 360.0
MAX_SWEEP_POINTS = 100_000
SOBOL_RESAMPLES, SOBOL_CONF_LEVEL = 200, 0.95


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler, `timeout`): stop exactly like Ctrl-C (joblib stops its workers;
    no `except Exception` on the way can swallow it)."""


class CliError(Exception):
    pass


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the flag, like every other refusal."""

    def error(self, message):
        self.exit(2, f"sewtol: error: {message} (see {self.prog} --help)\n")


def parse_sets(items, cls) -> dict:
    """--set NAME=VALUE pairs checked against the parameter names of `cls`."""
    from sewtol.mechanisms.params import field_names

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


def emit(fmt: str, *, obj=None, frame=None) -> None:
    if fmt == "json":
        data = obj if obj is not None else frame.to_dict(orient="records")
        sys.stdout.write(to_json(data))
    elif fmt == "csv":
        from sewtol.reports.tables import to_csv

        sys.stdout.write(to_csv(frame))
    else:
        sys.stdout.write(frame.to_markdown(index=False, floatfmt=".4f") + "\n")


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


def cmd_needle_frames(args):
    from sewtol.mechanisms.needle_208.frames import frames_table, list_frames

    if args.format == "json":
        emit("json", obj=[f.to_dict() for f in list_frames()])
    else:
        emit(args.format, frame=frames_table())


def cmd_needle_nominal(args):
    from sewtol.mechanisms.needle_208.single import nominal_figures

    _check_beta_range(args)
    params = _needle_params(args)
    fig = nominal_figures(params, tuple(args.beta_range), args.limit_um)
    # the nominal machine: no tolerance set, nothing drawn; beta* searched as in every study
    emit(args.format, obj={**fig.to_dict(), "context": _context(args, params, None, None)},
         frame=fig.to_dataframe())
    _print_notes(args, fig.notes())

    def draw(ax):
        from sewtol.mechanisms.needle_208 import beta as sb
        from sewtol.mechanisms.needle_208 import metrics as nm

        betas = np.linspace(*args.beta_range, 201)
        totals = sb.totals_on_grid(nm.columns(params)[0], betas)[0]
        _plots().sum_delta_vs_beta(betas, totals, fig.beta_opt_deg, fig.window_deg,
                                   fig.limit_um, ax=ax)

    _save_plot(args, draw)


def _print_notes(args, notes) -> None:
    """Table output says in words what JSON carries as flags (an optimum on a range bound)."""
    if args.format == "table" and notes:
        sys.stdout.write("".join(f"\nnote: {line}" for line in notes) + "\n")


# --- one vocabulary of flags (issue 14 item 7): the same flag means the same thing everywhere


def _beta_options(p, what="searched for beta* (deg)"):
    """--beta-range LOW HIGH and --limit-um (defaults 10 35 and 10, resolved when checked)."""
    p.add_argument("--beta-range", nargs=2, type=float, default=None, metavar=("LOW", "HIGH"),
                   help=f"regulating range {what}; default 10 35")
    p.add_argument("--limit-um", type=float, default=None,
                   help="SumDelta limit (um) of the yield and the window; default 10")


def _plot_option(p, what):
    p.add_argument("--plot", default=None, metavar="FILE",
                   help=f"also draw {what} into FILE (.png, .svg or .pdf)")


def _progress_option(p):
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: on when stderr is a terminal)")


def _check_plot(args) -> None:
    """--plot FILE: a known suffix in a writable folder, checked before anything runs."""
    plot = getattr(args, "plot", None)
    if plot is None:
        return
    from sewtol.reports.plots import PLOT_FORMATS

    path = Path(plot)
    if path.suffix.lower() not in PLOT_FORMATS:
        raise ParameterError("--plot", f"must end in {', '.join(PLOT_FORMATS)}", plot)
    if path.is_dir():
        raise ParameterError("--plot", "must be a file, not a folder", plot)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ParameterError("--plot", f"cannot be written: {folder} is not a folder", plot)


def _plots():
    from sewtol.reports import plots

    return plots


def _save_plot(args, draw) -> None:
    """draw(ax) the study's figure and save it to --plot (no-op without it)."""
    if getattr(args, "plot", None) is None:
        return
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    draw(ax)
    save_figure(args, fig)


def save_figure(args, fig) -> None:
    """Save a drawn figure to --plot; a folder that cannot be written is one line naming it."""
    try:
        _plots().save_as(fig, Path(args.plot))
    except OSError as exc:
        raise ParameterError("--plot", f"cannot be written ({exc.strerror})", args.plot) from None


def _beta_star_figures(args, params, strategy=None):
    """The nominal figures at beta* in --beta-range (default 10 35; with a strategy that adjusts
    beta, beta's range), at --limit-um."""
    from sewtol.mechanisms.needle_208.single import nominal_figures

    rng = getattr(args, "beta_range", None) or (10.0, 35.0)
    for c in getattr(strategy, "compensators", ()):
        if c.name == "beta":
            rng = (c.low, c.high)
    return nominal_figures(params, tuple(rng), getattr(args, "limit_um", None) or 10.0)


def _at_beta_star(args, params, strategy=None):
    """The nominal with beta at its beta* (`_beta_star_figures`): what "beta fixed" means in
    every needle study (montecarlo, sobol, guides, strategies, worst-case)."""
    return params.override(beta=_beta_star_figures(args, params, strategy).beta_opt_deg)


def _fixed_record(args, params, strategy=None) -> dict:
    """The fixed case's beta, what it means, and whether that beta* lies on a range bound."""
    from sewtol.mechanisms.needle_208.montecarlo import FIXED_BETA_MEANS

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

    beta = list(getattr(args, "beta_range", None) or (10.0, 35.0))
    for c in getattr(strategy, "compensators", ()):
        if c.name == "beta":  # the strategy's own range of beta
            beta = [c.low, c.high]
    return {"tolerances": None if tolerances is None else tolerances.name,
            "seed": getattr(args, "seed", None),
            "n": getattr(args, "n", None), "frame": getattr(args, "frame", None) or DEFAULT_FRAME,
            "guide_shift_um": float(params.guide_shift_um),
            "guide_angle_deg": float(params.guide_angle),
            "strategy": "beta" if strategy is None else strategy.name,
            "beta_search_range_deg": beta, "limit_um": getattr(args, "limit_um", None) or 10.0,
            # the model that computed the numbers (`run FILE` says "generic" on its sampled path)
            "path": "needle_208"}


def _deviation_columns(machines, params, units=None):
    """machines.csv names each drawn deviation as such, with its unit: dev_AB_mm, dev_beta_deg,
    dev_guide_shift_um (a parameter whose name ends in its unit keeps it once)."""
    units = units or {}
    names = {}
    for p in params:
        unit = units.get(p) or _unit_of(p)
        base = p[: -len(unit) - 1] if p.endswith("_" + unit) else p
        names[p] = f"dev_{base}_{unit}"
    return machines.rename(columns=names)


def _unit_of(param: str) -> str:
    for unit in ("um", "mm", "deg"):
        if param.endswith("_" + unit):
            return unit
    # angles of the two mechanisms (deg): beta, CBE, the regulator b, every *angle* and *phase*
    return "deg" if param in ("beta", "CBE", "b") or "angle" in param or "phase" in param \
        else "mm"


def cmd_needle_deviation(args):
    from sewtol.mechanisms.needle_208.single import deviation_table

    _check_step(args.step_deg)
    p = _needle_params(args)
    if args.beta is not None:
        p = p.override(beta=args.beta)
    frame = deviation_table(p, args.step_deg)
    emit(args.format, obj={"context": _machine_context(args, p, beta_deg=float(p.beta)),
                           "rows": frame.to_dict(orient="records")}, frame=frame)
    _save_plot(args, lambda ax: _plots().deviation_vs_crank(
        {f"beta = {float(p.beta):.4f} deg": frame}, ax=ax))


def _machine_context(args, params, **extra) -> dict:
    """What decides a single machine's numbers (its JSON's `context`): the frame or mechanism,
    the values changed by --set, the sampling step and the guide, where there is one."""
    from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME

    out = {"set": parse_sets(getattr(args, "set", None) or [], type(params))}
    if hasattr(params, "guide_shift_um"):
        out.update({"mechanism": "208 needle drive",
                    "frame": getattr(args, "frame", None) or DEFAULT_FRAME,
                    "guide_shift_um": float(params.guide_shift_um),
                    "guide_angle_deg": float(params.guide_angle)})
    else:
        out.update({"mechanism": "131-42+3 feed", "b_deg": float(params.b),
                    "plate_mm": float(params.plate_mm), "material_mm": float(params.material_mm)})
    if getattr(args, "step_deg", None) is not None:
        out["step_deg"] = float(args.step_deg)
    return {**out, **extra}


def _study_nominal(args):
    """The nominal machine of a study: it must assemble, or nothing is computed or written."""
    from sewtol.mechanisms.needle_208.model import check_assembly

    # `run FILE STUDY` on the needle fast path gives the file's nominal machine (nominal_params)
    given = getattr(args, "nominal_params", None)
    params = _needle_params(args) if given is None else given
    check_assembly(params)
    return params


def _tolerances(args):
    from sewtol.mechanisms.needle_208.model import Needle208
    from sewtol.mechanisms.params import field_names
    from sewtol.tolerances import NEEDLE_208_SETS, resolve

    if getattr(args, "tolerance_set", None) is not None:  # `run FILE`: the file's set, resolved
        return args.tolerance_set
    return resolve(args.tolerances, NEEDLE_208_SETS, field_names(Needle208))


def _check_n(value, name="--n", minimum=2):
    if value < minimum:
        raise ParameterError(name, f"must be >= {minimum}", value)


def _check_step(value, name="--step-deg"):
    if not (MIN_STEP_DEG <= value <= 90):
        raise ParameterError(name, f"must be in [{MIN_STEP_DEG:g}, 90]", value)


FLAGS = {"n": "--n", "seed": "--seed", "tolerances": "--tolerances", "n_jobs": "--n-jobs"}


def _as_flags(check, *a):
    """Run a library check; its error names the CLI flag rather than the keyword argument."""
    try:
        check(*a)
    except ParameterError as exc:
        if exc.field in FLAGS:
            raise ParameterError(FLAGS[exc.field], exc.rule, exc.value) from None
        raise


def _check_out(args):
    """--out must be (or become) a writable folder; checked before anything is written."""
    out = getattr(args, "out", None)
    if not out:
        return
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ParameterError("--out", "must be a folder, not a file", out)
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise ParameterError("--out", f"cannot be created: {probe} is not a folder", out)
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ParameterError("--out", f"cannot be written: no write permission in {probe}", out)


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
    _scheduler(args)


def _not_offered(args, command: str, **why) -> None:
    """Refuse, in one line, a shared study flag (resume, scheduler, n_jobs) that `command` takes
    from the common parser but does not use; `why` maps each checked flag to the reason."""
    for key, reason in why.items():
        if key == "resume":
            flag, used, value = "--resume", bool(args.resume), True
        elif key == "scheduler":
            where = _scheduler(args)
            flag, used, value = "--scheduler", where is not None, where and where[1]
        else:
            flag, used, value = "--n-jobs", args.n_jobs != 1, args.n_jobs
        if used:
            raise ParameterError(flag, f"is not offered by {command} ({reason})", value)


def _scheduler(args) -> tuple[str, str] | None:
    """(flag, address) of the Dask scheduler from --scheduler or SEWTOL_SCHEDULER, or None for
    this machine. Checked with the other flags, before anything is computed."""
    if getattr(args, "scheduler", None) is not None:
        flag, address = "--scheduler", args.scheduler
    elif os.environ.get("SEWTOL_SCHEDULER", "").strip():
        flag, address = "SEWTOL_SCHEDULER", os.environ["SEWTOL_SCHEDULER"]
    else:
        return None
    if not address.strip() or any(ch.isspace() for ch in address):
        raise ParameterError(flag, "must be a Dask scheduler address such as tcp://host:8786",
                             address)
    if getattr(args, "n_jobs", 1) != 1:
        raise ParameterError("--n-jobs", f"is the single-machine path; with {flag} the "
                             "cluster's workers set the parallelism", args.n_jobs)
    return flag, address


@contextlib.contextmanager
def _cluster(args):
    """A distributed.Client on the study's scheduler (None without one), closed afterwards."""
    where = _scheduler(args)
    if where is None:
        yield None
        return
    from sewtol.studies.parallel import connect

    flag, address = where
    try:
        client = connect(address)
    except ParameterError as exc:
        raise ParameterError(flag, exc.rule, address) from None
    with client:
        yield client


def _check_beta_range(args):
    """--beta-range and --limit-um (defaults 10 35 and 10 um where a command takes them)."""
    from sewtol.mechanisms.needle_208 import beta as sb

    if getattr(args, "beta_range", None) is None:
        args.beta_range = list(sb.DEFAULT_RANGE_DEG)
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


def _inputs(args, kind, params, tolerances, **extra) -> dict:
    """Every input that decides a study's numbers (the manifest binds its chunks to these)."""
    from sewtol.mechanisms.params import as_dict
    from sewtol.provenance import version_record

    return {"study": kind, "n": getattr(args, "n", None), "seed": args.seed,
            "params": as_dict(params),
            "tolerances": {"name": tolerances.name, "items": tolerances.as_dict()},
            **version_record(), **extra, **getattr(args, "file_inputs", {})}


def _store(args, inputs: dict):
    """The checkpoint folder of a study run with --out (None without); takes its lock."""
    if not args.out:
        return None
    from sewtol.studies.checkpoint import ChunkStore

    return ChunkStore(Path(args.out) / "chunks", inputs, args.resume, label=str(args.out))


def _history(store, started: str) -> list:
    """Start times of every run into this folder (the first, then each --resume)."""
    if store is None:
        return [{"started_utc": started, "resumed": False}]
    from sewtol.io import write_text_atomic

    path = store.folder / "runs.json"
    try:
        runs = json.loads(path.read_text(encoding="utf-8")) if path.exists() else []
        runs = [r for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []
    except (OSError, ValueError):
        runs = []
    runs = [{"started_utc": str(r.get("started_utc")), "resumed": bool(r.get("resumed"))}
            for r in runs] + [{"started_utc": started, "resumed": bool(runs) or store.resumed}]
    write_text_atomic(path, json.dumps(runs, indent=2) + "\n")
    return runs


def _write_outputs(args, kind, inputs, started, result_obj, frames, runs):
    """Tables, then the result, then run.json into --out, each file atomically (a run.json
    means the folder is complete)."""
    if not args.out:
        return
    from sewtol.io import write_text_atomic
    from sewtol.provenance import run_record
    from sewtol.reports.tables import to_csv

    out = Path(args.out)
    try:
        for name, frame in frames.items():
            write_text_atomic(out / f"{name}.csv", to_csv(frame))
        write_text_atomic(out / f"{kind}.json", to_json(result_obj))
        where = _scheduler(args)
        record = run_record(started, {**inputs, "n_jobs": args.n_jobs,
                                      "scheduler": where[1] if where else None}, runs=runs)
        write_text_atomic(out / "run.json", to_json(record))
    except OSError as exc:
        raise ParameterError("--out", f"cannot be written ({exc.strerror}); the finished chunks "
                             "are kept: free the space and rerun with --resume",
                             str(exc.filename or out)) from None


def cmd_needle_scan(args):
    from sewtol.mechanisms.needle_208.scan import scan

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
        inputs = _inputs(args, "scan", params, tolerances, limit_um=args.limit_um,
                         beta_search_range_deg=list(args.beta_range), context=context)
        _write_outputs(args, "scan", inputs, started, obj, {"scan": frame},
                       [{"started_utc": started, "resumed": False}])
    emit(args.format, obj=obj, frame=frame)
    if "beta_at_bound" in frame:
        n = int(frame["beta_at_bound"].sum())
        _print_notes(args, [f"{n} of {len(frame)} rows have beta* on a bound of the searched "
                            f"range {list(args.beta_range)} deg (column beta_at_bound): their "
                            "optimum may lie outside it"] if n else [])
    _save_plot(args, lambda ax: _scan_figure(frame, "total_um", ax, "SumDelta at beta* (um)",
                                             args.limit_um))


def _scan_figure(frame, column, ax, ylabel, limit=None):
    """A scan's `column` at each tolerance's upper and lower limit, one group per tolerance."""
    labels = list(dict.fromkeys(frame["param"]))
    series = {side: [float(frame.loc[(frame["param"] == p) & (frame["side"] == side),
                                     column].iloc[0]) for p in labels]
              for side in ("upper", "lower")}
    return _plots().grouped_bars(labels, series, ax=ax, ylabel=ylabel, limit=limit,
                                 title="each tolerance at its limits")


def cmd_needle_montecarlo(args):
    from sewtol.studies.montecarlo import CHUNK, check_sampling

    _check_n(args.n)
    _check_study(args)
    strategy = _strategy(args)
    _check_beta_range(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    limit, rng = args.limit_um, tuple(args.beta_range)
    _as_flags(check_sampling, params, tolerances, args.n, args.seed, CHUNK)
    if strategy is not None:
        if args.plot is not None:
            raise ParameterError("--plot", "is not offered with --adjust (the histograms show "
                                 "beta fixed against beta adjusted)", args.plot)
        return _adjusted_montecarlo(args, params, tolerances, strategy, limit)
    res, record = run_montecarlo(args, params, tolerances, limit, rng)
    emit(args.format, obj=record, frame=res.summary_frame())
    _print_notes(args, _montecarlo_notes(res, record))
    _save_plot(args, lambda ax: _plots().montecarlo_histograms(
        res.machines["total_fixed_um"], res.machines["total_adjusted_um"], res.limit_um,
        (res.yield_of("fixed"), res.yield_of("adjusted")), ax=ax))


def run_montecarlo(args, params, tolerances, limit, rng, **inputs_extra):
    """The Monte-Carlo of `needle montecarlo` (beta fixed and adjusted), with its study folder
    (--out/--resume) and cluster: the result and its JSON record. `run FILE montecarlo` on the
    needle fast path runs cmd_needle_montecarlo itself (args.file_inputs names the file in
    run.json), so both print the same bytes."""
    from sewtol.mechanisms.needle_208.montecarlo import montecarlo
    from sewtol.provenance import now
    from sewtol.studies.montecarlo import CHUNK

    started = now()
    inputs = _inputs(args, "montecarlo", params, tolerances, limit_um=limit,
                     beta_search_range_deg=list(rng), chunk_size=CHUNK,
                     strategy="beta fixed at the nominal's beta* (fixed_beta=optimum) and beta "
                     "re-optimised per machine", **inputs_extra)
    store = _store(args, inputs)
    try:
        runs = _history(store, started)
        with _cluster(args) as client:
            res = montecarlo(params, tolerances, args.n, args.seed, limit_um=limit,
                             range_deg=rng, n_jobs=args.n_jobs, progress=args.progress,
                             store=store, chunk_size=CHUNK, scheduler=client)
        record = _montecarlo_record(args, params, tolerances, res)
        _write_outputs(args, "montecarlo", inputs, started, record,
                       {"machines": _deviation_columns(res.machines, res.params),
                        "summary": res.summary_frame()}, runs)
    finally:
        if store is not None:
            store.close()
    return res, record


def _montecarlo_record(args, params, tolerances, res) -> dict:
    """The JSON of `needle montecarlo` (and of `run FILE montecarlo` on the needle fast path):
    the result, its context and whether the fixed case's beta* lies on a range bound."""
    return {**res.to_dict(), "context": _context(args, params, tolerances, None),
            "fixed_beta_at_bound": _beta_star_figures(args, params).beta_at_bound}


def _montecarlo_notes(res, record) -> list[str]:
    k, pinned = res.beta_at_bound(), res.beta_at_bound(pinned=True)
    return ([f"yield intervals: {record['yield_ci']['method']}, 95 %"]
            + _fixed_notes({**record, "fixed_beta_deg": res.nominal_beta_deg})
            + ([f"{k} of {res.n} machines have an adjusted beta* whose optimum reaches a bound "
                f"of the searched range {list(res.range_deg)} deg; {pinned} of them are pinned "
                "there (SumDelta still falling: the optimum lies outside the range), the others "
                "sit on a flat plateau"] if k else []))


# --- adjustment strategies (issue 13): --adjust/--range/--step/--resolution, `needle strategies`


def _strategy(args):
    """The strategy of --adjust/--range/--step/--resolution (None without --adjust).

    --beta-range means the range searched for beta everywhere: with --adjust naming beta it is
    beta's --range (giving both is refused); with --adjust not naming beta nothing searches beta,
    so it is refused."""
    from sewtol.mechanisms.needle_208.compensators import parse_cli
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
    return parse_cli(adjust, ranges, args.step, args.resolution,
                     valid=field_names(Needle208))


def _strategy_record(strategy) -> dict:
    return {c.name: {"low": c.low, "high": c.high, "step": c.step, "resolution": c.resolution,
                     "mode": c.mode} for c in strategy.compensators}


def _adjusted_montecarlo(args, params, tolerances, strategy, limit):
    """needle montecarlo --adjust: the per-machine table of one strategy and its summary."""
    from sewtol.mechanisms.needle_208.strategies import adjusted_montecarlo_model, summarise_frame
    from sewtol.provenance import now
    from sewtol.studies.montecarlo import CHUNK, sample_machines

    params = _at_beta_star(args, params, strategy)
    started = now()
    inputs = _inputs(args, "montecarlo_adjusted", params, tolerances, limit_um=limit,
                     chunk_size=CHUNK, strategy=strategy.name,
                     compensators=_strategy_record(strategy))
    store = _store(args, inputs)
    try:
        runs = _history(store, started)
        with _cluster(args) as client:
            machines = sample_machines(adjusted_montecarlo_model, params, tolerances, args.n,
                                       args.seed, args.n_jobs, args.progress, store=store,
                                       chunk_size=CHUNK, scheduler=client, strategy=strategy,
                                       limit_um=limit)
        summary = summarise_frame(machines, strategy, limit)
        record = {**summary.iloc[0].to_dict(), "seed": args.seed, "tolerances": tolerances.name,
                  "compensators": _strategy_record(strategy),
                  **_fixed_record(args, params, strategy),
                  "context": _context(args, params, tolerances, strategy)}
        _write_outputs(args, "montecarlo", inputs, started, record,
                       {"machines": _deviation_columns(machines, tolerances.active().params),
                        "summary": summary}, runs)
    finally:
        if store is not None:
            store.close()
    emit(args.format, obj=record, frame=summary)
    _print_notes(args, _fixed_notes(record))


def cmd_needle_strategies(args):
    from sewtol.mechanisms.needle_208.compensators import Strategy
    from sewtol.mechanisms.needle_208.strategies import default_strategies, strategies_table
    from sewtol.provenance import now

    _check_n(args.n)
    _check_study(args)
    _not_offered(args, "needle strategies",
                 resume="it keeps no checkpoints; rerun with the same seed",
                 scheduler="it runs on this machine", n_jobs="it runs in one process")
    strategy = _strategy(args)
    params, tolerances = _at_beta_star(args, _study_nominal(args)), _tolerances(args)
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
        frames[f"machines_{safe}"] = _deviation_columns(res.machines(r.name), res.params)
    inputs = _inputs(args, "strategies", params, tolerances, limit_um=10.0,
                     strategies={r.name: _strategy_record(r) for r in rows})
    context = {**_context(args, params, tolerances, strategy),
               "strategy": [r.name for r in rows], "limit_um": 10.0}
    obj = {"context": context, **_fixed_record(args, params, strategy),
           "rows": table.to_dict(orient="records")}
    _write_outputs(args, "strategies", inputs, started, obj, frames, [])
    emit(args.format, obj=obj, frame=table)
    _save_plot(args, lambda ax: _plots().grouped_bars(
        list(table["strategy"]), {"yield": table["yield"]}, ax=ax, ylabel="yield",
        errors={"yield": (table["yield_ci_low"], table["yield_ci_high"])},
        title=f"yield by adjustment strategy, {args.n} machines (95 % interval)"))


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
    from sewtol.mechanisms.needle_208.sobol import needle_sobol
    from sewtol.provenance import now
    from sewtol.studies.sobol import CHUNK, check_sobol
    from sewtol.studies.sobol import check_power_of_two

    try:
        check_power_of_two(args.n)
    except ParameterError as exc:
        raise ParameterError("--n", exc.rule, args.n) from None
    _check_study(args)
    strategy = _strategy(args)
    _check_beta_range(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    _as_flags(check_sobol, params, tolerances, args.n, args.seed, args.second_order)
    rng = tuple(args.beta_range)
    started = now()
    context = _context(args, params, tolerances, strategy)
    extra = {} if strategy is None else {"compensators": _strategy_record(strategy)}
    inputs = _inputs(args, "sobol", params, tolerances, beta_search_range_deg=list(rng),
                     limit_um=args.limit_um, second_order=args.second_order, context=context,
                     chunk_size=CHUNK, resamples=SOBOL_RESAMPLES,
                     confidence_level=SOBOL_CONF_LEVEL,
                     strategy="beta fixed at the nominal's beta* (fixed_beta=optimum) and beta "
                     "re-optimised per sample" if strategy is None else "beta fixed at the "
                     f"nominal's beta* (fixed_beta=optimum) and {strategy.name} adjusted per "
                     "sample (exact joint optimum)", **extra)
    store = _store(args, inputs)
    try:
        runs = _history(store, started)
        with _cluster(args) as client:
            res = needle_sobol(params, tolerances, args.n, args.seed, range_deg=rng,
                               n_jobs=args.n_jobs, progress=args.progress, store=store,
                               resamples=SOBOL_RESAMPLES, conf_level=SOBOL_CONF_LEVEL,
                               chunk_size=CHUNK, scheduler=client, strategy=strategy,
                               limit_um=args.limit_um, second_order=args.second_order)
        frames = {"indices": res.to_dataframe(), "convergence": res.convergence}
        if args.second_order:
            frames["second_order"] = res.second_order_frame()
        _write_outputs(args, "sobol", inputs, started, _sobol_json(res, args.second_order, context),
                       frames, runs)
    finally:
        if store is not None:
            store.close()
    emit(args.format, obj=_sobol_json(res, args.second_order, context), frame=res.to_dataframe())
    if args.second_order and args.format == "table":
        sys.stdout.write("\nsecond-order indices S2 (pairs; conf: half-width of the "
                         f"{SOBOL_CONF_LEVEL:.0%} bootstrap interval)\n")
        emit("table", frame=res.second_order_frame())
    _save_plot(args, lambda ax: _plots().sobol_bars(
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
            "model_runs_per_case": res.model_runs, "context": context}


# --- needle guides and needle allocation (issue 13 items 6 and 7) ------------------------------


def _small_study(args):
    """Flags of guides/allocation, checked before anything is computed."""
    _check_n(args.n)
    if args.seed < 0:
        raise ParameterError("--seed", "must be a whole number >= 0", args.seed)
    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    if not tolerances.active().items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    tolerances.check_against(params)
    return strategy, params, tolerances


def cmd_needle_guides(args):
    from sewtol.mechanisms.needle_208.guides import compare_guides

    strategy, params, tolerances = _small_study(args)
    _check_beta_range(args)
    table = compare_guides(params, tolerances, args.n, args.seed, strategy=strategy,
                           range_deg=tuple(args.beta_range), limit_um=args.limit_um)
    obj = {"tolerances": tolerances.name, "n": args.n, "seed": args.seed,
           "fixed_beta_means": "each guide setting's own beta* (as `sewtol needle nominal` "
                               "prints it for that guide)",
           "context": _context(args, params, tolerances, strategy),
           "strategy": "fixed beta and beta adjusted" if strategy is None else strategy.name,
           **({} if strategy is None else {"compensators": _strategy_record(strategy)}),
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)
    _save_plot(args, lambda ax: _plots().grouped_bars(
        list(table["guide"]), {"beta fixed at the guide's beta*": table["yield_fixed_beta"],
                               **({"beta adjusted": table["yield_adjusted_beta"]}
                                  if strategy is None else
                                  {f"{strategy.name} adjusted": table["yield_adjusted"]})}, ax=ax,
        ylabel="yield", title=f"yield by guide setting, {args.n} machines"))


def cmd_needle_allocation(args):
    from sewtol.mechanisms.needle_208.allocation import allocate
    from sewtol.mechanisms.needle_208.strategies import allocate_for_strategy

    if not (np.isfinite(args.target) and 0 < args.target < 1):
        raise ParameterError("--target", "must be a yield strictly between 0 and 1",
                             args.target)
    strategy, params, tolerances = _small_study(args)
    if strategy is None:
        res = allocate(params, tolerances, args.target, args.n, args.seed)
        name = "beta"
        table = res.to_dataframe()
        table["lower_mm"], table["upper_mm"] = -table["tolerance_mm"], table["tolerance_mm"]
    else:
        res = allocate_for_strategy(params, tolerances, strategy, args.target, args.n,
                                    args.seed)
        name = strategy.name
        table = res.to_dataframe()
    obj = {"tolerances": tolerances.name, "strategy": name, "target": res.target,
           "yield_adjusted": res.yield_adjusted, "n": res.n, "seed": res.seed,
           "scale": res.scale,
           "cost_model": "reciprocal: sum c_i / width_i; shape (c_i / s_i^2)^(1/3), common "
                         "scale by bisection on the Monte-Carlo yield (common random numbers)",
           **({} if strategy is None else {"compensators": _strategy_record(strategy)}),
           "context": _context(args, params, tolerances, strategy),
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)
    _save_plot(args, lambda ax: allocation_figure(table, tolerances.name, res.target, ax))


def allocation_figure(table, reference: str, target: float, ax):
    """Each tolerance's width (upper - lower, um) in the reference set and as allocated."""
    widths = {f"set {reference}": 1000 * (table["reference_upper_mm"] - table["reference_lower_mm"]),
              f"allocated (yield {target:g})": 1000 * (table["upper_mm"] - table["lower_mm"])}
    ax = _plots().grouped_bars(list(table["param"]), widths, ax=ax,
                               ylabel="tolerance width (\u00b5m, log scale)",
                               title="Tolerance allocation: widths before and after")
    ax.set_yscale("log")  # the widths span two decades (LM about 1 mm, AB about 10 um)
    return ax


def cmd_needle_worst_case(args):
    from sewtol.mechanisms.needle_208.worst_case import worst_case_table

    strategy = _strategy(args)
    params, tolerances = _study_nominal(args), _tolerances(args)
    active = tolerances.active()
    if not active.items:
        raise ParameterError("--tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    if len(active.items) > 10:
        raise ParameterError("--tolerances", "worst case enumerates corners; at most 10 "
                             "tolerances", len(active.items))
    tolerances.check_against(params)
    _check_beta_range(args)
    params = _at_beta_star(args, params, strategy)
    table = worst_case_table(params, tolerances, tuple(args.beta_range), strategy=strategy)
    obj = {"tolerances": tolerances.name, **_fixed_record(args, params, strategy),
           "context": _context(args, params, tolerances, strategy),
           "strategy": "beta" if strategy is None else strategy.name,
           **({} if strategy is None else {"compensators": _strategy_record(strategy)}),
           "method": "every corner and the centre, the best 3 polished by L-BFGS-B in the box "
                     "(never below any evaluated point; not proven global)",
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)
    _print_notes(args, _fixed_notes(obj) + [
        f"the worst machine's beta* in {r['case']} reaches a bound of the searched range: its "
        "optimum may lie outside it" for r in obj["rows"] if r.get("beta_at_bound")])
    _save_plot(args, lambda ax: _plots().grouped_bars(
        list(table["case"]), {"worst SumDelta in the box": table["total_um"]}, ax=ax,
        ylabel="SumDelta (um)", limit=_context(args, params, tolerances, strategy)["limit_um"],
        title=f"worst case over the tolerance box ({tolerances.name})"))


def add_needle_guides_allocation(nsub, needle_common, study) -> None:
    p = nsub.add_parser("worst-case", help="worst SumDelta over the tolerance box, fixed and "
                        "adjusted")
    needle_common(p)
    study(p, seed=False)
    p.add_argument("--beta-range", nargs=2, type=float, default=None, metavar=("LOW", "HIGH"),
                   help="regulating range searched for beta (deg); default 10 35")
    _adjust_options(p)
    _plot_option(p, "the worst SumDelta of each case against the limit")
    p.set_defaults(func=cmd_needle_worst_case)

    p = nsub.add_parser("guides", help="guide settings compared: beta*, window, yields")
    needle_common(p)
    study(p, seed=False)
    p.add_argument("--n", type=int, default=2000, help="machines per guide setting")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    _beta_options(p)
    _adjust_options(p)
    _plot_option(p, "the yields of each guide setting, beta fixed and adjusted")
    p.set_defaults(func=cmd_needle_guides)

    p = nsub.add_parser("allocation", help="widest tolerances for a yield after adjustment")
    needle_common(p)
    study(p, seed=False)
    p.add_argument("--n", type=int, default=2000,
                   help="machines per trial (common random numbers; default 2000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--target", type=float, default=0.9973,
                   help="yield after adjustment to keep (default 0.9973)")
    _adjust_options(p)
    _plot_option(p, "each tolerance's width in the reference set and allocated")
    p.set_defaults(func=cmd_needle_allocation)


# --- needle largest-tolerances: the largest single deviation of each part ----------------------

def cmd_needle_largest_tolerances(args):
    from sewtol.mechanisms.needle_208.model import LENGTHS, Needle208
    from sewtol.mechanisms.needle_208.scan import largest_tolerances
    from sewtol.mechanisms.params import field_names
    from sewtol.tolerances import is_branch

    _check_beta_range(args)
    params = _study_nominal(args)
    names = list(LENGTHS) if args.params is None else [s.strip() for s in args.params.split(",")]
    # beta is re-optimised per machine, so a deviation of it means nothing here
    valid = [f for f in field_names(Needle208)
             if not is_branch(f) and f not in ("guide_shift_um", "beta")]
    for name in names:
        if name not in valid:
            raise ParameterError("--params", "must name parameters of the needle drive "
                                 f"({', '.join(valid)})", name)
    if not (np.isfinite(args.max_mm) and args.max_mm > 0):
        raise ParameterError("--max-mm", "must be a positive deviation in mm", args.max_mm)
    table = largest_tolerances(params, names, limit_um=args.limit_um, max_mm=args.max_mm,
                               guide_shift_um=float(params.guide_shift_um),
                               range_deg=tuple(args.beta_range))
    obj = {"context": _context(args, params, None, None),
           "limit_um": args.limit_um, "max_mm": args.max_mm,
           "method": "each parameter alone, the others nominal: SumDelta at beta* (re-optimised "
                     "in the searched range) on a geometric grid from 1 um, then bisection to "
                     "1e-5 mm; reaches_max marks sides where even max_mm keeps the limit",
           "rows": table.to_dict(orient="records")}
    emit(args.format, obj=obj, frame=table)


def add_needle_largest_tolerances(nsub, needle_common) -> None:
    p = nsub.add_parser("largest-tolerances", help="largest single deviation of each part that "
                        "keeps SumDelta(beta*) within the limit")
    needle_common(p)
    p.add_argument("--params", default=None, metavar="NAMES",
                   help="comma-separated parameters (default the seven links LF ... CD)")
    p.add_argument("--max-mm", type=float, default=1.0,
                   help="largest deviation tried, mm (default 1)")
    _beta_options(p)
    p.set_defaults(func=cmd_needle_largest_tolerances)


# --- needle ppm (rare-event probability of failure after adjustment; issue 15) ---------------

def cmd_needle_ppm(args):
    from sewtol.mechanisms.needle_208 import ppm as NR
    from sewtol.provenance import now
    from sewtol.studies import rare_event as R

    _check_study(args)
    _check_beta_range(args)
    _not_offered(args, "needle ppm", resume="it keeps no checkpoints; rerun with the same seed",
                 scheduler="its levels run on this machine; use --n-jobs")
    if not (np.isfinite(args.target) and 0 < args.target < 1):
        raise ParameterError("--target", "must be a probability in (0, 1)", args.target)
    if args.budget < 100:
        raise ParameterError("--budget", "must be a whole number of model calls >= 100",
                             args.budget)
    params, tolerances = _study_nominal(args), _tolerances(args)
    ls = NR.needle_limit_state(params, tolerances, args.limit_um, args.adjust,
                              tuple(args.beta_range))
    started = now()
    res = R.estimate(ls, np.random.default_rng(args.seed), args.method, args.target,
                     args.budget, n_jobs=args.n_jobs, progress=args.progress)
    obj = {**res.to_dict(), "tolerances": tolerances.name, "adjust": args.adjust,
           "seed": args.seed, "target": args.target, "budget": args.budget,
           "context": _context(args, params, tolerances, None)}
    if args.out:
        from sewtol.io import write_text_atomic
        from sewtol.provenance import run_record
        from sewtol.reports.tables import to_csv

        out = Path(args.out)
        inputs = _inputs(args, "ppm", params, tolerances, method=args.method,
                         target=args.target, budget=args.budget, adjust=args.adjust,
                         limit_um=args.limit_um, beta_search_range_deg=list(args.beta_range))
        try:
            write_text_atomic(out / "ppm.json", to_json(obj))
            for name, frame in (("levels", res.levels), ("failing_examples", res.examples)):
                write_text_atomic(out / f"{name}.csv", to_csv(frame))
            write_text_atomic(out / "run.json", to_json(run_record(started, inputs)))
        except OSError as exc:
            raise ParameterError("--out", f"cannot be written ({exc.strerror})",
                                 str(exc.filename or out)) from None
    frame = res.to_dataframe().assign(tolerances=tolerances.name, adjust=args.adjust)
    emit(args.format, obj=obj, frame=frame)
    if args.format == "table":
        print(f"\nP(SumDelta > {args.limit_um:g} um or no value) = {res.statement}")


def add_needle_ppm(nsub, common, study) -> None:
    p = nsub.add_parser("ppm", help="failures per million after adjustment (rare-event methods)")
    common(p)
    study(p)
    p.add_argument("--adjust", choices=("none", "beta"), default="beta",
                   help="assembly adjustment: none (beta fixed at nominal beta*) or beta")
    _beta_options(p)
    p.add_argument("--method", choices=("auto", "montecarlo", "subset", "nais"), default="auto",
                   help="auto: Monte-Carlo if budget * target >= 10, else subset simulation")
    p.add_argument("--target", type=float, default=1e-6,
                   help="smallest probability to resolve (default 1e-6)")
    p.add_argument("--budget", type=int, default=20000, help="model calls (default 20000)")
    p.set_defaults(func=cmd_needle_ppm)


def _feed_params(args):
    from sewtol.mechanisms.feed_131.model import Feed131

    return Feed131().override(**parse_sets(args.set, Feed131))


def cmd_feed_trajectory(args):
    from sewtol.mechanisms.feed_131.studies import trajectory

    _check_step(args.step_deg)
    params = _feed_params(args)
    traj = trajectory(params, args.step_deg)
    emit(args.format, obj={"context": _machine_context(args, params),
                           "rows": traj.to_dict(orient="records")}, frame=traj)
    _save_plot(args, lambda ax: _plots().tooth_paths(traj, params.plate_mm, params.material_mm,
                                                     ax=ax))


def cmd_feed_metrics(args):
    from sewtol.mechanisms.feed_131.studies import metrics

    params = _feed_params(args)
    m = metrics(params)
    if args.format == "csv":
        emit("csv", frame=m.to_dataframe())
    else:
        emit(args.format, obj={**m.to_dict(), "context": _machine_context(args, params)},
             frame=m.to_dataframe())


def cmd_feed_regulator(args):
    from sewtol.mechanisms.feed_131.studies import regulator_sweep

    lo, hi, step = args.b_range
    if not (np.isfinite([lo, hi, step]).all() and lo < hi and step > 0):
        raise ParameterError("--b-range", "must be finite LOW HIGH STEP with LOW < HIGH and "
                             "STEP > 0", args.b_range)
    if (hi - lo) / step + 1 > MAX_SWEEP_POINTS:
        raise ParameterError("--b-range", f"gives more than {MAX_SWEEP_POINTS} settings; use a "
                             "larger STEP", args.b_range)
    params = _feed_params(args)
    sweep = regulator_sweep(params, np.arange(lo, hi + 1e-9, step))
    emit(args.format, obj={"context": _machine_context(args, params, b_range_deg=[lo, hi, step]),
                           "rows": sweep.to_dict(orient="records")}, frame=sweep)
    _save_plot(args, lambda ax: _plots().regulator_curve(sweep, params.b, ax=ax))


def build_parser() -> argparse.ArgumentParser:
    from sewtol import __version__
    from sewtol.provenance import git_revision

    ap = Parser(prog="sewtol", description=__doc__.splitlines()[0])
    ap.add_argument("--version", action="version",
                    version=f"sewtol {__version__} (revision {git_revision()})")
    sub = ap.add_subparsers(dest="group", required=True, parser_class=Parser)
    needle = sub.add_parser("needle", help="208-class needle drive")
    nsub = needle.add_subparsers(dest="command", required=True, parser_class=Parser)

    def common(p, example="LF=6.8", formats=FORMATS):
        p.add_argument("--set", action="append", metavar="NAME=VALUE",
                       help=f"override a parameter (repeatable), e.g. --set {example}")
        p.add_argument("--format", choices=formats, default="table")

    def needle_common(p, **kwargs):
        from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME

        common(p, **kwargs)
        p.add_argument("--frame", default=None, metavar="NAME",
                       help=f"named frame of the 208 (default {DEFAULT_FRAME}); "
                            "list them with `sewtol needle frames`")
        p.add_argument("--guide-shift-um", type=float, default=None, metavar="UM",
                       help="move the fixed guide along its normal (um); the same as --set "
                            "guide_shift_um=UM")

    p = nsub.add_parser("nominal", help="beta*, deviation figures, window, guide, stroke")
    needle_common(p, formats=("table", "json"))
    _beta_options(p)
    _plot_option(p, "SumDelta against beta with beta* and the window")
    p.set_defaults(func=cmd_needle_nominal)

    p = nsub.add_parser("deviation", help="E and d(phi) over one crank turn")
    needle_common(p)
    p.add_argument("--beta", type=float, default=None, help="beta (deg); default: the nominal")
    p.add_argument("--step-deg", type=float, default=1.0, help="crank-angle step (deg)")
    _plot_option(p, "d(phi) over the crank turn")
    p.set_defaults(func=cmd_needle_deviation)

    def study(p, seed=True):
        p.add_argument("--tolerances", default="base",
                       help="base, recommended, FILE.toml or FILE.toml:SET (default base)")
        if seed:
            p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
            p.add_argument("--n-jobs", type=int, default=1,
                           help="parallel workers on this machine (joblib)")
            p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                           help="run on a Dask cluster, e.g. tcp://host:8786 (default: "
                           "$SEWTOL_SCHEDULER, else this machine); same numbers as a local run")
            _progress_option(p)
            p.add_argument("--out", default=None, metavar="DIR",
                           help="write results, machines, run.json and checkpoints here")
            p.add_argument("--resume", action="store_true",
                           help="continue the interrupted study in --out without recomputing "
                                "its finished chunks")

    p = nsub.add_parser("scan", help="each tolerance at its limits, beta re-optimised")
    needle_common(p)
    study(p, seed=False)
    _beta_options(p)
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write scan.csv, scan.json and run.json (the context) here")
    _adjust_options(p)
    _plot_option(p, "SumDelta at each tolerance's upper and lower limit")
    p.set_defaults(func=cmd_needle_scan, seed=None, n_jobs=1)

    p = nsub.add_parser("montecarlo", help="yield with beta fixed and adjusted per machine")
    needle_common(p)
    study(p)
    p.add_argument("--n", type=int, default=2000, help="machines (default 2000)")
    _beta_options(p)
    _plot_option(p, "the histograms of SumDelta, beta fixed and adjusted")
    p.set_defaults(func=cmd_needle_montecarlo)

    _adjust_options(p)

    p = nsub.add_parser("strategies", help="yield by adjustment strategy on the same machines")
    needle_common(p)
    study(p)
    p.add_argument("--n", type=int, default=500, help="machines (default 500)")
    _adjust_options(p)
    _plot_option(p, "the yield of each strategy with its 95 % interval")
    p.set_defaults(func=cmd_needle_strategies)

    p = nsub.add_parser("sobol", help="Sobol indices of SumDelta (SALib)")
    needle_common(p)
    study(p)
    p.add_argument("--n", type=int, default=256, help="base samples, a power of two")
    p.add_argument("--second-order", action="store_true",
                   help="also the second-order indices S2 of every pair (N (2D + 2) runs "
                        "instead of N (D + 2))")
    _beta_options(p)
    _plot_option(p, "S1 and ST of the adjusted case with their intervals")
    _adjust_options(p)
    p.set_defaults(func=cmd_needle_sobol)

    add_needle_ppm(nsub, needle_common, study)
    add_needle_guides_allocation(nsub, needle_common, study)
    add_needle_largest_tolerances(nsub, needle_common)

    p = nsub.add_parser("frames", help="the named frames of the 208 with their residuals")
    p.add_argument("--format", choices=FORMATS, default="table")
    p.set_defaults(func=cmd_needle_frames)

    feed = sub.add_parser("feed", help="131-42+3 feed chains (lower and upper dog)")
    fsub = feed.add_subparsers(dest="command", required=True, parser_class=Parser)
    p = fsub.add_parser("trajectory", help="both middle teeth over one turn")
    common(p, example="b=25")
    p.add_argument("--step-deg", type=float, default=1.0, help="main-shaft angle step (deg)")
    _plot_option(p, "both middle-tooth paths")
    p.set_defaults(func=cmd_feed_trajectory)
    p = fsub.add_parser("metrics", help="feed step, rise, phases, travel; differential ratio")
    common(p, example="b=25")
    p.set_defaults(func=cmd_feed_metrics)
    p = fsub.add_parser("regulator", help="feed steps and ratio against the regulator setting b")
    common(p, example="b=25")
    p.add_argument("--b-range", nargs=3, type=float, default=[0.0, 60.0, 2.0],
                   metavar=("LOW", "HIGH", "STEP"), help="b values swept (deg)")
    _plot_option(p, "the feed steps against b")
    p.set_defaults(func=cmd_feed_regulator)
    from sewtol.cli_feed import add_feed_studies  # `sewtol feed scan | montecarlo | sobol`

    add_feed_studies(fsub, common)

    from sewtol.cli_run import add_mechanisms, add_run  # `sewtol run FILE.toml STUDY`

    add_run(sub, Parser)
    add_mechanisms(sub)
    return ap


def resolve_progress(args, stream=None):
    """--progress/--no-progress as given; neither: on when stderr is a terminal."""
    if getattr(args, "progress", False) is None:
        args.progress = bool((stream or sys.stderr).isatty())
    return args


def _on_sigterm(signum, frame):
    raise Terminated()


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    previous = None
    try:  # only the main thread may set handlers; a library caller's threads run without
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:
        pass
    resolve_progress(args)
    try:
        _check_out(args)
        _check_plot(args)
        args.func(args)
    except (ParameterError, AssemblyError, CliError) as exc:
        print(f"sewtol: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # e.g. the disk filled up while a chunk was saved
        where = getattr(args, "out", None)
        kept = (f"; finished chunks are kept in {where}/chunks: rerun with --resume" if where
                else "")
        print(f"sewtol: error: {exc.filename or 'output'}: {exc.strerror or exc}{kept}",
              file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        where = getattr(args, "out", None)
        hint = (f"; finished chunks are saved in {where}/chunks: rerun the same command with "
                "--resume" if where else "; nothing was saved (use --out DIR to keep chunks)")
        what = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"sewtol: {what}{hint}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


if __name__ == "__main__":
    sys.exit(main())
