"""Nominal refinement of the 208 needle drive (sewtol.studies.refine), both variants the design
question asks for, the smallest set of links that cuts SumDelta threefold, and the beta-only
yield of each design on the base tolerance set.

    python studies/needle_208_refine.py --out DIR [--seed 1] [--designs FILE.json]
    python studies/needle_208_refine.py --out DIR --phase housing_kept   # one phase, then
    python studies/needle_208_refine.py --out DIR --phase write --designs FILE.json

Writes DIR/refine.md (the tables and the confirmation in words), DIR/refine.json,
DIR/deviation_before_after.png and, with --designs, the refined designs with their claimed
figures (the tests re-evaluate them: tests/data/refined_needle_208.json).

Variants (both hold the stroke within +-0.1 mm of today's and every transmission angle >= 40 deg
over the whole turn):
- housing kept: only the seven links change (+-10 %), today's guide line stays exactly where it
  is (no shift), beta is set per machine as today;
- guide refitted: the links, the pivots A and D (+-2 mm) and the guide's inclination (+-0.5 deg)
  change, and the guide is shifted to its best place (beta and the guide shift adjusted).

The smallest set: greedy forward selection over the links (housing kept), each candidate set
searched by one short differential evolution with a minimax polish of its best and of today's
design; the smallest size reached is then confirmed by searching every set one link smaller.

Robust design (sewtol.studies.robust): the yield on the base set with beta alone (and beta +
guide shift) maximised over the nominal design (links, the angle CBE, the pivots, the guide's
inclination and its place), common random numbers; a Pareto front of nominal SumDelta, yield
and stroke error from every design evaluated plus an epsilon-constraint sweep; each best design
re-checked with fresh machines (another seed).

Not in `make report`: the searches take tens of minutes of CPU. Each phase pickles its result
into --work; `--phase write` turns them into reports/needle_208/refine_* (seconds).
"""

from __future__ import annotations

import argparse
import itertools
import json
import pickle
import time
from pathlib import Path

import numpy as np
import pandas as pd

from sewtol.cli.run import load_mechanism
from sewtol.studies import refine as RF
from sewtol.studies import robust as RB

LINKS = ["LF", "LM", "AM", "AB", "BC", "BE", "CD"]
PIVOTS = ["Ax", "Ay", "Dx", "Dy"]
STROKE_TOL_UM = 100.0
YIELD_N = 1000
KEPT = {"beta": (10.0, 35.0)}  # today's guide line stays exactly: beta alone is set
# the guide bore moves with the refit: its shift is the guide's best place, +-2 mm as a pivot
REFIT = {"beta": (10.0, 35.0), "guide_shift_um": (-2000.0, 2000.0)}


def constraints(mech, adjust):
    return RF.default_constraints(mech) + [RF.keep(mech, "stroke_um", STROKE_TOL_UM, adjust)]


def beta_only_yield(values: dict, n: int, seed: int) -> dict:
    """Yield of the design's machines on the base set with beta set per machine (10..35 deg),
    SumDelta <= 10 um, the guide where the design puts it (sewtol.montecarlo)."""
    import sewtol
    from sewtol.mechanisms import params as P

    machine = sewtol.Needle208(**{k: values[k] for k in P.field_names(sewtol.Needle208)})
    res = sewtol.montecarlo(machine, "base", n=n, seed=seed)
    frame = res.summary_frame()
    row = frame[frame["case"].str.contains("adjust")].iloc[0].to_dict()
    return {k: row[k] for k in ("case", "n", "ok", "yield", "yield_ci_low", "yield_ci_high")
            if k in row}


def _subset_search(mech, subset, seed):
    """One set of links, housing kept: a short differential evolution, then the minimax polish
    of its best and of today's design (sewtol.studies.refine)."""
    cons = constraints(mech, KEPT)
    return RF.refine(mech, list(subset), adjust=KEPT, constraints=cons, seed=seed, restarts=1,
                     popsize=8, maxiter=40, polish="minimax", local_search=True)


def smallest_set(mech, target_um: float, seed: int, log, exhaustive_max: int = 3):
    """Greedy forward selection: add the link whose set reaches the lowest SumDelta, until
    target_um; then every set of the size below the one found (up to exhaustive_max links) is
    searched too, to confirm that none reaches the target. Returns (the set, its result, the
    rows of every set searched)."""
    rows, chosen, found, res_found = [], [], None, None
    seen = {}

    def run(subset, stage):
        key = tuple(sorted(subset))
        if key not in seen:
            t = time.perf_counter()
            r = _subset_search(mech, key, seed)
            seen[key] = r
            rows.append({"stage": stage, "size": len(key), "parameters": ",".join(key),
                         "SumDelta_um": r.objective_after, "ratio": r.ratio,
                         "reaches_3x": r.objective_after <= target_um,
                         "active_bounds": "; ".join(r.active_bounds),
                         "active_constraints": "; ".join(r.active_constraints),
                         "seconds": time.perf_counter() - t})
            log(f"  {stage} {','.join(key)}: {r.objective_after:.4f} um")
        return seen[key]

    while len(chosen) < len(LINKS):
        trial = {p: run(chosen + [p], "greedy") for p in LINKS if p not in chosen}
        p_best = min(trial, key=lambda p: trial[p].objective_after)
        chosen = chosen + [p_best]
        if trial[p_best].objective_after <= target_um:
            found, res_found = chosen, trial[p_best]
            break
    if found and len(found) - 1 <= exhaustive_max:
        for subset in itertools.combinations(LINKS, len(found) - 1):
            run(list(subset), "exhaustive")
        # a smaller set that reached the target would be the answer
        for subset in itertools.combinations(LINKS, len(found) - 1):
            r = seen[tuple(sorted(subset))]
            if r.objective_after <= target_um:
                found, res_found = list(subset), r
                break
    return found, res_found, pd.DataFrame(rows)


ROBUST_N = 200  # machines per design in the search (common random numbers)
CHECK_N = 2000  # fresh machines (another seed) for each best design's yield
CBE_BOX_DEG = 5.0
ROBUST_LINKS = ["LF", "AB", "BC", "BE", "CD"]  # LM and AM act only through the swing, as LF


def robust_bounds(mech) -> dict:
    b = RF.default_bounds(mech, ROBUST_LINKS + PIVOTS + ["guide_angle"])
    cbe = mech.nominal_values()["CBE"]
    return {**b, "CBE": (cbe - CBE_BOX_DEG, cbe + CBE_BOX_DEG),
            "guide_shift_um": REFIT["guide_shift_um"]}


def robust_runs(mech, seed: int, log) -> dict:
    """The robust-design searches (sewtol.studies.robust): yield on the base set maximised
    with beta alone (two restarts), with beta + guide shift, and an epsilon-constraint sweep of
    the nominal SumDelta with a wider stroke band (+-1 mm) for the front."""
    base = mech.tolerance_sets["base"]
    bounds = robust_bounds(mech)
    stroke0 = RF.keep(mech, "stroke_um", STROKE_TOL_UM, ["beta"])
    today_stroke = 0.5 * (stroke0.lower + stroke0.upper)
    tight = RF.default_constraints(mech) + [stroke0]
    wide = RF.default_constraints(mech) + [RF.Constraint(
        "stroke_um", today_stroke - 1000.0, today_stroke + 1000.0, 1000.0,
        "stroke within +-1 mm of today's (the front's band)")]
    common = dict(nominal_adjust=["beta"], error_of=("stroke_um", today_stroke), n=ROBUST_N,
                  seed=seed, popsize=5)
    out = {}
    plan = [("beta", dict(adjust=["beta"], constraints=tight, restarts=2, maxiter=40)),
            ("beta_shift", dict(adjust=["beta", "guide_shift"], constraints=tight, restarts=1,
                                maxiter=30)),
            ("front_free", dict(adjust=["beta"], constraints=wide, restarts=1, maxiter=30))]
    for eps in (1.5, 3.0):
        plan.append((f"front_eps{eps:g}", dict(adjust=["beta"], constraints=wide, restarts=1,
                                               maxiter=25, nominal_limit=eps)))
    for name, kw in plan:
        t = time.perf_counter()
        out[name] = RB.robust(mech, bounds, base, **common, **kw)
        r = out[name]
        log(f"  robust {name}: yield {r.figures['yield'].tolist()} (today, robust), "
            f"{time.perf_counter() - t:.0f} s")
    return out


def _design_record(res) -> dict:
    return {"parameters": {k: float(v) for k, v in res.changed.items()},
            "today": res.before, "refined": res.after, "ratio": res.ratio,
            "adjust": {k: list(v) for k, v in res.options["adjust_boxes"].items()},
            "constraints": [{"output": c.output, "lower": c.lower, "upper": c.upper}
                            for c in res.constraints]}


def run_phase(phase: str, mech, seed: int, out: Path, log) -> None:
    """One phase into DIR/PHASE.pkl (phases run as separate processes: the machine is shared)."""
    base = mech.tolerance_sets["base"]
    t = time.perf_counter()
    if phase == "housing_kept":
        res = RF.refine(mech, LINKS, adjust=KEPT, constraints=constraints(mech, KEPT), seed=seed,
                        restarts=3, popsize=10, maxiter=150, polish="minimax", tolerances=base)
    elif phase == "guide_refitted":
        refit = {**dict.fromkeys(LINKS + PIVOTS), "guide_angle": None}
        res = RF.refine(mech, refit, adjust=REFIT, constraints=constraints(mech, REFIT),
                        seed=seed, restarts=4, popsize=8, maxiter=200, polish="minimax",
                        tolerances=base)
    elif phase == "smallest_set":
        today = RF.DesignProblem(mech, "SumDelta_um", {}, KEPT, (), True).outputs_at(
            mech.nominal_values(), [])["SumDelta_um"]
        found, res, subsets = smallest_set(mech, today / 3, seed, log)
        res = (res, subsets)
    elif phase == "robust":
        res = robust_runs(mech, seed, log)
    else:
        raise SystemExit(f"unknown phase {phase}")
    with open(out / f"{phase}.pkl", "wb") as fh:
        pickle.dump((res, time.perf_counter() - t), fh)


LINK_PAIRS = [("F", "L"), ("L", "M"), ("M", "A"), ("A", "B"), ("C", "B"), ("B", "E"),
              ("C", "D")]


def plot_linkage(mech, designs: dict, ax, q_deg: float = 90.0):
    """Links and joints of each design at crank angle q_deg, E's path and the guide line;
    today's in grey under the others."""
    q = np.radians(np.arange(0, 360, 0.5))
    styles = {"today": dict(color="0.55", lw=2.6, zorder=1)}
    colours = iter(["tab:red", "tab:blue", "tab:green", "tab:purple"])
    for name, values in designs.items():
        st = styles.get(name) or dict(color=next(colours), lw=1.2, zorder=2)
        v = {k: np.array([float(x)]) for k, x in values.items()}
        state = mech.state(v, np.array([np.radians(q_deg)]))
        pts = {k: complex(np.asarray(state.points[k].p).reshape(-1)[0])
               for k in ("F", "L", "M", "A", "B", "C", "D", "E")}
        for a, b in LINK_PAIRS:
            ax.plot([pts[a].real, pts[b].real], [pts[a].imag, pts[b].imag], **st)
        ax.plot([p.real for p in pts.values()], [p.imag for p in pts.values()], "o",
                ms=3.5, color=st["color"], zorder=st["zorder"] + 1)
        path = mech.state(v, q).points["E"].p.reshape(-1)
        ax.plot(path.real, path.imag, ls=":", color=st["color"], lw=1.0,
                label=f"{name} (E's path dotted)")
        a = np.radians(values["guide_angle"])
        n = np.array([np.cos(a), -np.sin(a)])
        g = np.array([values["guide_x"], values["guide_y"]]) + n * values["guide_shift_um"] * 1e-3
        u = np.array([np.sin(a), np.cos(a)])
        ends = np.array([g - 16 * u, g + 16 * u])
        ax.plot(ends[:, 0], ends[:, 1], ls="--", color=st["color"], lw=0.8)
        if name == "today":
            for k in ("F", "A", "D", "E", "B", "C", "M", "L"):
                ax.annotate(k, (pts[k].real, pts[k].imag), textcoords="offset points",
                            xytext=(4, 4), fontsize=8, color="0.3")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(loc="lower right", fontsize=7)
    return ax


def _md(frame, fmt=".4f") -> str:
    return frame.to_markdown(index=False, floatfmt=fmt)


def write(mech, work: Path, out: Path, seed: int, designs_file, no_yields: bool, log):
    """Turn the phases' pickles (work) into reports/needle_208/refine_* (out)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    results, timings, subsets, small, robust = {}, {}, None, None, {}
    for phase in ("housing_kept", "guide_refitted", "smallest_set", "robust"):
        if not (work / f"{phase}.pkl").exists():
            continue
        with open(work / f"{phase}.pkl", "rb") as fh:
            res, timings[phase] = pickle.load(fh)
        if phase == "smallest_set":
            small, subsets = res
        elif phase == "robust":
            robust = res
        else:
            results[phase] = res
    if small is not None:
        results["smallest_set"] = small
    first = next(iter(results.values()))
    today_um = first.objective_before
    start = first.start
    base = mech.tolerance_sets["base"]
    t = time.perf_counter()
    yields = {}
    if not no_yields:
        yields["today"] = beta_only_yield(start, YIELD_N, seed)
        for k, r in results.items():
            yields[k] = beta_only_yield(r.refined, YIELD_N, seed)
    # the robust designs: the yield again with fresh machines (another seed), and the AB, BE,
    # BC sensitivity (beta re-optimised) beside today's
    checks, sens = [], []
    check_seed = seed + 1000
    for name, r in robust.items():
        for label, design in (("today", r.start), (name, r.best)):
            if label == "today" and any(c["design"] == "today" and c["adjust"] ==
                                        "+".join(r.adjust) for c in checks):
                continue
            y = RB.yield_check(mech, design, base, r.adjust, r.objective, r.limit, CHECK_N,
                               check_seed)
            checks.append({"design": label, "adjust": "+".join(r.adjust), **y})
    for label, design in [("today", start)] + [(k, r.refined) for k, r in results.items()] + [
            (f"robust_{k}", r.best) for k, r in robust.items() if not k.startswith("front")]:
        f = RF.influence(mech, design, ["AB", "BE", "BC"], "SumDelta_um", KEPT, base)
        for row in f.itertuples():
            sens.append({"design": label, "parameter": row.parameter,
                         "slope_um_per_mm": row.slope_per_unit,
                         "change_up_um": row.change_up, "change_down_um": row.change_down})
    timings["yields"] = time.perf_counter() - t
    checks = pd.DataFrame(checks)
    sens = pd.DataFrame(sens)

    md = ["# Nominal refinement and robust design of the 208 needle drive", "",
          f"seed {seed}; today's SumDelta {today_um:.4f} um (beta set; the guide where today's "
          "frame puts it). Held fixed in every variant: F (the main shaft), the guide's point "
          "N1 (it moves only along its normal by the guide shift), the branches; the stroke "
          "within +-0.1 mm of today's and every transmission angle >= 40 deg over the whole "
          "turn (assemblable, dead-point margin).", ""]
    for k, r in results.items():
        md += [f"## {k}: {r.objective_before:.4f} -> {r.objective_after:.4f} um "
               f"({r.ratio:.2f}x)", "",
               "Refined: " + ", ".join(r.bounds) + "; set on the design: "
               + ", ".join(r.options["adjust_boxes"]) + ". Everything else as today.", "",
               _md(r.parameters, ".5f"), "", _md(r.outputs_frame()), "",
               "Restarts (differential evolution):", "", _md(r.restarts, ".6f"), ""]
        if r.polished is not None:
            md += ["Each start polished by the minimax (epigraph SLSQP) polish:", "",
                   _md(r.polished, ".6f"), ""]
        md += ["Degree of influence at the optimum:", "", _md(r.influence), "",
               *[f"- {line}" for line in r.confirmation()], ""]
    if subsets is not None:
        md += ["## Smallest set of links reaching 3x (housing kept)", "",
               "Greedy forward selection, then every set one link smaller (exhaustive); each "
               "set: one differential evolution (8 per parameter, 40 generations), the minimax "
               "polish of its best and of today's design.", "", _md(subsets), ""]
    for name, r in robust.items():
        md += [f"## Robust design, {name}: adjust {'+'.join(r.adjust)}, {r.n} machines "
               f"(common random numbers, seed {r.seed})", "",
               "Design parameters: " + ", ".join(r.bounds) + "; constraints: "
               + "; ".join(c.text() for c in r.constraints)
               + (f"; nominal SumDelta <= {r.nominal_limit:g} um" if r.nominal_limit else "")
               + ". Held fixed: F, N1, LM, AM, the branches.", "",
               _md(r.figures), "", _md(r.restarts), "", _md(r.to_dataframe(), ".5f"), ""]
    if robust:
        front = RB.front_of(pd.concat([r.archive for r in robust.values()], ignore_index=True))
        md += ["## Pareto front (every design the robust searches evaluated: nominal SumDelta "
               "low, beta-only yield high, stroke error small; no NSGA-II: pymoo is not a "
               "dependency)", "", f"{len(front)} non-dominated designs; the yield on "
               f"{ROBUST_N} machines each.", "",
               _md(front[["nominal", "yield", "error"]].assign(error=front["error"] * 1e-3)
                   .rename(columns={"nominal": "SumDelta_um", "error": "stroke_error_mm"})),
               "",
               f"## Yields re-checked with fresh machines ({CHECK_N}, seed {check_seed}, 95 % "
               "Wilson intervals)", "", _md(checks), ""]
    md += ["## AB, BE, BC sensitivity (beta re-optimised; change at +-the base tolerance)", "",
           _md(sens), ""]
    if yields:
        md += ["## Beta-only yield on the base set (SumDelta <= 10 um, beta 10..35 per "
               f"machine, {YIELD_N} machines, seed {seed})", "",
               _md(pd.DataFrame([{"design": k, **v} for k, v in yields.items()])), ""]
    md += ["Timings (s, a machine shared with other work): "
           + ", ".join(f"{k} {v:.0f}" for k, v in timings.items()), ""]
    (out / "refine_summary.md").write_text("\n".join(md))
    record = {"seed": seed, "today_SumDelta_um": today_um,
              "designs": {k: _design_record(r) for k, r in results.items()},
              "robust": {k: r.to_dict() for k, r in robust.items()},
              "yield_checks": checks.to_dict("records"), "sensitivity": sens.to_dict("records"),
              "yields": yields, "timings_s": timings,
              "results": {k: r.to_dict() for k, r in results.items()}}
    (out / "refine.json").write_text(json.dumps(record, indent=1, default=float))
    pd.concat([r.parameters.assign(variant=k) for k, r in results.items()]).to_csv(
        out / "refine_parameters.csv", index=False)
    if subsets is not None:
        subsets.to_csv(out / "refine_smallest_set.csv", index=False)
    if robust:
        front.to_csv(out / "refine_pareto.csv", index=False)
        checks.to_csv(out / "refine_robust_yield.csv", index=False)
    sens.to_csv(out / "refine_sensitivity.csv", index=False)

    fig, axes = plt.subplots(len(results), 1, figsize=(7, 3.2 * len(results)))
    for ax, r in zip(np.atleast_1d(axes), results.values(), strict=True):
        r.plot(ax)
    fig.tight_layout()
    fig.savefig(out / "refine_deviation.png", dpi=150)
    plt.close(fig)
    drawn = {"today": start, **{k: r.refined for k, r in results.items()
                                if k in ("housing_kept", "guide_refitted")}}
    if "beta" in robust:
        drawn["robust (beta)"] = robust["beta"].best
    fig, ax = plt.subplots(figsize=(8, 7))
    plot_linkage(mech, drawn, ax)
    ax.set_title("208 needle drive at crank angle 90 deg: today (grey) and the refined / "
                 "robust designs\nheld fixed: F, the guide's point N1, the branches; guide "
                 "lines dashed", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "refine_linkage.png", dpi=150)
    plt.close(fig)
    if robust:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        sc = ax.scatter(front["nominal"], 100 * front["yield"], c=np.abs(front["error"]) * 1e-3,
                        s=16, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="|stroke error| (mm)")
        for name, r in robust.items():
            if name in ("beta", "beta_shift"):
                row = r.figures.set_index("design")
                ax.scatter(row.loc["robust", "nominal"], 100 * row.loc["robust", "yield"],
                           marker="*", s=120, color="tab:red" if name == "beta" else "tab:blue",
                           label=f"best, adjust {'+'.join(r.adjust)}")
                ax.scatter(row.loc["today", "nominal"], 100 * row.loc["today", "yield"],
                           marker="s", s=40, color="0.3",
                           label=f"today, adjust {'+'.join(r.adjust)}")
        ax.set_xscale("log")
        ax.set_xlabel("nominal SumDelta (um, beta set)")
        ax.set_ylabel(f"yield, base set, beta alone ({ROBUST_N} machines) (%)")
        ax.set_title("Pareto front: nominal SumDelta, yield, stroke error\nvaried: LF, AB, BC, "
                     "BE, CD, CBE, A, D, guide angle and place; held: F, N1, LM, AM, branches",
                     fontsize=9)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "refine_pareto.png", dpi=150)
        plt.close(fig)
    if designs_file:
        Path(designs_file).write_text(json.dumps(
            {"seed": seed, "today_SumDelta_um": today_um,
             "designs": {k: _design_record(r) for k, r in results.items()},
             "robust": {k: {"parameters": {p: v for p, v in r.best.items()
                                           if v != r.start.get(p)},
                            "nominal_SumDelta_um": float(r.figures.set_index("design")
                                                         .loc["robust", "nominal"]),
                            "stroke_error_um": float(r.figures.set_index("design")
                                                     .loc["robust", "error"])}
                        for k, r in robust.items() if k in ("beta", "beta_shift")}},
            indent=1, default=float) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="the report folder (refine_* files)")
    ap.add_argument("--work", default=None, help="the phases' pickles (default --out)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--designs", default=None)
    ap.add_argument("--no-yields", action="store_true",
                    help="skip the Monte-Carlo yields (write the designs only)")
    ap.add_argument("--phase", default="all",
                    choices=("all", "housing_kept", "guide_refitted", "smallest_set", "robust",
                             "write"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    work = Path(args.work) if args.work else out
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)

    def log(text):
        print(text, flush=True)

    mech = load_mechanism("needle_208")
    phases = ("housing_kept", "guide_refitted", "smallest_set", "robust")
    if args.phase != "write":
        for phase in (phases if args.phase == "all" else (args.phase,)):
            run_phase(phase, mech, args.seed, work, log)
        if args.phase != "all":
            return
    write(mech, work, out, args.seed, args.designs, args.no_yields, log)


if __name__ == "__main__":
    main()
