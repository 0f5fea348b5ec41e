"""Yield by adjustment strategy for the 208 needle drive, base and recommended sets.

Writes reports/needle_208/strategies.md/.csv (both sets), strategies_SET_machines_STRATEGY.csv,
strategies_SET_failures.md/.csv (which tolerances drive the machines still out of spec),
strategies_yield.png and strategies_SET_STRATEGY_hist.png (one histogram per compensator with
its limits drawn), strategies_setting_error.md/.csv/.png (the yield of beta + shift + angle
against the guide angle's setting error, both sets on the same machines as the table) and
strategies_run.json.

    python studies/needle_208_strategies.py [--out reports] [--seed 2026] [--n 500] [--n-jobs 1]
        [--tolerances FILE.toml[:SET] ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from sewtol.errors import ParameterError  # noqa: E402
from sewtol.io import write_text_atomic  # noqa: E402
from sewtol.mechanisms.needle_208.compensators import default_strategies  # noqa: E402
from sewtol.mechanisms.needle_208.model import Needle208  # noqa: E402
from sewtol.mechanisms.params import field_names  # noqa: E402
from sewtol.provenance import now, run_record  # noqa: E402
from sewtol.reports import plots  # noqa: E402
from sewtol.reports.tables import write_table  # noqa: E402
from sewtol.studies.strategies import yield_curve  # noqa: E402
from sewtol.tables.needle_208 import as_mechanism, strategies_table  # noqa: E402
from sewtol.tolerances import NEEDLE_208_SETS, resolve_all  # noqa: E402

SETS = ("base", "recommended")
# the guide angle's setting error (normal sd, deg) of the curve: the default 0.01 in the middle
CURVE_SD_DEG = (0.0, 0.0025, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03)
CURVE_STRATEGY = "beta+shift+angle"


def plot_yield(tables: dict[str, pd.DataFrame], ax):
    names = list(next(iter(tables.values())).strategy)
    x = np.arange(len(names))
    width = 0.8 / len(tables)
    for j, (set_name, t) in enumerate(tables.items()):
        y = t["yield"].to_numpy() * 100
        err = np.vstack([y - t["yield_ci_low"] * 100, t["yield_ci_high"] * 100 - y])
        ax.bar(x + (j - 0.5 * (len(tables) - 1)) * width, y, width, yerr=err, capsize=3,
               label=f"{set_name} tolerances")
    ax.set_xticks(x, names, rotation=20)
    ax.set_ylabel(f"yield, \u03a3\u0394 \u2264 10 {plots.MICRO} (%)")
    ax.set_title("Yield by adjustment strategy (same machines per set, 95 % Clopper-Pearson)")
    ax.legend()
    return ax


def plot_settings(adj, set_name, out: Path, fmt: str = "png") -> list[Path]:
    paths = []
    for comp in adj.strategy.compensators:
        x = adj.settings[comp.name]
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.hist(x[np.isfinite(x)], bins=30, color="tab:blue")
        for lim in (comp.low, comp.high):
            ax.axvline(lim, color="tab:red", ls="--")
        unit = f" ({comp.unit.replace('um', plots.MICRO)})" if comp.unit else ""
        label = comp.name.removesuffix("_um").replace("_", " ")
        ax.set_xlabel(f"{label} setting{unit}, {comp.mode}; limits dashed")
        ax.set_ylabel("machines")
        share = float(np.mean(adj.at_limit[comp.name]))
        ax.set_title(f"{set_name}, {adj.strategy.name}: {label} ({share:.1%} at a limit)")
        fig.tight_layout()
        safe = "".join(ch if ch.isalnum() else "_" for ch in adj.strategy.name)
        paths.append(plots.save(fig, out / f"strategies_{set_name}_{safe}_{comp.name}_hist.png",
                                fmt))
    return paths


JOBS_HELP = "adjust the machines in chunks on this many processes (same tables)"


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=JOBS_HELP, progress=True, figures=True, n=500)
    ap.add_argument("--tolerances", action="append", metavar="FILE.toml[:SET]",
                    help="these sets instead of the built-in base and recommended (repeatable)")
    args = ap.parse_args(argv)
    try:
        sets = resolve_all(args.tolerances, {k: NEEDLE_208_SETS[k] for k in SETS},
                           field_names(Needle208))
        for ts in sets.values():
            ts.check_against(Needle208.nominal())
    except ParameterError as exc:
        print(f"needle_208_strategies.py: error: {exc}", file=sys.stderr)
        return 2
    started = now()
    out = Path(args.out) / "needle_208"
    out.mkdir(parents=True, exist_ok=True)
    p = Needle208.nominal()
    tables, frames = {}, []
    for set_name, ts in sets.items():
        res = strategies_table(p, ts, args.n, args.seed, n_jobs=args.n_jobs,
                               progress=args.progress)
        t = res.to_dataframe()
        tables[set_name] = t
        frames.append(t.assign(tolerances=set_name))
        for adj in res.adjustments:
            safe = "".join(ch if ch.isalnum() else "_" for ch in adj.strategy.name)
            m = res.machines(adj.strategy.name)
            write_text_atomic(out / f"strategies_{set_name}_machines_{safe}.csv",
                              m.to_csv(index=False, float_format="%.9g", lineterminator="\n"))
            if adj.strategy.name in ("beta+shift", "all"):
                plot_settings(adj, set_name, out, args.figure_format)
        fail = res.failure_contributors("beta+shift")
        write_table(fail, out, f"strategies_{set_name}_failures",
                    f"What drives the machines still out of spec with beta + guide shift "
                    f"({set_name} tolerances)",
                    {"n": args.n, "seed": args.seed,
                     "share_*_pct": "correlation-ratio share of the adjusted SumDelta's scatter "
                     "(all machines that run / the out-of-spec ones)",
                     "mean_z": "(deviation - mid) / half-width averaged over the failing "
                     "machines (0: does not matter, +/-1: failures sit at that limit)"})
    curves = {}
    row = next(r for r in default_strategies() if r.name == CURVE_STRATEGY)
    for set_name, ts in sets.items():
        curves[set_name] = yield_curve(as_mechanism(p), ts, args.n, args.seed, row,
                                       "guide_angle", CURVE_SD_DEG, n_jobs=args.n_jobs,
                                       progress=args.progress, limit_um=10.0)
    curve_frame = pd.concat([c.to_dataframe().assign(tolerances=k) for k, c in curves.items()],
                            ignore_index=True)
    curve_frame.insert(0, "tolerances", curve_frame.pop("tolerances"))
    write_table(curve_frame, out, "strategies_setting_error",
                "Yield of beta + shift + angle against the guide angle's setting error",
                {"n per set": args.n, "seed": args.seed,
                 "machines": "the same machines as strategies.md, the same error draws at every "
                 "sd (only the scale changes)",
                 "model": "the angle set first: its optimum plus a normal error of this sd "
                 "(clipped to +/-0.1 deg), then beta and the guide shift re-set optimally",
                 "default": "sd 0.01 deg (docs/adjustment.md: about one 0.01 mm dial "
                 "graduation over the 50 mm guide); sd 0 is the exact row",
                 "counts": "ok + out_of_spec + cannot_close + dead_point = n"})
    fig, ax = plt.subplots(figsize=(7, 4))
    for set_name, c in curves.items():
        plots.yield_vs_setting_error(c, ax, label=f"{set_name} tolerances")
    ax.axvline(0.01, color="0.5", ls=":", lw=0.8)
    ax.set_title(f"Yield of beta + shift + angle against the guide angle's setting error, "
                 f"{args.n} machines per set (95 % interval; default sd 0.01 deg dotted)",
                 fontsize=9)
    fig.tight_layout()
    plots.save(fig, out / "strategies_setting_error.png", args.figure_format)
    both = pd.concat(frames, ignore_index=True)
    both.insert(0, "tolerances", both.pop("tolerances"))
    write_table(both, out, "strategies", "Yield by adjustment strategy, 208 needle drive",
                {"n per set": args.n, "seed": args.seed,
                 "machines": "the same machines in every row of a set (common random numbers)",
                 "criterion": "SumDelta <= 10 um, guide fixed through N1 unless adjusted",
                 "compensators": "beta 10..35 deg (absolute); guide_shift_um +/-100 um; "
                 "guide_angle +/-0.1 deg about N1; CD +/-0.3 mm (sliding head)",
                 "resolution, setting_error": "per row, each compensator's (none: set "
                 "exactly); with a setting error the compensators are set one by one, the "
                 "guide angle first, the later ones re-set (docs/adjustment.md)",
                 "beta+shift+angle exact": "the idealisation: the guide angle set exactly",
                 "none": "beta at the nominal machine's beta*, nothing adjusted",
                 "counts": "ok + out_of_spec + cannot_assemble + dead_point = n",
                 "Cpk": "one-sided, (10 um - mean) / 3 s over the machines that run",
                 "at_limit_share": "machines with any compensator at an end of its range"})
    fig, ax = plt.subplots(figsize=(8, 4.5))
    plot_yield(tables, ax)
    fig.tight_layout()
    plots.save(fig, out / "strategies_yield.png", args.figure_format)
    inputs = {"study": "strategies", "n": args.n, "seed": args.seed, "sets": list(sets)}
    write_text_atomic(out / "strategies_run.json",
                      json.dumps(run_record(started, inputs), indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
