"""Feed chains of the 131-42+3: figures, tooth paths, regulator and tolerance studies.

    python studies/feed_131_report.py [--out reports] [--seed 2026] [--n-mc 2000]
        [--n-sobol 512] [--n-jobs 1 | --scheduler tcp://host:8786] [--progress]

Writes reports/feed_131-42-3/ (tables as CSV + Markdown, PNG plots, index.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from sewtol import feed
from sewtol.io import to_json, write_text_atomic
from sewtol.mechanisms.feed_131 import Feed131
from sewtol.mechanisms.params import as_dict
from sewtol.provenance import now, run_record
from sewtol.reports import plots
from sewtol.reports.tables import write_table


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--n-mc", type=int, default=2000)
    ap.add_argument("--n-sobol", type=int, default=512)
    ap.add_argument("--n-jobs", type=int, default=1)
    ap.add_argument("--progress", action="store_true")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the Monte-Carlo on a Dask cluster (same tables)")
    plots.add_figure_format(ap)
    args = ap.parse_args(argv)
    started = now()
    out = Path(args.out) / "feed_131-42-3"
    p = Feed131()
    settings = {"data": "../shared/design/feed_131-42-3.md (the analysis program's link data)",
                "regulator b (deg)": p.b, "plate level H (mm)": p.plate_mm,
                "material thickness (mm)": p.material_mm}

    m = feed.metrics(p)
    frame = m.to_dataframe()
    write_table(frame, out, "figures", "Working figures of the feed dogs",
                {**settings, "differential ratio (upper/lower step)": f"{m.differential_ratio:.4f}",
                 "horizontal mismatch while both grip (mm)": f"{m.mismatch_mm:.4f} over "
                 f"{m.overlap_deg:.1f} deg",
                 "units": "mm and deg; rise: lower above the plate, upper below plate + material"})
    res = feed.readoff_residuals(p)
    wide = res.wide()
    write_table(wide, out, "readoffs", "The source's plot read-offs against the model, residual "
                "(model - source) under each explanation a careful reader would test",
                {**settings, "read-offs": "../shared/design/feed_131-42-3.md (thesis plots: lower "
                 "top point, upper bottom point of the middle tooth)",
                 "residuals": "phases wrapped to (-180, 180] deg; steps compared as lengths "
                 "|T|, their sense as feed_direction (+1 forward, -1 reverse); NaN: the tooth "
                 "never crosses that level"}, floatfmt=".3f")
    write_table(res.summary(), out, "readoff_explanations",
                "Each explanation: what it changes and its largest residuals per dog",
                {**settings, **{e.name: (", ".join(f"{k} = {v:g}" for k, v in e.changes.items())
                                         or "no change") + (f"; upper read on the side "
                                                            f"{e.upper_side} the plate"
                                                            if e.upper_side else "")
                                for e in res.explanations}}, floatfmt=".3f")
    traj = feed.trajectory(p, 1.0)
    write_table(traj, out, "trajectory", "Middle-tooth paths over one turn", settings)
    f, ax = plt.subplots(figsize=(6, 5))
    plots.tooth_paths(traj, p.plate_mm, p.material_mm, ax)
    ax.set_title("131-42+3 feed dogs: middle-tooth paths", fontsize=10)
    plots.save(f, out / "tooth_paths.png", args.figure_format)
    f, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    plots.feed_xy_vs_phi(traj, p.plate_mm, axes)
    axes[0].set_title("x and y of the middle teeth against the main-shaft angle", fontsize=10)
    plots.save(f, out / "xy_vs_phi.png", args.figure_format)

    sweep = feed.regulator_sweep(p, np.arange(0.0, 60.0001, 1.0))
    neutral = feed.b_for_step(p, 0.0)
    write_table(sweep, out, "regulator", "Regulator sweep: feed steps against b",
                {**settings, "neutral (lower step 0) at b (deg)": f"{neutral:.4f}",
                 "b for a 2.5 mm stitch (deg)": f"{feed.b_for_step(p, 2.5):.4f}",
                 "b for a -2.0 mm (reverse) stitch (deg)": f"{feed.b_for_step(p, -2.0):.4f}",
                 "units": "b deg, steps mm, mismatch mm"})
    band = feed.b_range_for_ratio(p, (1.0, 1.2))
    write_table(band, out, "regulator_ratio_band",
                "Ranges of b that keep the differential ratio within 1.0 ... 1.2",
                {**settings, "grid": "0 ... 60 deg in 0.25 deg steps"})
    f, ax = plt.subplots(figsize=(7, 4))
    plots.regulator_curve(sweep, p.b, ax)
    ax.axvline(neutral, color="C3", ls="--", lw=1, label=f"neutral b = {neutral:.2f} deg")
    ax.legend(fontsize=7)
    ax.set_title("Stitch regulator: forward, neutral, reverse", fontsize=10)
    plots.save(f, out / "regulator.png", args.figure_format)

    ts = feed.default_tolerances()
    tset = {**settings, "tolerance set": ts.description, "seed": args.seed}
    sc = feed.scan(p, ts)
    sc = sc.reindex(sc["change_lower_step_mm"].abs().sort_values(ascending=False).index)
    write_table(sc.reset_index(drop=True), out, "scan",
                "Per-parameter scan of the feed (sorted by |change of the lower step|)", tset,
                floatfmt=".5f")
    mc = feed.montecarlo(p, ts, args.n_mc, args.seed, n_jobs=args.n_jobs, progress=args.progress,
                         scheduler=args.scheduler)
    write_table(feed.montecarlo_summary(mc), out, "montecarlo",
                f"Monte-Carlo of {args.n_mc} feed mechanisms", tset, floatfmt=".5f")
    contrib = feed.contributor_table(mc, ts)
    write_table(contrib, out, "contributors", "Contributors (bias-corrected eta^2) per output",
                tset)
    sob, chosen = feed.sobol(p, ts, args.n_sobol, args.seed, mc, n_jobs=args.n_jobs,
                             progress=args.progress, scheduler=args.scheduler)
    write_table(sob.to_dataframe(), out, "sobol", "Sobol indices of the feed steps and the "
                "differential ratio, each over the tolerances that matter to it",
                {**tset, "base samples N": args.n_sobol, "intervals": "95 % bootstrap",
                 **{f"parameters of {o}": ", ".join(v) for o, v in chosen.items()},
                 "choice": "by the Monte-Carlo's eta^2, until 90 % of the summed first-order "
                 "effects (4 ... 12 parameters)"})
    write_table(sob.convergence, out, "sobol_convergence",
                "Convergence of the feed Sobol indices: largest change between N/2 and N",
                {**tset, "base samples N": args.n_sobol})

    index = [
        "# 131-42+3 feed chains: reports",
        "",
        f"Lower dog: feed step {m.lower['feed_step_mm']:.3f} mm, rises above the plate at "
        f"phi = {m.lower['entry_phi_deg']:.1f} deg, highest {m.lower['max_rise_mm']:.3f} mm at "
        f"{m.lower['max_rise_phi_deg']:.1f} deg, vertical travel "
        f"{m.lower['vertical_travel_mm']:.3f} mm.",
        f"Upper dog: feed step {m.upper['feed_step_mm']:.3f} mm, works from "
        f"{m.upper['entry_phi_deg']:.1f} to {m.upper['exit_phi_deg']:.1f} deg, vertical travel "
        f"{m.upper['vertical_travel_mm']:.3f} mm. Differential ratio {m.differential_ratio:.4f}.",
        f"Regulator: neutral at b = {neutral:.3f} deg (data b = {p.b:g}); reverse below.",
        f"Settings: plate y = {p.plate_mm} mm, material {p.material_mm} mm; tolerance studies "
        f"use an assumed set ({ts.description}), seed {args.seed}.",
        "",
        "- [figures.md](figures.md), [trajectory.md](trajectory.md), tooth_paths.png, xy_vs_phi.png",
        "- [readoffs.md](readoffs.md), [readoff_explanations.md](readoff_explanations.md): the "
        "source's read-offs against the model under each explanation",
        "- [regulator.md](regulator.md), regulator.png, "
        "[regulator_ratio_band.md](regulator_ratio_band.md)",
        "- [scan.md](scan.md), [montecarlo.md](montecarlo.md), [contributors.md](contributors.md),"
        " [sobol.md](sobol.md), [sobol_convergence.md](sobol_convergence.md)",
    ]
    write_text_atomic(out / "index.md", "\n".join(index) + "\n")
    record = run_record(started, {"mechanism": "131-42+3 feed chains", "params": as_dict(p),
                     "tolerance_set": {"name": ts.name, "description": ts.description,
                                       "items": ts.as_dict()},
                     "seed": args.seed, "n_mc": args.n_mc, "n_sobol": args.n_sobol,
                     "n_jobs": args.n_jobs})
    write_text_atomic(out / "run.json", to_json(record))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
