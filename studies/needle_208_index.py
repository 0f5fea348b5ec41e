"""The index of reports/needle_208/: index.md (Markdown, figures embedded as images) and
report.html (one self-contained page: three headline lines first (the yield, one
recommendation, how far it depends on the frame), then the conclusions in words, every table
and figure, the provenance). Reads only what the other study scripts wrote (run it last); every number in the
conclusions comes from those tables.

    python studies/needle_208_index.py [--out reports]
"""

from __future__ import annotations

import json
import re
from datetime import datetime
from pathlib import Path

import pandas as pd

from sewtol.intervals import clopper_pearson
from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.compensators import STRATEGY_ROWS as STRATEGY_COMPENSATORS
from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME
from sewtol.reports import plots
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


def set_params(run: dict) -> dict[str, list[str]]:
    """Each set's toleranced parameters (only those are ranked for the set)."""
    return {k: list(v) for k, v in run.get("inputs", {}).get("tolerance_sets", {}).items()}


# the machine as designed: beta is the one adjustment the 208 makes on each machine (the design
# note: "only beta is adjusted on each machine"); the headline's yield is this strategy's
DESIGNED_STRATEGY = "beta"
# the frames study's labels (needle_208_frames.py)
FRAME_LABELS = ("holds in every frame", "fails in every frame", "frame-dependent")
COMPENSATOR_WORDS = {"beta": "beta", "guide_shift_um": "guide shift", "guide_angle": "guide angle",
                     "CD": "CD (sliding head)"}
IDEAL_SUFFIX = " exact"  # strategies.md's idealised rows: every compensator set exactly


def frame_conclusions(frames_md: str) -> list[Conclusion]:
    """frames.md's statements with their labels (holds in / fails in every frame, or
    frame-dependent)."""
    out = []
    for line in _section(frames_md, "What holds in every frame"):
        text = line.lstrip("- ").strip()
        for verdict in FRAME_LABELS:
            tag = f"**{verdict}**: "
            if text.startswith(tag):
                out.append(Conclusion(text[len(tag):], verdict))
                break
        else:
            out.append(Conclusion(text))
    return out


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def span(lo: float, hi: float) -> str:
    return f"{100 * lo:.1f}–{100 * hi:.1f} %"


def strategy_frames(out: Path) -> pd.DataFrame | None:
    """Every strategy yield on every frame: strategies.csv (the default frame) and
    strategies_frames.csv (the others, needle_208_strategies_frames.py); None without the first."""
    path = out / "strategies.csv"
    if not path.exists():
        return None
    st = _csv(path).assign(frame=DEFAULT_FRAME)
    other = out / "strategies_frames.csv"
    if other.exists():
        st = pd.concat([st, _csv(other)], ignore_index=True)
    return st


def frame_ranges(st: pd.DataFrame) -> pd.DataFrame:
    """Per set and strategy: the yield on the default frame (with its interval and n) and the
    lowest and highest yield over every frame computed, with the frames counted."""
    rows = []
    for (name, strategy), g in st.groupby(["tolerances", "strategy"], sort=False):
        if not (g["frame"] == DEFAULT_FRAME).any():  # a set the default frame's table lacks
            continue
        home = g[g["frame"] == DEFAULT_FRAME].iloc[0]
        others = g[g["frame"] != DEFAULT_FRAME]
        rows.append({"tolerances": name, "strategy": strategy, "yield": home["yield"],
                     "low": home.yield_ci_low, "high": home.yield_ci_high, "n": int(home.n),
                     "setting_error": home.setting_error, "resolution": home.resolution,
                     "frames": len(g), "min": g["yield"].min(), "max": g["yield"].max(),
                     "worst_frame": g.sort_values("yield").iloc[0].frame,
                     "n_other": int(others.n.max()) if len(others) else 0,
                     "half_width_other": float(((others.yield_ci_high - others.yield_ci_low) / 2)
                                               .max()) if len(others) else float("nan")})
    return pd.DataFrame(rows)


def recommend(ranges: pd.DataFrame, name: str) -> pd.Series:
    """The one adjustment to recommend for set `name`: of the strategies a fitter can do (not an
    idealised row), the one with the highest yield on its worst frame (the frame is not
    published); ties go to the higher yield on the default frame."""
    g = ranges[(ranges.tolerances == name) & ~ranges.strategy.str.endswith(IDEAL_SUFFIX)]
    return g.sort_values(["min", "yield"], ascending=False).iloc[0]


def _precision(row) -> str:
    """The row's setting precision in words, from its setting_error and resolution columns
    (each "NAME what" joined by "; ", or "none": set exactly)."""
    words = []
    for column, what in (("setting_error", "error"), ("resolution", "resolution")):
        text = "none" if pd.isna(row[column]) else str(row[column])
        for part in ([] if text == "none" else text.split("; ")):
            name, _, rest = part.partition(" ")
            words.append(f"the {COMPENSATOR_WORDS.get(name, name)} set with a {rest} {what}")
    return (_and(words) + ", the others set exactly") if words else "every compensator set exactly"


def _best_everywhere(st: pd.DataFrame, name: str, strategy: str) -> tuple[bool, list[str]]:
    """Whether `strategy` has the highest yield of the realistic rows on every frame."""
    real = st[(st.tolerances == name) & ~st.strategy.str.endswith(IDEAL_SUFFIX)]
    frames, best = [], []
    for frame, g in real.groupby("frame", sort=False):
        frames.append(frame)
        best.append(g.sort_values("yield", ascending=False).iloc[0].strategy == strategy)
    return all(best), frames


TYPICAL_READING_SD_UM = 3.0  # a dial gauge graduated in 0.01 mm (docs/adjustment.md)


def _reading_clause(out: Path, name: str, strategy: str) -> str:
    """What the yield becomes when the compensators are set from a reading of the needle path
    with a dial gauge's typical error, from strategies_measurement_error.csv (the recommended
    strategy's row, or the largest strategy the measurement study ran); empty without it."""
    path = out / "strategies_measurement_error.csv"
    if not path.exists():
        return ""
    m = _csv(path)
    m = m[(m.tolerances == name) & (m.measurement_sd_um == TYPICAL_READING_SD_UM)
          & ~m.strategy.str.endswith(IDEAL_SUFFIX)]
    if m.empty:
        return ""
    row = m[m.strategy == strategy]
    row = (row if not row.empty else m.loc[[m.strategy.str.len().idxmax()]]).iloc[0]
    return (f" These settings are made from the true deviation; made from a reading of the "
            f"needle path with a {TYPICAL_READING_SD_UM:g} µm sd (a 0.01 mm dial gauge), "
            f"{row.strategy} gives {pct(row['yield'])} (95 % interval "
            f"{span(row.yield_ci_low, row.yield_ci_high)}, n = {int(row.n)}; "
            "[strategies_measurement_error.md](strategies_measurement_error.md)).")


def headline(out: Path, sets: list[str]) -> tuple[tuple[str, str], ...]:
    """The report's first three lines: the yield of the designed machine, the one adjustment to
    add (with the yield it buys and its setting precision) and how far that depends on the
    frame. Empty when this run wrote no strategies table."""
    st = strategy_frames(out)
    if st is None:
        return ()
    ranges = frame_ranges(st)
    name = sets[0] if sets[0] in set(ranges.tolerances) else ranges.tolerances.iloc[0]
    g = ranges[ranges.tolerances == name].set_index("strategy")
    now = g.loc[DESIGNED_STRATEGY]
    rec = recommend(ranges, name)
    added = [c for c in STRATEGY_COMPENSATORS.get(rec.strategy, ())
             if c not in STRATEGY_COMPENSATORS[DESIGNED_STRATEGY]]
    frames_n = int(g["frames"].max())
    yield_line = (f"{pct(now['yield'])} of machines meet SumDelta ≤ 10 µm (95 % interval "
                  f"{span(now.low, now.high)}, n = {now.n}; {name} tolerances, beta adjusted "
                  f"per machine as designed, frame {DEFAULT_FRAME}).")
    if not added:
        do_line = (f"keep {DESIGNED_STRATEGY}: no strategy a fitter can do beats it on its "
                   "worst frame ([strategies.md](strategies.md)).")
    else:
        words = _and([COMPENSATOR_WORDS[c] for c in added])
        do_line = (f"add the {words} adjustment{'s' if len(added) > 1 else ''} (strategy "
                   f"{rec.strategy}): {pct(now['yield'])} → {pct(rec['yield'])} (95 % interval "
                   f"{span(rec.low, rec.high)}, n = {rec.n}) with {_precision(rec)}.")
        ideal = [s for s in g.index if s.endswith(IDEAL_SUFFIX)]
        for s in ideal:
            real = s.removesuffix(IDEAL_SUFFIX)
            if real in g.index:
                do_line += (f" {real} gives {pct(g.loc[real, 'yield'])} at that precision, "
                            f"{pct(g.loc[s, 'yield'])} only with every compensator set exactly "
                            "(an idealisation).")
        do_line += _reading_clause(out, name, rec.strategy)
    if frames_n < 2:
        frame_line = (f"not assessed: this run computed the strategies on {DEFAULT_FRAME} only "
                      "(needle_208_strategies_frames.py computes the others).")
    else:
        everywhere, names = _best_everywhere(st, name, rec.strategy)
        verdict = ("holds in every frame" if everywhere else "frame-dependent")
        n_other = int(g["n_other"].max())
        frame_line = (
            f"the recommendation {verdict} ({rec.strategy} is the best realistic strategy "
            f"{'on each of ' + _and(names) if everywhere else 'on some frames only'}); the "
            f"yields are frame-dependent: {rec.strategy} {span(rec['min'], rec['max'])}, "
            f"{DESIGNED_STRATEGY} {span(now['min'], now['max'])} over the {frames_n} named frames "
            f"(n = {n_other} on each other frame; every strategy's range under What adjustment "
            "buys).")
    return (("Yield", yield_line), ("What to do", do_line), ("Frame", frame_line))


def _evidence(out: Path, name: str, params: list[str]) -> tuple[str, list[str]]:
    """One set's rankings in one line, its parameters only, and the two with the largest total
    Sobol index (eta^2 where there is no Sobol table)."""
    words, links, top = [], [], []
    path = out / f"montecarlo_{name}_pareto.csv"
    if path.exists():
        par = _csv(path)
        tol = par[par["param"].isin(params)]
        lead = tol.sort_values(tol.columns[1] if "variance_pct" not in tol else "variance_pct",
                               ascending=False).head(2)
        key = "variance_pct" if "variance_pct" in par else "share_pct"
        words.append("eta^2 " + ", ".join(f"{r.param} {getattr(r, key):.1f} %"
                                          for r in lead.itertuples()))
        if "variance_pct" in par:
            rest = 100 - float(tol["variance_pct"].sum())
            if rest > 0:
                words[-1] += f" (the other {rest:.1f} % is interaction)"
        top = list(lead["param"])
        links.append(f"[montecarlo_{name}_pareto.md](montecarlo_{name}_pareto.md)")
    path = out / f"sobol_{name}.csv"
    if path.exists():
        sob = _csv(path)
        adj = sob[(sob["case"] == "adjusted_beta") & sob["param"].isin(params)]
        adj = adj.sort_values("ST", ascending=False).head(2)
        words.append("Sobol ST " + ", ".join(f"{r.param} {r.ST:.3f} ± {r.ST_conf:.3f}"
                                            for r in adj.itertuples()))
        top = list(adj["param"])
        links.append(f"[sobol_{name}.md](sobol_{name}.md)")
    path = out / f"sobol_{name}_second_order.csv"
    if path.exists():
        s2 = _csv(path)
        s2 = s2[(s2["case"] == "adjusted_beta") & s2["param_i"].isin(params)
                & s2["param_j"].isin(params)].sort_values("S2", ascending=False)
        if len(s2):
            r = s2.iloc[0]
            words.append(f"S2({r.param_i}, {r.param_j}) = {r.S2:.3f} ± {r.S2_conf:.3f}")
            links.append(f"[sobol_{name}_second_order.md](sobol_{name}_second_order.md)")
    path = out / "largest_tolerances.csv"
    if path.exists():
        lt = _csv(path)
        lt = lt[lt["param"].isin(params)].assign(abs_mm=lambda f: f["largest_delta_mm"].abs())
        tight = lt.groupby("param")["abs_mm"].min().sort_values().head(3)
        words.append("alone, the tightest " + ", ".join(f"{p} ±{v:.4f} mm"
                                                        for p, v in tight.items()))
        links.append("[largest_tolerances.md](largest_tolerances.md)")
    text = (f"{name} tolerances ({', '.join(params)}; beta adjusted): " + "; ".join(words)
            + " (" + ", ".join(links) + ").")
    return text, top


def _allocation(out: Path) -> dict | None:
    """allocation.md's tolerances and the yield its Monte-Carlo check reached (k of n)."""
    path = out / "allocation.csv"
    if not path.exists():
        return None
    md = (out / "allocation.md").read_text() if (out / "allocation.md").exists() else ""
    got = re.search(r"achieved yield: ([0-9.]+)", md)
    n = re.search(r"yield check: Monte-Carlo, (\d+) machines", md)
    ref = re.search(r"reference set: (\w+)", md)
    al = _csv(path).sort_values("tolerance_mm")
    return {"table": al, "yield": float(got.group(1)) if got else None,
            "n": int(n.group(1)) if n else None, "reference": ref.group(1) if ref else None}


def tighten_conclusions(out: Path, sets: list[str], params: dict[str, list[str]]
                        ) -> list[Conclusion]:
    """Which tolerances to tighten: per set, the rankings of its own tolerances in one line;
    then one recommendation: the pair that leads the sets' total Sobol indices, with the
    allocation that tightens them and the yield it reached."""
    items, tops = [], []
    for name in sets:
        if not params.get(name):
            continue
        text, top = _evidence(out, name, params[name])
        items.append(Conclusion(text))
        tops.append(top)
    al = _allocation(out)
    lead = [p for p in (tops[0] if tops else []) if all(p in t for t in tops)]
    if lead:
        rec = (f"**Recommendation**: tighten {_and(lead)} together (they lead the total Sobol "
               f"indices of {'every set' if len(tops) > 1 else 'the set'} and act together)")
        if al is not None:
            t = al["table"].set_index("param")["tolerance_mm"]
            asks = ", ".join(f"{p} ±{t[p]:.4f} mm" for p in lead if p in t)
            others = ", ".join(f"{p} ±{v:.4f} mm" for p, v in t.items() if p not in lead)
            rec += (f": for 99.73 % after beta adjustment the allocation ("
                    f"{al['reference'] or 'reference'} set's tolerances) asks {asks}, with "
                    f"{others}")
            if al["yield"] is not None and al["n"]:
                k = int(round(al["yield"] * al["n"]))
                lo, hi = clopper_pearson(k, al["n"])
                rec += (f"; it reached {pct(al['yield'])} (95 % interval {span(lo, hi)}, "
                        f"n = {al['n']}, frame {DEFAULT_FRAME}, ideal pins)")
        items.append(Conclusion(rec + " ([allocation.md](allocation.md))."))
    return items


def adjustment_conclusions(out: Path, sets: list[str]) -> list[Conclusion]:
    """Every strategy yield with its range over the named frames, per set; the allocated set's
    failures per million (default frame only)."""
    items = []
    st = strategy_frames(out)
    if st is not None:
        ranges = frame_ranges(st)
        for name, g in ranges.groupby("tolerances", sort=False):
            frames_n = int(g["frames"].max())
            parts = []
            for _, r in g.iterrows():
                text = f"{r.strategy} {pct(r['yield'])}"
                if frames_n > 1:
                    text += f" (frames {span(r['min'], r['max'])})"
                if r.strategy.endswith(IDEAL_SUFFIX):
                    text += " [idealisation: set exactly]"
                parts.append(text)
            best = recommend(ranges, name)
            where = (f"{int(g.n.iloc[0])} machines on {DEFAULT_FRAME}, {int(g.n_other.max())} on "
                     f"each of the other {frames_n - 1} frames (95 % intervals ± "
                     f"{100 * g.half_width_other.max():.1f} points at most there)"
                     if frames_n > 1 else f"{int(g.n.iloc[0])} machines on {DEFAULT_FRAME} only")
            items.append(Conclusion(
                f"{name} tolerances, {where}: {'; '.join(parts)}. Best on its worst frame: "
                f"{best.strategy} ({pct(best['yield'])}, 95 % interval "
                f"{span(best.low, best.high)}; worst frame {best.worst_frame} "
                f"{pct(best['min'])}) ([strategies.md](strategies.md)"
                + (", [strategies_frames.md](strategies_frames.md)" if frames_n > 1 else "")
                + ")."))
    path = out / "ppm.csv"
    if path.exists():
        ppm = _csv(path)
        for r in ppm[ppm["tolerance set"] == "allocated"].itertuples():
            items.append(Conclusion(f"Allocated tolerances, {r.strategy}, frame {DEFAULT_FRAME} "
                                    f"only: {r.statement} ([ppm.md](ppm.md))."))
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
    ("Adjustment strategies", ["strategies", "strategies_frames", "strategies_setting_error",
                               "strategies_measurement_error", "strategies_SET_failures"],
     [("strategies_yield", "Yield by adjustment strategy"),
      ("strategies_setting_error", "Yield of beta + shift + angle against the guide angle's "
       "setting error (default sd 0.01 deg dotted)"),
      ("strategies_measurement_error", "Yield against the error of the reading the "
       "compensators are set from"),
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
    ("Housing tolerances", ["housing_share"], []),
    # studies/needle_208_refine.py (not in make report: its searches take 20-45 min)
    ("Design refinement", ["refine_summary"],
     [("refine_linkage", "The refined linkages drawn over today's (what was held fixed: the "
       "main shaft F, the guide's point N1, the branches)"),
      ("refine_deviation", "d(phi) of today's design and of the refined designs"),
      ("refine_pareto", "Robust design: nominal SumDelta against the yield with beta alone "
       "(non-dominated designs)")]),
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
                        ("strategies on the other frames", "strategies_frames_run.json"),
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
    ap = plots.study_parser(__doc__, seed=None)
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"
    run = _json(out / "run.json")
    sets = set_names(run)
    frames_md = (out / "frames.md").read_text() if (out / "frames.md").exists() else ""

    conclusions = {
        "What adjustment buys (range over the named frames beside every yield)":
            adjustment_conclusions(out, sets),
        "Which tolerances to tighten": tighten_conclusions(out, sets, set_params(run)),
        "What holds in every frame, what fails in every frame, what depends on the frame":
            frame_conclusions(frames_md) or [Conclusion(
                "not assessed in this run (frames.md is written by needle_208_frames.py)")],
        "Joint clearances": clearance_conclusions(out) or [Conclusion(
            "not assessed in this run (clearances.md is written by needle_208_clearances.py)")],
        "Housing tolerances": [Conclusion(
            f"{_json(out / 'housing_share.json')['headline']} "
            "([housing_share.md](housing_share.md))")]
            if _json(out / "housing_share.json").get("headline") else [Conclusion(
            "not assessed in this run (housing_share.md is written by needle_208_housing.py)")],
        f"Nominal machine (frame {DEFAULT_FRAME})": nominal_conclusion(out),
    }
    intro = ("The frame of the 208 (the positions of the upper shaft A and the rear rocker pivot "
             "D, the dyad branches, the sense of beta) is not published. A figure comes from the "
             f"default reconstruction `{DEFAULT_FRAME}` unless the range over the named frames "
             "stands beside it; the Frames section repeats the studies on every named frame. "
             "Criterion everywhere: SumDelta = Delta+ + Delta- ≤ 10 µm; the guide is fixed "
             "unless a strategy adjusts it.")
    sections, missing = build_sections(out, sets)
    prov = provenance(out, sets, missing)

    report = Report("208 needle drive: reports", intro, conclusions, sections, prov,
                    headline(out, sets))
    write_text_atomic(out / "index.md", markdown_index(report))
    write_text_atomic(out / "report.html", render(report))
    print(f"wrote {out / 'index.md'} and {out / 'report.html'}")


if __name__ == "__main__":
    main()
