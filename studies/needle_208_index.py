"""The index page of reports/needle_208/: what is robust first, then what each study says, then
every table and figure. Reads only the tables the other study scripts wrote (run it last).

    python studies/needle_208_index.py [--out reports]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from sewtol.io import write_text_atomic


def _section(md: str, heading: str) -> list[str]:
    """The lines of a Markdown section (without its heading), up to the next heading."""
    lines, inside = [], False
    for line in md.splitlines():
        if line.startswith("## "):
            if inside:
                break
            inside = line[3:].strip() == heading
            continue
        if inside:
            lines.append(line)
    return [x for x in lines if x.strip()]


def _csv(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports")
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"

    nominal = _csv(out / "nominal.csv").set_index("quantity")["value"]
    mc = json.loads((out / "montecarlo_summary.json").read_text())
    strategies = _csv(out / "strategies.csv")
    ppm = _csv(out / "ppm.csv")
    frames = (out / "frames.md").read_text()

    lines = [
        "# 208 needle drive: reports",
        "",
        "The frame of the 208 (the positions of the upper shaft A and the rear rocker pivot D, the",
        "dyad branches, the sense of beta) is not published. Every figure below comes from the",
        "default reconstruction `sewtol-0.1`; [frames.md](frames.md) repeats the studies on every",
        "named frame ([calibration.md](calibration.md) says how each was fitted). Read the",
        "conclusions in that light:",
        "",
        "## What holds in every frame, and what depends on the frame",
        "",
        *_section(frames, "What is robust"),
        "",
        "## What the studies say (frame sewtol-0.1, seed 2026)",
        "",
        f"- Nominal: beta* = {nominal['beta* (deg)']:.3f} deg, SumDelta = "
        f"{nominal['SumDelta at beta* (um)']:.3f} um, SumDelta <= 10 um for beta in "
        f"{nominal['window SumDelta <= 10 um, low (deg)']:.2f} ... "
        f"{nominal['window SumDelta <= 10 um, high (deg)']:.2f} deg, stroke "
        f"{nominal['stroke (mm)']:.2f} mm ([nominal.md](nominal.md)).",
    ]
    for name in ("base", "recommended"):
        s = mc[name]
        c = s["counts"]["adjusted_beta"]
        lines.append(
            f"- Monte-Carlo, {name} tolerances, {s['n']} machines: within 10 um "
            f"{s['yield_fixed_beta']:.2%} with beta fixed at the nominal beta*, "
            f"{s['yield_adjusted_beta']:.2%} with beta adjusted per machine "
            f"(ok {c['ok']} + out of spec {c['out_of_spec']} + failed {c['failed']} = {c['n']}; "
            f"[montecarlo_{name}.md](montecarlo_{name}.md)).")
    for name, g in strategies.groupby("tolerances", sort=False):
        parts = [f"{r.strategy} {r['yield']:.1%} [{r.yield_ci_low:.1%}, {r.yield_ci_high:.1%}]"
                 for _, r in g.iterrows()]
        lines.append(f"- Adjustment strategies, {name} tolerances, {int(g['n'].iloc[0])} machines "
                     f"(the same in every row): {'; '.join(parts)} ([strategies.md](strategies.md)).")
    alloc = ppm[ppm["tolerance set"] == "allocated"]
    for _, r in alloc.iterrows():
        lines.append(f"- Allocated tolerances (99.73 % after beta adjustment, "
                     f"[allocation.md](allocation.md)), {r.strategy}: {r.statement} "
                     "([ppm.md](ppm.md), [ppm_bruteforce.md](ppm_bruteforce.md)).")
    lines += [
        "",
        "## Tables and figures",
        "",
        "- [calibration.md](calibration.md), [frames.md](frames.md), frames.png: the named frames, "
        "their conditioning and residuals against every published figure",
        "- [nominal.md](nominal.md), [deviation.md](deviation.md), deviation.png, "
        "[sum_delta_vs_beta.md](sum_delta_vs_beta.md), sum_delta_vs_beta.png",
    ]
    for name in ("base", "recommended"):
        lines.append(
            f"- {name}: [scan](scan_{name}.md) (guide shifted: [+50 um](scan_{name}_shift+50um.md),"
            f" [-50 um](scan_{name}_shift-50um.md)), scan_{name}_deviation.png, "
            f"[worst case](worst_case_{name}.md), [Monte-Carlo](montecarlo_{name}.md) "
            f"([contributors](montecarlo_{name}_pareto.md)), montecarlo_{name}.png, "
            f"[Sobol](sobol_{name}.md) ([convergence](sobol_{name}_convergence.md)), "
            f"sobol_{name}.png, [failures after beta + shift](strategies_{name}_failures.md)")
    lines += [
        "- [largest_tolerances.md](largest_tolerances.md): per-parameter tolerance search",
        "- [allocation.md](allocation.md): widest tolerances for 99.73 % yield after adjustment",
        "- [guides.md](guides.md): guide settings compared",
        "- [strategies.md](strategies.md), strategies_yield.png, strategies_*_hist.png: yield by "
        "adjustment strategy; per-machine tables strategies_*_machines_*.csv",
        "- [ppm.md](ppm.md), [ppm_bruteforce.md](ppm_bruteforce.md), "
        "[ppm_exceedance.md](ppm_exceedance.md), ppm_exceedance.png, "
        "[ppm_failing_machines.md](ppm_failing_machines.md): failures per million",
        "- montecarlo_summary.json: the Monte-Carlo summaries as the CLI prints them",
    ]
    write_text_atomic(out / "index.md", "\n".join(lines) + "\n")
    print(f"wrote {out / 'index.md'}")


if __name__ == "__main__":
    main()
