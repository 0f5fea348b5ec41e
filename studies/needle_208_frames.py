"""Every study on every named frame of the 208, side by side, with a verdict per conclusion.

    python studies/needle_208_frames.py [--out reports] [--n-mc 2000] [--n-sobol 256]

Writes reports/needle_208/frames.md and frames.png. Each statement gets one of three labels, with
its value on every frame: it *holds in every frame*, it *fails in every frame*, or it is
*frame-dependent* (holds on some frames only): a designer acting on a frame-dependent figure acts
on a reconstruction, not on the machine.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME, frame_names, load_frame
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.needle_208.single import nominal_figures
from sewtol.reports import plots
from sewtol.tables.needle_208 import largest_tolerances, montecarlo, needle_sobol, scan
from sewtol.tolerances import NEEDLE_208_SETS

LINKS = ["LF", "LM", "AM", "AB", "BC", "BE", "CD"]


def study_frame(name, args, progress):
    f = load_frame(name)
    p = Needle208.nominal(f)
    nom = nominal_figures(p)
    progress(f"{name}: nominal")
    sc = scan(p, NEEDLE_208_SETS["recommended"]).to_dataframe()
    worst = sc.groupby("param")["total_um"].max().reindex(LINKS)
    lm = sc[sc.param == "LM"].set_index("side")["beta_deg"]
    progress(f"{name}: scan")
    yields = {}
    for ts in ("base", "recommended"):
        mc = montecarlo(p, NEEDLE_208_SETS[ts], args.n_mc, args.seed, n_jobs=args.n_jobs)
        yields[ts] = {"fixed": mc.yield_of("fixed"), "adjusted": mc.yield_of("adjusted"),
                      "failed": mc.failed, "n": mc.n}
        progress(f"{name}: Monte-Carlo {ts}")
    sob = needle_sobol(p, NEEDLE_208_SETS["recommended"], args.n_sobol, args.seed,
                       n_jobs=args.n_jobs).to_dataframe()
    st = sob[sob.case == "adjusted_beta"].set_index("param")["ST"]
    progress(f"{name}: Sobol")
    lt = largest_tolerances(p, LINKS, max_mm=1.0)
    lt_abs = lt.groupby("param")["largest_delta_mm"].apply(lambda s: float(np.min(np.abs(s))))
    progress(f"{name}: largest tolerances")
    return {"frame": f, "nominal": nom, "worst": worst, "lm_up": float(lm["upper"]),
            "lm_low": float(lm["lower"]), "yields": yields, "st": st.reindex(LINKS),
            "largest": lt_abs.reindex(LINKS)}


HOLDS, FAILS, DEPENDS = "holds in every frame", "fails in every frame", "frame-dependent"
LABELS = (HOLDS, FAILS, DEPENDS)


def label(holds: list[bool]) -> str:
    """The statement's label from whether it holds on each frame."""
    return HOLDS if all(holds) else FAILS if not any(holds) else DEPENDS


def verdicts(res: dict) -> list[tuple[str, str, str]]:
    names = list(res)
    rows = []

    def add(what, values, holds):
        spread = ", ".join(f"{n}: {v}" for n, v in zip(names, values, strict=True))
        rows.append((what, label(holds), spread))

    top3 = [set(r["worst"].sort_values(ascending=False).index[:3]) for r in res.values()]
    add("the three most critical links in the scan (largest SumDelta at a recommended limit)",
        ["/".join(sorted(t)) for t in top3], [t == top3[0] for t in top3])
    sob2 = [set(r["st"].sort_values(ascending=False).index[:2]) for r in res.values()]
    add("the two largest total Sobol indices (recommended, beta adjusted)",
        ["/".join(sorted(t)) for t in sob2], [t == sob2[0] for t in sob2])
    sob_top = [r["st"].idxmax() for r in res.values()]
    add("the single largest total Sobol index", [f"{s} ({r['st'][s]:.3f})" for s, r in
                                                 zip(sob_top, res.values(), strict=True)],
        [s == sob_top[0] for s in sob_top])
    tight4 = [set(r["largest"].sort_values().index[:4]) for r in res.values()]
    add("the four tightest links by largest single tolerance",
        ["/".join(sorted(t)) for t in tight4], [t == tight4[0] for t in tight4])
    least = [r["largest"].idxmin() for r in res.values()]
    add("the tightest link by largest single tolerance",
        [f"{s} ({r['largest'][s]:.4f} mm)" for s, r in zip(least, res.values(), strict=True)],
        [s == least[0] for s in least])
    lm = [np.sign(r["lm_up"] - r["lm_low"]) for r in res.values()]
    add("beta* grows with LM (Table 4.1: 24 at UL, 19 at LL)",
        [f"{r['lm_up']:.2f}/{r['lm_low']:.2f}" for r in res.values()], [s > 0 for s in lm])
    win = [r["nominal"].window_deg for r in res.values()]
    add("SumDelta <= 10 um over the whole of 19..25 (nominal)",
        [f"{a:.2f}..{b:.2f}" for a, b in win], [a <= 19 and b >= 25 for a, b in win])
    for ts in ("base", "recommended"):
        y = [r["yields"][ts]["adjusted"] for r in res.values()]
        add(f"yield with beta adjusted, {ts} tolerances >= 99 %",
            [f"{100 * v:.1f} %" for v in y], [v >= 0.99 for v in y])
    return rows


def main(argv=None) -> None:
    ap = plots.study_parser(__doc__, jobs=True, progress=True, figures=True, n_mc=2000,
                            n_sobol=256)
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"

    def progress(msg):
        if args.progress:
            print(msg, flush=True)

    res = {n: study_frame(n, args, progress) for n in frame_names()}
    ver = verdicts(res)
    lines = ["# 208 needle drive: every study on every named frame", "",
             f"Frames: {', '.join(f'`{n}`' for n in res)} (default `{DEFAULT_FRAME}`; "
             "calibration.md says how each was built). Monte-Carlo "
             f"{args.n_mc} machines, Sobol N = {args.n_sobol}, seed {args.seed}; scan and "
             "largest tolerances with beta re-optimised in 10..35 deg, guide fixed.", "",
             "## What holds in every frame", ""]
    for what, v, spread in sorted(ver, key=lambda r: LABELS.index(r[1])):
        lines.append(f"- **{v}**: {what} ({spread})")
    lines += ["", "## Side by side", ""]
    rows = []
    for n, r in res.items():
        nom = r["nominal"]
        row = {"frame": n, "family": r["frame"].summary_row()["family"],
               "beta* (deg)": nom.beta_opt_deg, "SumDelta* (um)": nom.total_um,
               "window (deg)": f"{nom.window_deg[0]:.2f}..{nom.window_deg[1]:.2f}",
               "stroke (mm)": nom.stroke_mm}
        for ts in ("base", "recommended"):
            y = r["yields"][ts]
            row[f"yield {ts} fixed/adj (%)"] = (f"{100 * y['fixed']:.1f}/{100 * y['adjusted']:.1f}"
                                                f" ({y['failed']} failed of {y['n']})")
        rows.append(row)
    lines += [pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3f"), ""]
    for title, key, fmt in (("Scan, recommended limits: largest SumDelta at either limit (um)",
                             "worst", ".2f"),
                            ("Sobol total index ST (recommended, beta adjusted)", "st", ".3f"),
                            ("Largest single tolerance keeping SumDelta(beta*) <= 10 um "
                             "(smaller side, mm)", "largest", ".4f")):
        t = pd.DataFrame({n: r[key] for n, r in res.items()})
        t.index.name = "link"
        lines += [f"### {title}", "", t.reset_index().to_markdown(index=False, floatfmt=fmt), ""]
    write_text_atomic(out / "frames.md", "\n".join(lines) + "\n")

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    x = np.arange(len(LINKS))
    w = 0.8 / len(res)
    for i, (n, r) in enumerate(res.items()):
        axes[0].bar(x + i * w, r["worst"].to_numpy(), w, label=n)
        axes[1].bar(x + i * w, r["st"].to_numpy(), w, label=n)
        axes[2].bar(x + i * w, r["largest"].to_numpy(), w, label=n)
    for ax, t in zip(axes, (f"scan: worst \u03a3\u0394 ({plots.MICRO}), dotted: 10 {plots.MICRO} "
                            "limit", "Sobol ST (\u03b2 adjusted)",
                            "largest tolerance (mm)"), strict=True):
        ax.set_xticks(x + 0.4 - w / 2, LINKS)
        ax.set_title(t, fontsize=9)
    axes[0].axhline(10.0, ls=":", c="k")
    axes[2].set_yscale("log")
    axes[0].legend(fontsize=8)
    plots.save(fig, out / "frames.png", args.figure_format)
    print(f"wrote {out / 'frames.md'} and {out / 'frames.png'}")


if __name__ == "__main__":
    main()
