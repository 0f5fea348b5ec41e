"""Feed chains of the 131-42+3: figures, tooth paths, regulator and tolerance studies.

    python studies/feed_131_report.py [--out reports] [--seed 2026] [--n-mc 2000]
        [--n-sobol 512] [--n-jobs 1 | --scheduler tcp://host:8786] [--progress]

Writes reports/feed_131-42-3/ (tables as CSV + Markdown, PNG plots, index.md).
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from sewtol.io import to_json, write_text_atomic
from sewtol.mechanisms.feed_131 import analysis as feed
from sewtol.mechanisms.feed_131.model import Feed131
from sewtol.mechanisms.params import as_dict
from sewtol.provenance import now, run_record
from sewtol.reports import plots
from sewtol.reports.html import Conclusion, Figure, Report, Section, markdown_index, render
from sewtol.reports.tables import write_table
from sewtol.studies import summaries as SU

# the feed report's outputs (the file's closed-form dog figures, output kind feed_dogs)
OUTPUTS = ("lower_step_mm", "upper_step_mm", "differential_ratio", "mismatch_mm")
SOBOL_OUTPUTS = OUTPUTS[:3]
CONTRIBUTOR_OUTPUTS = ("lower_step_mm", "differential_ratio", "mismatch_mm")

FIGURES = [("tooth_paths", "Middle-tooth paths with entry/exit and a dot every 30 deg of phi"),
           ("xy_vs_phi", "x and y of the middle teeth against phi; each dog's working part shaded"),
           ("regulator", "Feed steps against the regulator setting b over the range where the "
            "chain assembles")]
SECTIONS = [("Working figures and paths", ["figures", "trajectory"], FIGURES[:2]),
            ("The source's read-offs", ["readoffs", "readoff_explanations"], []),
            ("Regulator", ["regulator", "regulator_ratio_band"], FIGURES[2:]),
            ("Tolerances: scan, Monte-Carlo, contributors, Sobol",
             ["scan", "montecarlo", "contributors", "sobol", "sobol_convergence"], [])]


def feed_file():
    """The feed's mechanism file (its nominals are `Feed131()`'s values)."""
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file

    return load(mechanism_file("feed_131"))


def scan(mech, tolerances):
    """Each tolerance at its limits, others nominal (sewtol.studies.scan): feed steps, ratio and
    mismatch, and the changes of the steps and the ratio, one row per tolerance and side."""
    from sewtol.studies import scan as S

    f = SU.scan_table(S.scan(mech, tolerances, OUTPUTS, zero_width=True),
                      OUTPUTS).rename(columns={"deviation": "delta_mm"})
    return f[["param", "side", "delta_mm", *OUTPUTS, *(f"change_{k}" for k in SOBOL_OUTPUTS)]]


def montecarlo(mech, tolerances, n: int, seed: int, **options):
    """Feed outputs of n machines (sewtol.studies.montecarlo; options: n_jobs, progress,
    scheduler): machine, deviations, outputs."""
    from sewtol.studies.montecarlo import montecarlo as mc

    res = mc(mech, tolerances, n, seed, OUTPUTS, **options)
    return res.machines[["machine", *tolerances.active().params, *OUTPUTS]]


def write_pages(out: Path, intro: str, conclusions: dict, provenance: dict,
                fmt: str = "png", headline: tuple = ()) -> Report:
    """index.md and report.html of the feed folder from its tables and figures (already written)
    and the conclusions; returns the report."""
    sections = []
    for heading, tables, figures in SECTIONS:
        figs = tuple(Figure(stem, caption, (out / f"{stem}.{fmt}").read_bytes(), fmt)
                     for stem, caption in figures)
        sections.append(Section(heading, tuple((t, (out / f"{t}.md").read_text())
                                               for t in tables), figs))
    report = Report("131-42+3 feed chains: reports", intro, conclusions, sections, provenance,
                    headline)
    write_text_atomic(out / "index.md", markdown_index(report))
    write_text_atomic(out / "report.html", render(report))
    return report


def reading_conclusions(explanations) -> list[Conclusion]:
    """What holds under every explanation of the source's read-offs, and what depends on it."""
    out = []
    for dog in ("lower", "upper"):
        senses = explanations[f"{dog}_feeds"]
        made = explanations[senses.notna() & (senses != "n/a")]  # n/a: never crosses the level
        kinds = sorted(set(made[f"{dog}_feeds"]))
        verdict = "holds under every reading" if len(kinds) == 1 else "reading-dependent"
        spread = ", ".join(f"{e}: {f}" for e, f in zip(made["explanation"], made[f"{dog}_feeds"],
                                                         strict=True))
        out.append(Conclusion(f"the {dog} dog feeds {' or '.join(kinds)} under the "
                              f"{len(made)} explanations that produce it ({spread})", verdict))
        best = made.sort_values(f"{dog}_max_phase_residual_deg").iloc[0]
        out.append(Conclusion(
            f"{dog} dog: the explanation closest to the read phases is '{best.explanation}' "
            f"(largest phase residual {best[f'{dog}_max_phase_residual_deg']:.1f} deg, length "
            f"{best[f'{dog}_max_length_residual_mm']:.3f} mm; [readoff_explanations.md]"
            "(readoff_explanations.md))"))
    return out


def headline(summary, contrib, sob, explanations, n_mc: int, tolerances: str, b_25: float
             ) -> tuple[tuple[str, str], ...]:
    """The report's first three lines, in the needle report's shape where it applies: the
    scatter (the feed has no published acceptance limit, so no yield is claimed), one
    recommendation (the tolerances that carry two thirds of the stitch length's variance) and
    what depends on the reading of the source (the feed has one frame)."""
    rows = summary.set_index("output")
    words = [f"{label} {rows.loc[out, 'mean']:.3f}{unit} (1–99 % {rows.loc[out, 'p1']:.3f}–"
             f"{rows.loc[out, 'p99']:.3f}{unit})" for out, label, unit in
             (("lower_step_mm", "the lower step", " mm"), ("upper_step_mm", "the upper", " mm"),
              ("differential_ratio", "the differential ratio", ""))]
    failed = int(rows["failed"].max())
    scatter = (f"no acceptance limit is published for the feed, so no yield is claimed; over "
               f"{n_mc} machines ({failed} failed to assemble; {tolerances}) "
               + ", ".join(words) + " ([montecarlo.md](montecarlo.md)).")
    g = contrib[(contrib["output"] == "lower_step_mm")
                & ~contrib["param"].astype(str).str.startswith("(")]
    key = "variance_pct" if "variance_pct" in g else "share_pct"
    cum = g[key].cumsum()
    top = g.head(int((cum < 200 / 3).sum()) + 1)
    st = sob[sob["case"] == "lower_step_mm"].set_index("param")["ST"]
    sobol = ", ".join(f"{p} {st[p]:.3f}" for p in top["param"] if p in st)
    do = (f"to narrow the stitch length (the lower step), tighten {_and(list(top['param']))}: "
          f"together {top[key].sum():.1f} % of its variance (eta^2"
          + (f"; Sobol ST {sobol}" if sobol else "") + "); the regulator sets the step itself "
          f"(2.5 mm at b = {b_25:.2f} deg) ([contributors.md](contributors.md)).")
    parts = []
    for dog in ("lower", "upper"):
        senses = explanations[f"{dog}_feeds"]
        kinds = sorted(set(senses[senses.notna() & (senses != "n/a")]))
        parts.append(f"the {dog} dog feeds {' or '.join(kinds)} "
                     + ("under every reading" if len(kinds) == 1 else "(reading-dependent)"))
    reading = ("one frame (the analysis program's exact link data); of the source's plots, "
               + " and ".join(parts) + " ([readoff_explanations.md](readoff_explanations.md)).")
    return (("Scatter", scatter), ("What to do", do), ("Reading", reading))


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def tighten_conclusions(contrib, sob) -> list[Conclusion]:
    from sewtol.studies.montecarlo import EXPLAINED

    out = []
    for output, g in contrib.groupby("output", sort=False):
        k = int((g["cumulative_pct"] < 80.0).sum()) + 1
        top = g.head(k)
        st = sob[sob["case"] == output].sort_values("ST", ascending=False).head(3)
        sobol_text = ("Sobol ST " + ", ".join(f"{r.param} {r.ST:.3f}" for r in st.itertuples())
                      if len(st) else "no Sobol study of this output")
        links = "([contributors.md](contributors.md), [sobol.md](sobol.md))"
        if "variance_pct" in g:  # shares of the whole variance, with the explained sum
            tol = g[~g["param"].astype(str).str.startswith("(")]
            top = tol.head(int((tol["cumulative_pct"] < 80.0).sum()) + 1)
            shares = ", ".join(f"{p} {v:.1f} %" for p, v in zip(top["param"], top["variance_pct"],
                                                                strict=True))
            summed = g[g["param"] == EXPLAINED]["variance_pct"]
            explained = float(summed.iloc[0]) if len(summed) else float(
                tol["variance_pct"].sum())
            rest = (f"single tolerances explain {explained:.1f} %, the other "
                    f"{100 - explained:.1f} % is interaction" if explained < 100 else
                    f"single tolerances explain all of it (their estimates add up to "
                    f"{explained:.1f} %: sampling noise)")
            out.append(Conclusion(f"{output}: {shares} of the variance (eta^2); {rest}; "
                                  f"{sobol_text} {links}"))
            continue
        shares = ", ".join(f"{p} {v:.1f} %" for p, v in zip(top["param"], top["share_pct"],
                                                            strict=True))
        out.append(Conclusion(
            f"{output}: {shares} of the scatter (eta^2, {top['cumulative_pct'].iloc[-1]:.1f} % "
            f"together); {sobol_text} {links}"))
    return out


def main(argv=None) -> None:
    ap = plots.study_parser(__doc__, jobs=True, progress=True, figures=True, n_mc=2000,
                            n_sobol=512)
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the Monte-Carlo on a Dask cluster (same tables)")
    args = ap.parse_args(argv)
    started = now()
    out = Path(args.out) / "feed_131-42-3"
    p = Feed131()
    settings = {"data": "the analysis program's link data (docs/feed_131.md)",
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
                {**settings, "read-offs": "the source's plots (thesis: lower top point, upper "
                 "bottom point of the middle tooth; docs/feed_131.md)",
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
    phases = {dog: (getattr(m, dog)["entry_phi_deg"], getattr(m, dog)["exit_phi_deg"])
              for dog in ("lower", "upper")}
    traj = feed.trajectory(p, 1.0)
    write_table(traj, out, "trajectory", "Middle-tooth paths over one turn", settings)
    f, ax = plt.subplots(figsize=(6, 5))
    plots.tooth_paths(traj, p.plate_mm, p.material_mm, ax, phases=phases)
    ax.set_title("131-42+3 feed dogs: middle-tooth paths", fontsize=10)
    plots.save(f, out / "tooth_paths.png", args.figure_format)
    f, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    plots.feed_xy_vs_phi(traj, p.plate_mm, axes, phases=phases)
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
    # the plot sweeps past the table's 0 ... 60 deg, so the limits of assembly show
    plots.regulator_curve(feed.regulator_sweep(p, np.arange(-30.0, 70.0001, 0.5)), p.b, ax)
    ax.axvline(neutral, color="C3", ls="--", lw=1, label=f"neutral b = {neutral:.2f} deg")
    ax.legend(fontsize=7)
    ax.set_title("Stitch regulator: forward, neutral, reverse", fontsize=10)
    plots.save(f, out / "regulator.png", args.figure_format)

    mech = feed_file()
    ts = mech.tolerance_sets["assumed"]
    tset = {**settings, "tolerance set": ts.description, "seed": args.seed}
    sc = scan(mech, ts)
    sc = sc.reindex(sc["change_lower_step_mm"].abs().sort_values(ascending=False).index)
    write_table(sc.reset_index(drop=True), out, "scan",
                "Per-parameter scan of the feed (sorted by |change of the lower step|)", tset,
                floatfmt=".5f")
    mc = montecarlo(mech, ts, args.n_mc, args.seed, n_jobs=args.n_jobs, progress=args.progress,
                    scheduler=args.scheduler)
    write_table(SU.output_summary(mc, OUTPUTS), out, "montecarlo",
                f"Monte-Carlo of {args.n_mc} feed mechanisms", tset, floatfmt=".5f")
    contrib = SU.contributor_table(mc, ts, CONTRIBUTOR_OUTPUTS)
    write_table(contrib, out, "contributors", "Contributors (bias-corrected eta^2) per output",
                tset)
    sob, chosen = SU.screened_sobol(mech, ts, SOBOL_OUTPUTS, args.n_sobol, args.seed, mc,
                                    n_jobs=args.n_jobs, progress=args.progress,
                                    scheduler=args.scheduler)
    write_table(sob.to_dataframe(), out, "sobol", "Sobol indices of the feed steps and the "
                "differential ratio, each over the tolerances that matter to it",
                {**tset, "base samples N": args.n_sobol, "intervals": "95 % bootstrap",
                 **{f"parameters of {o}": ", ".join(v) for o, v in chosen.items()},
                 "choice": "by the Monte-Carlo's eta^2, until 90 % of the summed first-order "
                 "effects (4 ... 12 parameters)"})
    write_table(sob.convergence, out, "sobol_convergence",
                "Convergence of the feed Sobol indices: largest change between N/2 and N",
                {**tset, "base samples N": args.n_sobol})

    fmt = "svg" if args.figure_format == "svg" else "png"
    summary = SU.output_summary(mc, OUTPUTS)
    conclusions = {
        "What holds under every reading of the source, and what depends on it":
            reading_conclusions(res.summary()),
        "Which tolerances to tighten (assumed set)":
            tighten_conclusions(contrib, sob.to_dataframe()),
        "What the regulator (the adjustment) buys": [
            Conclusion(f"neutral at b = {neutral:.3f} deg (data b = {p.b:g}); reverse below; a "
                       f"2.5 mm stitch at b = {feed.b_for_step(p, 2.5):.3f} deg, a -2.0 mm reverse "
                       f"stitch at b = {feed.b_for_step(p, -2.0):.3f} deg "
                       "([regulator.md](regulator.md))"),
            *[Conclusion(f"differential ratio within 1.0 ... 1.2 for b = {r.b_low_deg:g} ... "
                         f"{r.b_high_deg:g} deg ([regulator_ratio_band.md]"
                         "(regulator_ratio_band.md))") for r in band.itertuples()]],
        "Nominal dogs and their scatter": [
            Conclusion(f"lower dog: feed step {m.lower['feed_step_mm']:.3f} mm, rises above the "
                       f"plate at phi = {m.lower['entry_phi_deg']:.1f} deg, highest "
                       f"{m.lower['max_rise_mm']:.3f} mm at {m.lower['max_rise_phi_deg']:.1f} deg, "
                       f"vertical travel {m.lower['vertical_travel_mm']:.3f} mm"),
            Conclusion(f"upper dog: feed step {m.upper['feed_step_mm']:.3f} mm, works from "
                       f"{m.upper['entry_phi_deg']:.1f} to {m.upper['exit_phi_deg']:.1f} deg, "
                       f"vertical travel {m.upper['vertical_travel_mm']:.3f} mm; differential "
                       f"ratio {m.differential_ratio:.4f}"),
            *[Conclusion(f"{r.output} over {r.n} machines ({r.failed} failed): mean "
                         f"{r.mean:.4f}, 1 ... 99 % {r.p1:.4f} ... {r.p99:.4f} "
                         "([montecarlo.md](montecarlo.md))") for r in summary.itertuples()]],
    }
    intro = (f"Settings: plate y = {p.plate_mm} mm, material {p.material_mm} mm; the link data "
             "are the analysis program's (exact, one frame); the tolerance studies use an assumed "
             f"set ({ts.description}), seed {args.seed}, Monte-Carlo {args.n_mc} machines, "
             f"Sobol N = {args.n_sobol}.")
    record = run_record(started, {"mechanism": "131-42+3 feed chains", "params": as_dict(p),
                     "tolerance_set": {"name": ts.name, "description": ts.description,
                                       "items": ts.as_dict()},
                     "seed": args.seed, "n_mc": args.n_mc, "n_sobol": args.n_sobol,
                     "n_jobs": args.n_jobs})
    seconds = (datetime.fromisoformat(record["finished_utc"])
               - datetime.fromisoformat(started)).total_seconds()
    prov = {"revision": record["git_revision"], "sewtol": record["sewtol_version"],
            "frame": "the analysis program's link data (no alternative frame)",
            "seed": args.seed, "Monte-Carlo machines n": args.n_mc,
            "Sobol base samples N": args.n_sobol, "tolerance set": ts.description,
            "run time": f"{seconds:.0f} s ({started} ... {record['finished_utc']})",
            "command": "`" + " ".join(record["command_line"]) + "`",
            "libraries": ", ".join(f"{k} {v}" for k, v in record["libraries"].items())}
    lines = headline(summary, contrib, sob.to_dataframe(), res.summary(), args.n_mc,
                     ts.description, feed.b_for_step(p, 2.5))
    write_pages(out, intro, conclusions, prov, fmt, lines)
    write_text_atomic(out / "run.json", to_json(record))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
