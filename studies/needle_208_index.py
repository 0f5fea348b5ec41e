"""The index of reports/needle_208/: index.md (Markdown, figures embedded as images) and
report.html (one self-contained page: conclusions in words first, every table and figure, the
provenance). Reads only what the other study scripts wrote (run it last); every number in the
conclusions comes from those tables.

    python studies/needle_208_index.py [--out reports]
"""

from __future__ import annotations

import argparse
import json
from datetime import datetime
from pathlib import Path

import pandas as pd

from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME
from sewtol.reports.html import Conclusion, Figure, Report, Section, markdown_index, render

FIGURE_SUFFIXES = ("svg", "png")  # what the HTML embeds (a pdf run writes a png beside it)


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


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def figure_file(out: Path, stem: str) -> Path | None:
    """The figure's newest embeddable file (a run with --figure-format svg after a png run
    leaves both; the newer one is this run's)."""
    found = [out / f"{stem}.{s}" for s in FIGURE_SUFFIXES if (out / f"{stem}.{s}").exists()]
    return max(found, key=lambda f: f.stat().st_mtime_ns) if found else None


def set_names(run: dict) -> list[str]:
    return list(run.get("inputs", {}).get("tolerance_sets", {})) or ["base", "recommended"]


def robust_conclusions(frames_md: str) -> list[Conclusion]:
    out = []
    for line in _section(frames_md, "What is robust"):
        text = line.lstrip("- ").strip()
        for verdict in ("robust", "frame-dependent"):
            tag = f"**{verdict}**: "
            if text.startswith(tag):
                out.append(Conclusion(text[len(tag):], verdict))
                break
        else:
            out.append(Conclusion(text))
    return out


def tighten_conclusions(out: Path, sets: list[str]) -> list[Conclusion]:
    """Which tolerances to tighten: the contributors to the adjusted SumDelta's scatter, the
    largest total Sobol indices, the tightest single tolerances, the allocation's tightest."""
    items = []
    for name in sets:
        path = out / f"montecarlo_{name}_pareto.csv"
        if path.exists():
            par = _csv(path)
            k = int((par["cumulative_pct"] < 90.0).sum()) + 1
            top = par.head(k)
            link = f"[montecarlo_{name}_pareto.md](montecarlo_{name}_pareto.md)"
            if "variance_pct" in par:  # shares of the whole variance, the remainder named
                tol = par[~par["param"].astype(str).str.startswith("(")]
                top = tol.head(int((tol["cumulative_pct"] < 90.0).sum()) + 1)
                explained = float(tol["variance_pct"].sum())
                shares = ", ".join(f"{p} {v:.1f} %" for p, v in zip(
                    top["param"], top["variance_pct"], strict=True))
                rest = (f"the other {100 - explained:.1f} % is interaction, "
                        f"{_and(list(top['param']))} acting together" if explained < 100 else
                        "no interaction beyond the estimates' sampling noise")
                items.append(Conclusion(
                    f"{name} tolerances: single tolerances explain {min(explained, 100.0):.1f} % "
                    f"of the variance of SumDelta after beta adjustment ({shares}; eta^2); "
                    f"{rest} ({link})."))
            else:
                shares = ", ".join(f"{p} {v:.1f} %" for p, v in zip(
                    top["param"], top["share_pct"], strict=True))
                items.append(Conclusion(
                    f"{name} tolerances: {_and(list(top['param']))} carry "
                    f"{top['cumulative_pct'].iloc[-1]:.1f} % of the scatter of SumDelta after "
                    f"beta adjustment (eta^2 shares {shares}; {link})."))
        path = out / f"sobol_{name}.csv"
        if path.exists():
            sob = _csv(path)
            adj = sob[sob["case"] == "adjusted_beta"].sort_values("ST", ascending=False).head(2)
            items.append(Conclusion(
                f"{name} tolerances, Sobol (beta adjusted): largest total indices "
                + ", ".join(f"{r.param} ST = {r.ST:.3f} +/- {r.ST_conf:.3f}"
                            for r in adj.itertuples()) + f" ([sobol_{name}.md](sobol_{name}.md))."))
        path = out / f"sobol_{name}_second_order.csv"
        if path.exists():
            s2 = _csv(path)
            s2 = s2[s2["case"] == "adjusted_beta"].sort_values("S2", ascending=False)
            top, rest = s2.iloc[0], s2.iloc[1:]
            link = f"[sobol_{name}_second_order.md](sobol_{name}_second_order.md)"
            # the words follow the number: "most" only where the pair carries over half
            share = ("carries most of the variance" if top.S2 > 0.5 else
                     f"carries {top.S2:.0%} of the variance, the largest of any pair")
            items.append(Conclusion(
                f"{name} tolerances, second-order Sobol (beta adjusted): S2({top.param_i}, "
                f"{top.param_j}) = {top.S2:.3f} +/- {top.S2_conf:.3f}: the interaction of "
                f"{top.param_i} and {top.param_j} {share}; every other "
                f"pair is below {rest['S2'].abs().max():.3f} ({link})."))
    path = out / "largest_tolerances.csv"
    if path.exists():
        lt = _csv(path)
        lt["abs_mm"] = lt["largest_delta_mm"].abs()
        tight = lt.groupby("param")["abs_mm"].min().sort_values().head(3)
        items.append(Conclusion(
            "Alone, the tightest parts are " + ", ".join(f"{p} (+/-{v:.4f} mm)" for p, v in
                                                         tight.items())
            + ": the largest single deviation that keeps SumDelta(beta*) ≤ 10 µm "
            "([largest_tolerances.md](largest_tolerances.md))."))
    path = out / "allocation.csv"
    if path.exists():
        al = _csv(path).sort_values("tolerance_mm")
        items.append(Conclusion(
            "For 99.73 % after beta adjustment the allocation asks for "
            + ", ".join(f"{r.param} +/-{r.tolerance_mm:.4f} mm" for r in al.itertuples())
            + " ([allocation.md](allocation.md))."))
    return items


def adjustment_conclusions(out: Path, sets: list[str]) -> list[Conclusion]:
    items = []
    mc = _json(out / "montecarlo_summary.json")
    for name in sets:
        if name not in mc:
            continue
        s = mc[name]
        c = s["counts"]["adjusted_beta"]
        # "yields" is the shared Monte-Carlo JSON; yield_*_beta the tables made before it
        fixed, adjusted = (s["yields"]["fixed_beta"], s["yields"]["adjusted_beta"]) if "yields" \
            in s else (s["yield_fixed_beta"], s["yield_adjusted_beta"])
        items.append(Conclusion(
            f"{name} tolerances, {s['n']} machines: adjusting beta per machine takes the yield "
            f"from {fixed:.1%} (beta fixed at the nominal beta*) to "
            f"{adjusted:.1%} (ok {c['ok']} + out of spec {c['out_of_spec']} + "
            f"failed {c['failed']} = {c['n']}; [montecarlo_{name}.md](montecarlo_{name}.md))."))
    path = out / "strategies.csv"
    if path.exists():
        st = _csv(path)
        for name, g in st.groupby("tolerances", sort=False):
            # the best a fitter can do: not an idealised row (every compensator set exactly)
            real = g[~g["strategy"].str.endswith(" exact")]
            best = (real if len(real) else g).sort_values("yield", ascending=False).iloc[0]
            parts = [f"{s} {y:.1%}" for s, y in zip(g["strategy"], g["yield"], strict=True)]
            items.append(Conclusion(
                f"{name} tolerances, {int(g['n'].iloc[0])} machines (the same in every row): "
                f"{'; '.join(parts)}. Best: {best.strategy} ({best['yield']:.1%}, 95 % interval "
                f"{best.yield_ci_low:.1%} ... {best.yield_ci_high:.1%}; "
                "[strategies.md](strategies.md))."))
    path = out / "ppm.csv"
    if path.exists():
        ppm = _csv(path)
        for r in ppm[ppm["tolerance set"] == "allocated"].itertuples():
            items.append(Conclusion(f"Allocated tolerances, {r.strategy}: {r.statement} "
                                    "([ppm.md](ppm.md))."))
    return items


def clearance_conclusions(out: Path) -> list[Conclusion]:
    """The pins' share and the guide fit that keeps 95 % of machines running, per tolerance set
    and strategy (needle_208_clearances.py's tables)."""
    items = []
    path = out / "clearance_share.csv"
    if path.exists():
        share = _csv(path)
        for name, rows in share.groupby("tolerances", sort=False):
            r = rows.set_index("case")
            items.append(Conclusion(
                f"{name} tolerances, H7/g6 on the seven 8 mm pins, beta adjusted: SumDelta <= "
                f"10 µm on {r.loc['links', 'yield']:.1%} of machines with ideal pins, "
                f"{r.loc['both', 'yield']:.1%} with the journals random in their clearance; the "
                f"pins alone give {r.loc['pins', 'variance_share']:.0%} of the variance, the "
                f"links alone {r.loc['links', 'variance_share']:.0%} "
                "([clearances.md](clearances.md))."))
    path = out / "clearance_guide.csv"
    if path.exists():
        guide = _csv(path)
        words = "; ".join(
            f"{r.tolerances}, {'no adjustment' if r.strategy == 'none' else r.strategy}: "
            f"{'no fit rated' if r.tightest_fit_95pct_run == 'none' else r.tightest_fit_95pct_run}"
            for r in guide.itertuples())
        items.append(Conclusion(
            "Tightest ISO 286 guide fit (8 mm rod, assumed; H6/h5 to H11/c11 rated) with which "
            f"95 % of machines run without binding, per tolerance set and strategy: {words} "
            "([clearances.md](clearances.md))."))
    return items


def nominal_conclusion(out: Path) -> list[Conclusion]:
    path = out / "nominal.csv"
    if not path.exists():
        return []
    nominal = _csv(path).set_index("quantity")["value"]
    return [Conclusion(
        f"Nominal: beta* = {nominal['beta* (deg)']:.3f} deg, SumDelta = "
        f"{nominal['SumDelta at beta* (um)']:.3f} µm, SumDelta ≤ 10 µm for beta in "
        f"{nominal['window SumDelta <= 10 um, low (deg)']:.2f} ... "
        f"{nominal['window SumDelta <= 10 um, high (deg)']:.2f} deg, stroke "
        f"{nominal['stroke (mm)']:.2f} mm ([nominal.md](nominal.md)).")]


# (heading, tables, figures with captions); SET stands for each tolerance set of the run
LAYOUT = [
    ("Nominal machine", ["nominal", "sum_delta_vs_beta", "deviation"],
     [("deviation", "d(phi) at beta* and at both ends of the window; sign convention and limit "
       "on the axes"), ("sum_delta_vs_beta", "SumDelta against beta, guide fixed")]),
    ("Frames", ["frames", "calibration"],
     [("frames", "Scan, Sobol and largest tolerance on every named frame")]),
    ("Scans, SET tolerances", ["scan_SET", "scan_SET_shift+50um", "scan_SET_shift-50um",
                               "worst_case_SET"],
     [("scan_SET_deviation", "d(phi) at each tolerance limit with beta re-optimised; each "
       "curve's SumDelta in its legend")]),
    ("Monte-Carlo, SET tolerances", ["montecarlo_SET", "montecarlo_SET_pareto"],
     [("montecarlo_SET", "SumDelta with beta fixed and adjusted (overflow and failed machines "
       "counted), beta* per machine (machines at a search bound in red)")]),
    ("Sobol, SET tolerances", ["sobol_SET", "sobol_SET_second_order", "sobol_SET_convergence"],
     [("sobol_SET", "First-order and total Sobol indices with 95 % intervals")]),
    ("Tolerance limits and allocation", ["largest_tolerances", "allocation", "guides"], []),
    # studies/least_cost_allocation.py (not in make report: about 10 min of CPU per strategy)
    ("Least-cost allocation", ["allocation_cost_summary", "allocation_cost"], []),
    ("Adjustment strategies", ["strategies", "strategies_setting_error",
                               "strategies_SET_failures"],
     [("strategies_yield", "Yield by adjustment strategy"),
      ("strategies_setting_error", "Yield of beta + shift + angle against the guide angle's "
       "setting error (default sd 0.01 deg dotted)"),
      ("strategies_SET_beta_shift_beta_hist", "beta setting, beta + shift (SET)"),
      ("strategies_SET_beta_shift_guide_shift_um_hist", "guide shift, beta + shift (SET)"),
      ("strategies_SET_all_beta_hist", "beta setting, all compensators (SET)"),
      ("strategies_SET_all_guide_shift_um_hist", "guide shift, all compensators (SET)"),
      ("strategies_SET_all_guide_angle_hist", "guide angle, all compensators (SET)"),
      ("strategies_SET_all_CD_hist", "CD setting, all compensators (SET)")]),
    ("Failures per million", ["ppm", "ppm_bruteforce", "ppm_exceedance", "ppm_failing_machines"],
     [("ppm_exceedance", "Exceedance of SumDelta")]),
    ("Tolerances as a joint distribution", ["joint_correlation", "joint_relation",
                                            "joint_selective"], []),
    ("Joint clearances", ["clearances"], []),
]


def build_sections(out: Path, sets: list[str]) -> tuple[list[Section], list[str]]:
    """The report's sections and the files the layout names that this run did not write
    (listed in the provenance)."""
    sections, missing = [], []

    def each(text: str, names: list[str]) -> list[str]:
        return [text.replace("SET", n) for n in names] if "SET" in text else [text]

    for heading, tables, figures in LAYOUT:
        # a heading with SET gives one section per set; otherwise the section lists every set's
        for names in ([[n] for n in sets] if "SET" in heading else [sets]):
            md, figs = [], []
            for t in (x for table in tables for x in each(table, names)):
                if (out / f"{t}.md").exists():
                    md.append((t, (out / f"{t}.md").read_text()))
                else:
                    missing.append(f"{t}.md")
            for stem_pattern, caption_pattern in figures:
                for n in (names if "SET" in stem_pattern else names[:1]):
                    stem = stem_pattern.replace("SET", n)
                    path = figure_file(out, stem)
                    if path is None:
                        missing.append(f"{stem}.png")
                        continue
                    figs.append(Figure(path.stem, caption_pattern.replace("SET", n),
                                       path.read_bytes(), path.suffix.lstrip(".")))
            title = heading.replace("SET", names[0])
            if md or figs:
                sections.append(Section(title, tuple(md), tuple(figs)))
    return sections, missing


def provenance(out: Path, sets: list[str], missing: list[str]) -> dict:
    run = _json(out / "run.json")
    inp = run.get("inputs", {})
    prov = {"revision": run.get("git_revision", "unknown"),
            "sewtol": run.get("sewtol_version", "unknown"),
            "frame": DEFAULT_FRAME, "seed": inp.get("seed", "unknown"),
            "Monte-Carlo machines n": inp.get("n_mc", "unknown"),
            "Sobol base samples N": inp.get("n_sobol", "unknown")}
    for name, body in inp.get("tolerance_sets", {}).items():
        prov[f"tolerance set {name}"] = "; ".join(
            f"{p} {v['lower']:+g}/{v['upper']:+g} mm {v['dist']}" for p, v in body.items())
    for label, path in (("tolerance studies", "run.json"), ("strategies", "strategies_run.json"),
                        ("failures per million", "ppm_run.json")):
        r = _json(out / path)
        if r:
            t0 = datetime.fromisoformat(r["started_utc"])
            t1 = datetime.fromisoformat(r["finished_utc"])
            prov[f"run time, {label}"] = (f"{(t1 - t0).total_seconds():.0f} s ({r['started_utc']}"
                                          f" ... {r['finished_utc']}), command "
                                          f"`{' '.join(r['command_line'])}`")
    if run:
        prov["libraries"] = ", ".join(f"{k} {v}" for k, v in run.get("libraries", {}).items())
        prov["python"] = run.get("python", "")
    prov["not written by this run"] = ", ".join(missing) or "nothing"
    return prov


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports")
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"
    run = _json(out / "run.json")
    sets = set_names(run)
    frames_md = (out / "frames.md").read_text() if (out / "frames.md").exists() else ""

    conclusions = {
        "What holds in every frame, and what depends on the frame":
            robust_conclusions(frames_md) or [Conclusion(
                "not assessed in this run (frames.md is written by needle_208_frames.py)")],
        "Which tolerances to tighten": tighten_conclusions(out, sets),
        "What adjustment buys": adjustment_conclusions(out, sets),
        "Joint clearances": clearance_conclusions(out) or [Conclusion(
            "not assessed in this run (clearances.md is written by needle_208_clearances.py)")],
        f"Nominal machine (frame {DEFAULT_FRAME})": nominal_conclusion(out),
    }
    intro = ("The frame of the 208 (the positions of the upper shaft A and the rear rocker pivot "
             "D, the dyad branches, the sense of beta) is not published. Every figure below "
             f"comes from the default reconstruction `{DEFAULT_FRAME}`; the Frames section "
             "repeats the studies on every named frame. Read the conclusions in that light. "
             "Criterion everywhere: SumDelta = Delta+ + Delta- ≤ 10 µm, guide fixed.")
    sections, missing = build_sections(out, sets)
    prov = provenance(out, sets, missing)

    report = Report("208 needle drive: reports", intro, conclusions, sections, prov)
    write_text_atomic(out / "index.md", markdown_index(report))
    write_text_atomic(out / "report.html", render(report))
    print(f"wrote {out / 'index.md'} and {out / 'report.html'}")


if __name__ == "__main__":
    main()
