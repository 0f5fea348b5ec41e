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

The smallest set: forward selection on the influence ranking (the k links of largest degree of
influence at the housing-kept optimum), each set searched by one short differential evolution
with a minimax polish of its best and of today's design; the size reached is then confirmed by
searching every set one link smaller.

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


def smallest_set(mech, ranking, target_um: float, seed: int, log, exhaustive_max: int = 4):
    """Forward selection on the influence ranking: the k most influential links at the
    housing-kept optimum, k = 1, 2, ..., until one set reaches target_um; then every set one
    link smaller (when it has at most exhaustive_max links) is searched too, to confirm that
    none reaches the target. Returns (the set, its result, the rows of every set searched)."""
    rows, found, res_found = [], None, None
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

    for k in range(1, len(ranking) + 1):
        r = run(ranking[:k], "ranking")
        if r.objective_after <= target_um:
            found, res_found = list(ranking[:k]), r
            break
    if found and 1 <= len(found) - 1 <= exhaustive_max:
        for subset in itertools.combinations(LINKS, len(found) - 1):
            r = run(list(subset), "exhaustive")
            if r.objective_after <= target_um:  # a smaller set reaches it: that is the answer
                found, res_found = list(subset), r
                break
    return found, res_found, pd.DataFrame(rows)


CONFIRM_VARIANTS = ("housing_kept", "guide_refitted")
EXHAUSTIVE_MAX = 4  # the exhaustive confirmation runs for sets of at most this many links
BRUTE_N = 20000  # designs of the dense sampling around each optimum
BRUTE_FRACTION = 0.02  # its half-width: 2 % of each parameter's box


def brute_force(mech, res, adjust, seed) -> dict:
    """A dense brute force around the optimum: BRUTE_N designs (Latin hypercube) within +-2 %
    of each box around it, clipped to the box, every one adjusted exactly and held to the
    constraints; the lowest found beside the optimum."""
    from scipy.stats import qmc

    names = list(res.bounds)
    lo = np.array([res.bounds[k][0] for k in names])
    hi = np.array([res.bounds[k][1] for k in names])
    x0 = np.array([res.refined[k] for k in names])
    half = BRUTE_FRACTION * (hi - lo)
    u = qmc.LatinHypercube(d=len(names), rng=np.random.default_rng(seed)).random(BRUTE_N)
    X = np.clip(x0 - half + 2 * half * u, lo, hi)
    prob = RF.DesignProblem(mech, res.objective, res.bounds, adjust, res.constraints, True)
    f = np.concatenate([prob(X[i:i + 500].T) for i in range(0, BRUTE_N, 500)])
    feasible = f < RF.PENALTY
    k = int(np.argmin(f))
    return {"n": BRUTE_N, "half_width_of_box": BRUTE_FRACTION,
            "feasible": int(feasible.sum()), "lowest_um": float(f[k]),
            "optimum_um": float(res.objective_after),
            "lowest_minus_optimum_um": float(f[k] - res.objective_after),
            "lowest_at": dict(zip(names, map(float, X[k]), strict=True))}


ROBUST_N = 200  # machines per design in the search (common random numbers)
CHECK_N = 2000  # fresh machines (another seed) for each best design's yield
CBE_BOX_DEG = 5.0
ROBUST_LINKS = ["LF", "AB", "BC", "BE", "CD"]  # LM and AM act only through the swing, as LF


LOCAL_LINK = 0.02  # the local box: +-2 % of a link around today's and the refined value
LOCAL_PIVOT_MM = 0.5
LOCAL_SHIFT_UM = 300.0


def robust_bounds(mech, around: dict | None = None) -> dict:
    """The design box of the robust search: the links +-10 %, the pivots +-2 mm, the guide
    angle +-0.5 deg, CBE +-5 deg, the guide's place +-2 mm; with `around` (a refined design)
    the local box spanning today's and that design's values, widened by +-2 % of each link,
    +-0.5 mm of each pivot and +-0.3 mm of the guide's place (the yield is 0 almost everywhere
    in the wide box: the straight designs are a thin set in it)."""
    b = RF.default_bounds(mech, ROBUST_LINKS + PIVOTS + ["guide_angle"])
    nominal = mech.nominal_values()
    cbe = nominal["CBE"]
    b = {**b, "CBE": (cbe - CBE_BOX_DEG, cbe + CBE_BOX_DEG),
         "guide_shift_um": REFIT["guide_shift_um"]}
    if around is None:
        return b
    out = {}
    for k, (lo, hi) in b.items():
        a, z = sorted((nominal[k], around.get(k, nominal[k])))
        w = (LOCAL_LINK * nominal[k] if k in ROBUST_LINKS else LOCAL_PIVOT_MM if k in PIVOTS
             else LOCAL_SHIFT_UM if k == "guide_shift_um" else hi - lo)
        out[k] = (max(lo, a - w), min(hi, z + w))
    return out


def robust_runs(mech, seed: int, log, work_dir: Path) -> dict:
    """The robust-design searches (sewtol.studies.robust): yield on the base set maximised
    with beta alone (two restarts), with beta + guide shift, and an epsilon-constraint sweep of
    the nominal SumDelta with a wider stroke band (+-1 mm) for the front."""
    base = mech.tolerance_sets["base"]
    bounds = robust_bounds(mech)
    stroke0 = RF.keep(mech, "stroke_um", STROKE_TOL_UM, ["beta"])
    today_stroke = 0.5 * (stroke0.lower + stroke0.upper)
    tight = RF.default_constraints(mech) + [stroke0]
    common = dict(nominal_adjust=["beta"], error_of=("stroke_um", today_stroke), n=ROBUST_N,
                  seed=seed, popsize=5)
    # the stroke held at today's by the crank radius (solved per design, LF inside its +-10 %)
    lf = RF.default_bounds(mech, ["LF"])["LF"]
    hold = ("stroke_um", today_stroke, "LF", lf)
    without_lf = {k: v for k, v in bounds.items() if k != "LF"}
    # the housing-kept refined design rides in the first populations; the local box spans
    # it and today's
    with open(work_dir / "housing_kept.pkl", "rb") as fh:
        kept = pickle.load(fh)[0].refined
    common["init_designs"] = [kept]
    local = {k: v for k, v in robust_bounds(mech, kept).items() if k != "LF"}
    out = {}
    plan = [("beta_wide", dict(adjust=["beta"], constraints=tight, restarts=1, maxiter=20,
                               hold=hold, bounds=without_lf)),
            ("beta", dict(adjust=["beta"], constraints=tight, restarts=2, maxiter=30,
                          hold=hold, bounds=local)),
            ("beta_shift", dict(adjust=["beta", "guide_shift"], constraints=tight, restarts=1,
                                maxiter=20, hold=hold, bounds=local))]
    for eps in (1.5, 3.0):
        plan.append((f"front_eps{eps:g}", dict(adjust=["beta"], constraints=tight,
                                               restarts=1, maxiter=20, nominal_limit=eps,
                                               hold=hold, bounds=local)))
    if (work_dir / "robust_beta.pkl").exists():  # the wide-box run made before: kept as is
        with open(work_dir / "robust_beta.pkl", "rb") as fh:
            first = pickle.load(fh)
        if first.bounds == {k: tuple(map(float, v)) for k, v in without_lf.items()}:
            out["beta_wide"] = first
            plan = plan[1:]
    for name, kw in plan:
        t = time.perf_counter()
        kw = dict(kw)
        out[name] = RB.robust(mech, kw.pop("bounds"), base, **common, **kw)
        with open(work_dir / f"robust_{name}.pkl", "wb") as fh:  # each run kept as it ends
            pickle.dump(out[name], fh)
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
        with open(out / "housing_kept.pkl", "rb") as fh:
            kept, _ = pickle.load(fh)
        infl = kept.influence.sort_values("influence", key=abs, ascending=False)
        ranking = list(infl["parameter"])
        log("forward selection on the degree of influence at the housing-kept optimum: "
            + ", ".join(ranking))
        found, res, subsets = smallest_set(mech, ranking, kept.objective_before / 3, seed, log,
                                           exhaustive_max=EXHAUSTIVE_MAX)
        res = (res, subsets)
    elif phase == "robust":
        res = robust_runs(mech, seed, log, out)
    elif phase in ("repolish_housing_kept", "repolish_guide_refitted"):
        # the searches again from their pickled restarts, every start re-polished
        variant = phase.removeprefix("repolish_")
        with open(out / f"{variant}.pkl", "rb") as fh:
            old, t_old = pickle.load(fh)
        adjust = KEPT if variant == "housing_kept" else REFIT
        params = dict.fromkeys(old.bounds) if variant == "housing_kept" else {
            **dict.fromkeys(LINKS + PIVOTS), "guide_angle": None}
        res = RF.refine(mech, params, adjust=adjust, constraints=constraints(mech, adjust),
                        seed=seed, polish="minimax", tolerances=base,
                        starts=old.restarts, restarts=len(old.restarts),
                        popsize=old.options["popsize"], maxiter=old.options["maxiter"])
        with open(out / f"{variant}.pkl", "wb") as fh:
            pickle.dump((res, t_old + time.perf_counter() - t), fh)
        return
    elif phase == "confirm":
        res = {}
        if (out / "confirm.pkl").exists():  # a variant already confirmed is kept
            with open(out / "confirm.pkl", "rb") as fh:
                res = pickle.load(fh)[0]
        for variant, adjust in (("housing_kept", KEPT), ("guide_refitted", REFIT)):
            if variant not in CONFIRM_VARIANTS:
                continue
            if variant not in res and (out / f"{variant}.pkl").exists():
                with open(out / f"{variant}.pkl", "rb") as fh:
                    r, _ = pickle.load(fh)
                res[variant] = brute_force(mech, r, adjust, seed)
                log(f"  {variant}: {res[variant]}")
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


def _robust_record(mech, r, today_stroke_um) -> dict:
    """A robust design as --set parameters (beta at its nominal optimum) with its nominal
    SumDelta and stroke error (um), as the file evaluates them."""
    prob = RF.DesignProblem(mech, "SumDelta_um", {}, KEPT, (), True)
    o = prob.outputs_at(r.best, ["stroke_um"])
    values = {**r.best, **o["_settings"]}
    return {"parameters": {p: float(v) for p, v in values.items() if v != r.start.get(p)},
            "nominal_SumDelta_um": o["SumDelta_um"],
            "stroke_error_um": o["stroke_um"] - today_stroke_um,
            "yield_search": float(r.figures.set_index("design").loc["robust", "yield"]),
            "n_search": r.n, "adjust": list(r.adjust)}


def write(mech, work: Path, out: Path, seed: int, designs_file, no_yields: bool, log):
    """Turn the phases' pickles (work) into reports/needle_208/refine_* (out)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    results, timings, subsets, small, robust, brute = {}, {}, None, None, {}, {}
    for phase in ("housing_kept", "guide_refitted", "smallest_set", "robust", "confirm"):
        if not (work / f"{phase}.pkl").exists():
            continue
        with open(work / f"{phase}.pkl", "rb") as fh:
            res, timings[phase] = pickle.load(fh)
        if phase == "smallest_set":
            small, subsets = res
        elif phase == "robust":
            robust = res
        elif phase == "confirm":
            brute = res
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
               *[f"- {line}" for line in r.confirmation()]]
        if k in brute:
            b = brute[k]
            md += [f"- dense brute force around the optimum: {b['n']} designs (Latin "
                   f"hypercube, +-{100 * b['half_width_of_box']:g} % of each box, beta"
                   + (" and the shift" if k == "guide_refitted" else "") + " exact at each, "
                   f"{b['feasible']} feasible): the lowest {b['lowest_um']:.4f} um, "
                   f"{b['lowest_minus_optimum_um']:+.4f} um from the optimum"]
        md += [""]
    if subsets is not None:
        md += ["## Smallest set of links reaching 3x (housing kept)", "",
               "Forward selection on the influence ranking, then every set one link smaller "
               "(exhaustive); each "
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
        # the front of the beta-only searches (one strategy: yields of another are not
        # comparable)
        front = RB.front_of(pd.concat([r.archive for r in robust.values()
                                       if tuple(r.adjust) == ("beta",)], ignore_index=True))
        md += ["## Pareto front (every design the robust searches evaluated: nominal SumDelta "
               "low, beta-only yield high, stroke error small; no NSGA-II: pymoo is not a "
               "dependency)", "", f"{len(front)} non-dominated designs; the yield on "
               f"{ROBUST_N} machines each.", "",
               _md(front[["nominal", "yield", "error"]].assign(error=front["error"] * 1e-3)
                   .rename(columns={"nominal": "SumDelta_um", "error": "stroke_error_mm"})),
               "",
               f"## Yields re-checked with fresh machines ({CHECK_N}, seed {check_seed}, 95 % "
               "Wilson intervals)", "", _md(checks), "",
               "The nominal SumDelta of every robust design is read with beta alone set on "
               "the nominal design and the guide where the design puts it (also for the "
               "beta + shift search, whose machines get their shift too).", ""]
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
              "yields": yields, "timings_s": timings, "brute_force": brute,
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
        o = RF.DesignProblem(mech, "SumDelta_um", {}, KEPT, (), True).outputs_at(
            robust["beta"].best, [])
        drawn["robust (beta)"] = {**robust["beta"].best, **o["_settings"]}
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
            if name == "beta":
                row = r.figures.set_index("design")
                ax.scatter(row.loc["robust", "nominal"], 100 * row.loc["robust", "yield"],
                           marker="*", s=120, color="tab:red",
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
             "robust": {k: _robust_record(mech, r, first.before["stroke_um"])
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
                             "confirm", "repolish_housing_kept", "repolish_guide_refitted",
                             "write"))
    ap.add_argument("--exhaustive-max", type=int, default=EXHAUSTIVE_MAX,
                    help="the smallest set's exhaustive confirmation up to this many links "
                    "(0: none)")
    ap.add_argument("--confirm", default=None,
                    help="the variants the confirm phase samples around (default both)")
    args = ap.parse_args(argv)
    globals()["EXHAUSTIVE_MAX"] = args.exhaustive_max
    if args.confirm:
        globals()["CONFIRM_VARIANTS"] = tuple(args.confirm.split(","))
    out = Path(args.out)
    work = Path(args.work) if args.work else out
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)

    def log(text):
        print(text, flush=True)

    mech = load_mechanism("needle_208")
    phases = ("housing_kept", "guide_refitted", "smallest_set", "robust", "confirm")
    if args.phase != "write":
        for phase in (phases if args.phase == "all" else (args.phase,)):
            run_phase(phase, mech, args.seed, work, log)
        if args.phase != "all":
            return
    write(mech, work, out, args.seed, args.designs, args.no_yields, log)


if __name__ == "__main__":
    main()
