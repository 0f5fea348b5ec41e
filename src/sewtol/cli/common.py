"""What every command family of `sewtol` shares: the parser class, flag options and checks,
outputs (emit, --out folders, --plot files) and the run records. Families import from here;
this module imports no family."""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import os
import sys
from pathlib import Path

from sewtol.errors import ParameterError
from sewtol.io import to_json

FORMATS = ("table", "json", "csv")
MIN_STEP_DEG = 1e-3  # 360 000 angles per turn; finer steps only fill memory
# the largest |value| --set takes: no length (mm), angle (deg) or shift (um) of a sewing
# machine comes near it, and 1e308 would overflow to inf inside the model
MAX_SET_VALUE = 1e6


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the flag, like every other refusal."""

    def error(self, message):
        self.exit(2, f"sewtol: error: {message} (see {self.prog} --help)\n")


def parse_sets(items, cls=None) -> dict:
    """--set NAME=VALUE pairs, their names checked against the parameters of `cls` if given
    (`run FILE`: the loader checks the names and each parameter's rule)."""
    from sewtol.mechanisms.params import field_names

    valid = None if cls is None else field_names(cls)
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError("--set", "must be NAME=VALUE", item)
        name, _, text = item.partition("=")
        name = name.strip()
        if valid is not None and name not in valid:
            raise ParameterError(name, f"unknown parameter; valid names are {', '.join(valid)}",
                                 name)
        if name in out:
            raise ParameterError(name, "is given twice; give each name once", item)
        try:
            value = float(text)
        except ValueError:
            raise ParameterError(name, "must be a number", text) from None
        if not abs(value) <= MAX_SET_VALUE:  # also nan and inf
            raise ParameterError(name, f"must be a finite number in [-{MAX_SET_VALUE:g}, "
                                 f"{MAX_SET_VALUE:g}]", text)
        out[name] = value
    return out


# the columns that say why a machine gives no value, whose sum a compact table prints as
# `failed` (so ok + out_of_spec + failed = n stays visible)
FAILURE_COLUMNS = ("cannot_assemble", "cannot_close", "dead_point", "undefined", "unexplained")


def emit(fmt: str, *, obj=None, frame=None, compact=None, wide: bool = False) -> None:
    """Print a study's result: `obj` as JSON, `frame` as CSV, or `frame` as a Markdown table.
    JSON and CSV always hold every column; a table with `compact` (the column names a decision
    needs, in their order) prints those unless `wide`, and says in a note what --wide adds.
    `frame` is a DataFrame or its rows as records (dicts): a table of plain records
    (`plain_columns`) is printed without importing pandas, in the same bytes."""
    if isinstance(frame, list):
        shown = plain_columns(frame, compact, wide) if fmt == "table" else None
        if shown is not None:
            from tabulate import tabulate

            # pandas' to_markdown: tabulate of the frame's values, object rows of str/int/float
            rows = [list(row) for row in zip(*shown.values(), strict=True)]
            sys.stdout.write(tabulate(rows, headers=list(shown), tablefmt="pipe",
                                      showindex=False, floatfmt=".4f") + "\n")
            return _wide_note([c for c in dict.fromkeys(k for r in frame for k in r)
                               if c not in shown])
        if fmt != "json" or obj is None:
            import pandas as pd

            frame = pd.DataFrame(frame)
    if fmt == "json":
        data = obj if obj is not None else frame.to_dict(orient="records")
        sys.stdout.write(to_json(data))
    elif fmt == "csv":
        from sewtol.reports.tables import to_csv

        sys.stdout.write(to_csv(frame))
    else:
        shown = frame if wide or compact is None else compact_view(frame, compact)
        sys.stdout.write(shown.to_markdown(index=False, floatfmt=".4f") + "\n")
        _wide_note([c for c in frame.columns if c not in shown.columns])


def _compact_plan(columns, compact) -> dict:
    """The `compact` names a table of `columns` shows, in that order, each -> its column, or
    for `failed` (when there is no such column) the tuple of FAILURE_COLUMNS it sums."""
    plan = {}
    for name in compact:
        if name in columns:
            plan[name] = name
        elif name == "failed":
            causes = tuple(c for c in FAILURE_COLUMNS if c in columns)
            if causes:
                plan[name] = causes
    return plan


def compact_view(frame, compact):
    """`frame` cut to `_compact_plan`'s columns, `failed` the sum of its failure columns."""
    import pandas as pd

    return pd.DataFrame({name: frame[src] if isinstance(src, str) else
                         frame[list(src)].sum(axis=1)
                         for name, src in _compact_plan(frame.columns, compact).items()},
                        index=frame.index)


def _wide_note(hidden) -> None:
    if hidden:
        sys.stdout.write(f"\nnote: --wide adds {len(hidden)} more columns "
                         f"({', '.join(map(str, hidden))}); --format json and csv hold "
                         "every column\n")


def plain_columns(records, compact=None, wide: bool = True) -> dict | None:
    """The columns of pandas.DataFrame(records) (cut to `compact` by `_compact_plan`, as
    `compact_view` cuts a frame, unless `wide`) as lists of the values its .values hands
    tabulate, or None when pandas must decide: a missing cell or a None (NaN), a bool, a column
    mixing text and numbers, failure columns that are not counts, or no text column (an
    all-number frame's values are floats)."""
    import numbers

    names = list(dict.fromkeys(k for r in records for k in r))
    cols = {}
    for name in names:
        vals = [r.get(name) for r in records]
        if all(isinstance(v, str) for v in vals):
            cols[name] = vals
        elif any(v is None or isinstance(v, bool) or not isinstance(v, numbers.Real)
                 for v in vals) or not vals:
            return None
        else:  # int64 when every value is an integer type, else float64
            kind = int if all(isinstance(v, numbers.Integral) for v in vals) else float
            cols[name] = [kind(v) for v in vals]
    if not (wide or compact is None):
        cut = {}
        for name, src in _compact_plan(cols, compact).items():
            if isinstance(src, str):
                cut[name] = cols[src]
            elif all(isinstance(v, int) for c in src for v in cols[c]):
                cut[name] = [sum(v) for v in zip(*(cols[c] for c in src), strict=True)]
            else:
                return None
        cols = cut
    return cols if any(isinstance(c[0], str) for c in cols.values()) else None


def wide_option(p):
    """--wide: a table prints every column (by default the columns a decision needs)."""
    p.add_argument("--wide", action="store_true",
                   help="table output: print every column (default: the columns a decision "
                        "needs; --format json and csv always hold every column)")


def print_notes(args, notes) -> None:
    """Table output says in words what JSON carries as flags (an optimum on a range bound)."""
    if args.format == "table" and notes:
        sys.stdout.write("".join(f"\nnote: {line}" for line in notes) + "\n")


def plot_option(p, what):
    p.add_argument("--plot", default=None, metavar="FILE",
                   help=f"also draw {what} into FILE (.png, .svg or .pdf)")


def progress_option(p):
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: on when stderr is a terminal)")


def check_plot(args) -> None:
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


def plots():
    from sewtol.reports import plots

    return plots


def save_plot(args, draw) -> None:
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
        plots().save_as(fig, Path(args.plot))
    except OSError as exc:
        raise ParameterError("--plot", f"cannot be written ({exc.strerror})", args.plot) from None


def scan_figure(frame, column, ax, ylabel, limit=None):
    """A scan's `column` at each tolerance's upper and lower limit, one group per tolerance."""
    labels = list(dict.fromkeys(frame["param"]))
    series = {side: [float(frame.loc[(frame["param"] == p) & (frame["side"] == side),
                                     column].iloc[0]) for p in labels]
              for side in ("upper", "lower")}
    return plots().grouped_bars(labels, series, ax=ax, ylabel=ylabel, limit=limit,
                                 title="each tolerance at its limits")


def deviation_columns(machines, params, units=None):
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


def machine_context(args, params, **extra) -> dict:
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


def check_step(value, name="--step-deg"):
    if not (MIN_STEP_DEG <= value <= 90):
        raise ParameterError(name, f"must be in [{MIN_STEP_DEG:g}, 90]", value)

FLAGS = {"n": "--n", "seed": "--seed", "tolerances": "--tolerances", "n_jobs": "--n-jobs"}


def as_flags(check, *a, flags=FLAGS):
    """Run a library check; its error names the CLI flag rather than the keyword argument."""
    try:
        return check(*a)
    except ParameterError as exc:
        if exc.field in flags:
            raise ParameterError(flags[exc.field], exc.rule, exc.value) from None
        raise


def check_out(args):
    """--out must be (or become) a writable folder; checked before anything is written."""
    out = getattr(args, "out", None)
    if out is None:
        return
    if not out.strip():
        raise ParameterError("--out", "must name a folder", out)
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


def check_study(args):
    """Every study flag is checked before anything is computed or written."""
    if getattr(args, "seed", 0) < 0:
        raise ParameterError("--seed", "must be a whole number >= 0", args.seed)
    if getattr(args, "n_jobs", 1) == 0 or getattr(args, "n_jobs", 1) < -1:
        raise ParameterError("--n-jobs", "must be a positive number of workers or -1 (all cores)",
                             args.n_jobs)
    if getattr(args, "resume", False) and not getattr(args, "out", None):
        raise ParameterError("--resume", "needs --out, the folder of the interrupted study",
                             True)
    scheduler_address(args)


def not_offered(args, command: str, **why) -> None:
    """Refuse, in one line, a shared study flag (resume, scheduler, n_jobs) that `command` takes
    from the common parser but does not use; `why` maps each checked flag to the reason."""
    for key, reason in why.items():
        if key == "resume":
            flag, used, value = "--resume", bool(args.resume), True
        elif key == "scheduler":
            where = scheduler_address(args)
            flag, used, value = "--scheduler", where is not None, where and where[1]
        else:
            flag, used, value = "--n-jobs", args.n_jobs != 1, args.n_jobs
        if used:
            raise ParameterError(flag, f"is not offered by {command} ({reason})", value)


def scheduler_address(args) -> tuple[str, str] | None:
    """(flag, address) of the Dask scheduler from --scheduler or SEWTOL_SCHEDULER, or None for
    this machine. Checked with the other flags, before anything is computed."""
    if getattr(args, "scheduler", None) is not None:
        flag, address = "--scheduler", args.scheduler
    elif os.environ.get("SEWTOL_SCHEDULER", "").strip():
        flag, address = "SEWTOL_SCHEDULER", os.environ["SEWTOL_SCHEDULER"]
    else:
        return None
    from sewtol.studies.parallel import check_address

    try:
        check_address(address)
    except ParameterError as exc:
        raise ParameterError(flag, exc.rule, address) from None
    if getattr(args, "n_jobs", 1) != 1:
        raise ParameterError("--n-jobs", f"is the single-machine path; with {flag} the "
                             "cluster's workers set the parallelism", args.n_jobs)
    return flag, address


@contextlib.contextmanager
def cluster(args):
    """A distributed.Client on the study's scheduler (None without one), closed afterwards."""
    where = scheduler_address(args)
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


def study_inputs(args, kind, params, tolerances, **extra) -> dict:
    """Every input that decides a study's numbers (the manifest binds its chunks to these)."""
    from sewtol.mechanisms.params import as_dict
    from sewtol.provenance import version_record

    return {"study": kind, "n": getattr(args, "n", None), "seed": args.seed,
            "params": as_dict(params),
            "tolerances": tolerances.as_record(),
            **version_record(), **extra, **getattr(args, "file_inputs", {})}


RUN_ONLY = ("n_jobs", "scheduler")  # recorded in run.json, but never change the numbers
# the code's identity: a finished study rerun into its own folder by a newer revision (as `make
# report` does) is the same study and replaces its results; resuming chunks still needs the
# same revision (checkpoint.ChunkStore compares the whole manifest)
CODE_ONLY = ("sewtol_version", "git_revision")


def check_study_folder(args, inputs: dict, chunked: bool = True) -> None:
    """--out D whose run.json records a different study is refused before anything is
    computed, as a chunked study's manifest is (checkpoint.ChunkStore): results of two studies
    are never mixed in one folder, and nothing already there is lost. A study that keeps no
    chunks (chunked=False) also refuses the chunks of an unfinished one."""
    from sewtol.io import read_json

    if not args.out:
        return
    manifest = Path(args.out) / "chunks" / "manifest.json"
    if not chunked and (manifest.exists() or manifest.is_symlink()):
        raise ParameterError("--out", "holds the chunks of another study (chunks/); resume it "
                             "with the command that started it, or choose an empty folder",
                             args.out)
    if not (Path(args.out) / "run.json").exists():
        return
    old = read_json(Path(args.out) / "run.json")
    old = old.get("inputs") if isinstance(old, dict) else None
    new = json.loads(to_json(inputs))
    if not isinstance(old, dict):
        raise ParameterError("--out", "holds a run.json that is not a sewtol record; choose "
                             "an empty folder", args.out)
    diff = sorted(k for k in set(old) | set(new)
                  if k not in RUN_ONLY + CODE_ONLY and old.get(k) != new.get(k))
    if diff:
        raise ParameterError("--out", f"holds the results of a different study (differs in "
                             f"{', '.join(diff)}); choose an empty folder", args.out)


def open_store(args, inputs: dict):
    """The checkpoint folder of a study run with --out (None without); takes its lock."""
    if not args.out:
        return None
    check_study_folder(args, inputs)
    from sewtol.studies.checkpoint import ChunkStore

    return ChunkStore(Path(args.out) / "chunks", inputs, args.resume, label=str(args.out))


def run_history(store, started: str) -> list:
    """Start times of every run into this folder (the first, then each --resume)."""
    if store is None:
        return [{"started_utc": started, "resumed": False}]
    from sewtol.io import read_json, write_text_atomic

    path = store.folder / "runs.json"
    runs = read_json(path)
    runs = [r for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []
    runs = [{"started_utc": str(r.get("started_utc")), "resumed": bool(r.get("resumed"))}
            for r in runs] + [{"started_utc": started, "resumed": bool(runs) or store.resumed}]
    write_text_atomic(path, json.dumps(runs, indent=2) + "\n")
    return runs


def write_outputs(args, kind, inputs, started, result_obj, frames, runs):
    """Tables, then the result, then run.json into --out, each file atomically (a run.json
    means the folder is complete)."""
    if not args.out:
        return
    from sewtol.io import write_pieces_atomic, write_text_atomic
    from sewtol.provenance import run_record
    from sewtol.reports.tables import csv_pieces, to_csv

    out = Path(args.out)

    def put(path: Path, text) -> None:  # a failure names the file, never its temp file
        try:
            if isinstance(text, str):
                write_text_atomic(path, text)
            else:  # a table's CSV piece by piece (`csv_pieces`)
                write_pieces_atomic(path, text)
        except OSError as exc:
            fix = "free the space" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "fix it"
            kept = ("; the finished chunks are kept: " + fix + " and rerun with --resume"
                    if (out / "chunks").is_dir() else f"; {fix} and rerun")
            raise ParameterError("--out", f"cannot be written ({exc.strerror}){kept}",
                                 str(path)) from None

    for name, frame in frames.items():  # a table, or its chunks (an iterable of tables)
        put(out / f"{name}.csv", to_csv(frame) if hasattr(frame, "to_csv")
            else csv_pieces(frame))
    put(out / f"{kind}.json", to_json(result_obj))
    where = scheduler_address(args)
    record = run_record(started, {**inputs, "n_jobs": args.n_jobs,
                                  "scheduler": where[1] if where else None}, runs=runs)
    put(out / "run.json", to_json(record))


def resolve_progress(args, stream=None):
    """--progress/--no-progress as given; neither: on when stderr is a terminal."""
    if getattr(args, "progress", False) is None:
        args.progress = bool((stream or sys.stderr).isatty())
    return args


def machine_options(p, example="LF=6.8", formats=FORMATS):
    """--set NAME=VALUE and --format: every command on one machine or its tolerances."""
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help=f"override a parameter (repeatable), e.g. --set {example}")
    p.add_argument("--format", choices=formats, default="table")
