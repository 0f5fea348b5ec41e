"""Least-cost tolerance allocation (sewtol.studies.least_cost) of the two worked examples, each
beside today's allocation at equal yield, checked on fresh machines.

    python studies/least_cost_allocation.py needle --out reports/needle_208 [--n 2000 --seed 2026]
    python studies/least_cost_allocation.py feed --out reports/feed_131-42-3 [--n 60 --seed 2026]
    python studies/least_cost_allocation.py needle --strategies beta --out /tmp/beta   # one each,
    python studies/least_cost_allocation.py combine --parts /tmp/beta /tmp/none --out DIR  # as one

needle: the 208 needle drive, SumDelta <= 10 um, 99.73 % with 95 % confidence on the search's
machines, the recommended set's parameters with the cost of examples/tolerances/needle_208_cost.toml
(sum of 1/t, equal weights: today's cost model), per strategy (beta set per machine in 10..35
deg, as today's allocation; no adjustment; beta + guide shift). Today's allocation is the
RSS-shaped one (reports/needle_208/allocation.md: t_i ~ (c_i / s_i^2)^(1/3)), recomputed per
strategy (sewtol.tables.needle_208.allocate) and brought to the same criterion on the
same machines by its largest common scale.

feed: the 131-42+3 feed's lower dog step, within +-0.01 mm of nominal, 90 % with 95 % confidence,
the feed chain's links (examples/tolerances/feed_131_cost.toml: the file's illustrative +-0.02 mm
set with the same assumed cost); today's generic allocation is the common scale of that set
(`sewtol run feed_131 allocation --shape set`). The feed's model takes about 10 ms a machine
(720 angles, both dogs), so its search runs on 60 machines with a small budget and no centre
scan in the polish: the restarts say how far they agree.

Writes DIR/allocation_cost.md/.csv (per strategy and parameter: today's limits and cost beside
the least-cost ones, and what limits each side), DIR/allocation_cost_summary.md/.csv (totals,
yield on the search's machines, yield on fresh machines with its 95 % interval),
DIR/allocation_cost_restarts.md/.csv and DIR/allocation_cost_run.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pandas as pd

import sewtol
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208.compensators import strategy_of
from sewtol.provenance import version_record
from sewtol.reports.tables import write_table
from sewtol.studies import allocation as AL
from sewtol.studies import least_cost as LC
from sewtol.tables import needle_208 as T
from sewtol.tolerances import load_toml

ROOT = Path(__file__).resolve().parent.parent
NEEDLE_COST = ROOT / "examples" / "tolerances" / "needle_208_cost.toml"
FEED_COST = ROOT / "examples" / "tolerances" / "feed_131_cost.toml"
FEED_OUTPUT = "lower_step_mm"
FEED_HALF_MM = 0.01


def side_by_side(res: LC.LeastCost, strategy: str, today: str) -> pd.DataFrame:
    t = res.table
    return pd.DataFrame({
        "strategy": strategy, "param": t["param"], "cost_model": t["cost_model"],
        f"{today}_lower": t["common_lower"], f"{today}_upper": t["common_upper"],
        f"{today}_cost": t["common_cost"],
        "least_cost_lower": t["lower"], "least_cost_upper": t["upper"],
        "least_cost_centre": t["centre"], "least_cost_cost": t["cost"],
        "lower_limited_by": t["lower_limited_by"], "upper_limited_by": t["upper_limited_by"]})


def summary(res: LC.LeastCost, strategy: str, seconds: float) -> pd.DataFrame:
    return res.compare.assign(strategy=strategy, target=res.target,
                              confidence=res.confidence, allowed_failures=res.allowed_failures,
                              restart_cost_spread=res.spread, search_seconds=seconds)[
        ["strategy", "allocation", "cost", "target", "confidence", "n", "allowed_failures",
         "failures", "yield", "scale", "fresh_n", "fresh_seed", "fresh_yield", "fresh_ci95_low",
         "fresh_ci95_high", "fresh_meets", "restart_cost_spread", "search_seconds"]]


def write(out: Path, rows, sums, restarts, settings, run):
    run = {**run, "settings": settings,
           "tables": {"allocation_cost": pd.concat(rows, ignore_index=True).to_dict("records"),
                      "summary": pd.concat(sums, ignore_index=True).to_dict("records"),
                      "restarts": pd.concat(restarts, ignore_index=True).to_dict("records")}}
    write_table(pd.concat(rows, ignore_index=True), out, "allocation_cost",
                "Least-cost tolerance allocation beside today's, at equal yield", settings,
                floatfmt=".5f")
    write_table(pd.concat(sums, ignore_index=True), out, "allocation_cost_summary",
                "Least-cost allocation: cost and yield, on the search's machines and on fresh "
                "ones", settings, floatfmt=".5f")
    write_table(pd.concat(restarts, ignore_index=True), out, "allocation_cost_restarts",
                "Least-cost allocation: each restart of the search", settings, floatfmt=".5f")
    (out / "allocation_cost_run.json").write_text(json.dumps(run, indent=2, default=str) + "\n")


def needle(args, out: Path) -> None:
    ref = load_toml(NEEDLE_COST)["recommended"]
    nominal = sewtol.Needle208.nominal()
    mech = T.as_mechanism(nominal)
    plans = {"beta": (None, {"beta": tuple(sb.DEFAULT_RANGE_DEG)}, {}),
             "none": (strategy_of([]), None, {}),
             "beta+shift": (strategy_of(["beta", "guide_shift_um"]), None,
                            {"limit_um": sb.DEFAULT_LIMIT_UM, "plateaus": False})}
    rows, sums, restarts, runs = [], [], [], {}
    for name in args.strategies:
        st, adjust, options = plans[name]
        if st is not None:
            adjust = st.compensators or None
        t0 = time.perf_counter()
        # today's RSS-shaped allocation for this strategy: its shape is the comparison
        rss = T.allocate(nominal, ref, args.target, args.n, args.seed, steps=10, strategy=st)
        res = LC.least_cost(mech, ref, "SumDelta_um", args.target, upper=sb.DEFAULT_LIMIT_UM,
                            n=args.n, seed=args.seed, adjust=adjust,
                            confidence=args.confidence, max_half=args.max_half,
                            restarts=args.restarts,
                            popsize=args.popsize, maxiter=args.maxiter, sweeps=args.sweeps,
                            shape=rss.as_tolerance_set(), shape_name="today (RSS shape)",
                            centre_scan=not args.no_centre_scan,
                            check_n=args.check_n, check_seed=args.seed + 1, **options)
        sec = time.perf_counter() - t0
        print(f"needle {name}: cost {res.cost:.2f} vs RSS {res.compare['cost'][1]:.2f}, "
              f"{sec:.0f} s", flush=True)
        rows.append(side_by_side(res, name, "rss"))
        sums.append(summary(res, name, sec))
        restarts.append(res.restarts.assign(strategy=name))
        runs[name] = res.to_dict()
        settings = {"mechanism": "208 needle drive, built-in nominal (main frame)",
                    "output": "SumDelta_um <= 10 um after the strategy's adjustment",
                    "reference set": f"recommended with the cost of {NEEDLE_COST.relative_to(ROOT)}",
                    "cost": "reciprocal c = 1/t per link, t = half-width mm (assumed: equal "
                            "weights, today's cost model)",
                    "criterion": f"yield {args.target} with {args.confidence} confidence "
                                 f"(one-sided Clopper-Pearson) on {args.n} machines, seed "
                                 f"{args.seed}",
                    "fresh check": f"{args.check_n} machines, seed {args.seed + 1}, 95 % "
                                   "Clopper-Pearson interval",
                    "held fixed": "nominal design and frame, guide line (shift only in "
                                  "beta+shift), each zone holds the nominal, half-width within "
                                  f"[0.01, 4] x the reference's and <= {args.max_half} mm",
                    "search": f"differential evolution, {args.restarts} restarts, popsize "
                              f"{args.popsize} x 2d, {args.maxiter} generations, {args.sweeps} "
                              "polish sweeps" + (" without the centre scan"
                                                 if args.no_centre_scan else ""),
                    "units": "mm"}
        write(out, rows, sums, restarts, settings,
              {"study": "least_cost_allocation needle", "args": vars(args), "results": runs,
               **version_record()})


def feed(args, out: Path) -> None:
    from sewtol.cli.run import load_mechanism

    mech = load_mechanism("feed_131")
    ref = load_toml(FEED_COST, mech.parameter_names)["links"]
    nominal = float(mech.evaluate(mech.nominal_values()).outputs[FEED_OUTPUT][0])
    upper, lower = nominal + FEED_HALF_MM, nominal - FEED_HALF_MM
    t0 = time.perf_counter()
    today = AL.allocate(mech, ref, FEED_OUTPUT, args.target, upper, lower, args.n, args.seed)
    res = LC.least_cost(mech, ref, FEED_OUTPUT, args.target, upper, lower, n=args.n,
                        seed=args.seed, confidence=args.confidence, max_half=args.max_half,
                        restarts=args.restarts,
                        popsize=args.popsize, maxiter=args.maxiter, sweeps=args.sweeps,
                        shape=ref, shape_name="today (common scale of the set)",
                        centre_scan=False,
                        check_n=args.check_n, check_seed=args.seed + 1)
    sec = time.perf_counter() - t0
    print(f"feed: cost {res.cost:.2f} vs common scale {res.compare['cost'][1]:.2f}, "
          f"{sec:.0f} s; today's point-yield scale {today.scale:.4g}", flush=True)
    settings = {"mechanism": "131-42+3 feed, built-in nominal (regulator b = 30 deg)",
                "output": f"{FEED_OUTPUT} within {lower:.5f} .. {upper:.5f} mm (nominal "
                          f"{nominal:.5f} +- {FEED_HALF_MM} mm: an illustrative limit)",
                "reference set": f"links with the cost of {FEED_COST.relative_to(ROOT)}",
                "cost": "reciprocal c = 1/t per link, t = half-width mm (assumed: equal weights)",
                "criterion": f"yield {args.target} with {args.confidence} confidence (one-sided "
                             f"Clopper-Pearson) on {args.n} machines, seed {args.seed}",
                "fresh check": f"{args.check_n} machines, seed {args.seed + 1}, 95 % "
                               "Clopper-Pearson interval",
                "today": f"the set's common scale (sewtol run feed_131 allocation --shape set: "
                         f"plain yield >= target on the same machines gives scale {today.scale:.4g}); here "
                         "brought to the same criterion",
                "held fixed": "nominal design, no adjustment, each zone holds the nominal, "
                              "half-width within [0.01, 4] x the reference's",
                "search": f"differential evolution, {args.restarts} restarts, popsize "
                          f"{args.popsize} x 2d, {args.maxiter} generations, {args.sweeps} "
                          "polish sweeps without the centre scan",
                "units": "mm"}
    write(out, [side_by_side(res, "none", "today")], [summary(res, "none", sec)],
          [res.restarts.assign(strategy="none")], settings,
          {"study": "least_cost_allocation feed", "args": vars(args),
           "results": {"none": res.to_dict()}, "today_point_scale": today.scale,
           **version_record()})


def combine(args, out: Path) -> None:
    """The tables of several runs (e.g. one strategy each, run side by side) as one."""
    runs = [json.loads((Path(d) / "allocation_cost_run.json").read_text()) for d in args.parts]
    frames = {k: [pd.DataFrame(r["tables"][k]) for r in runs]
              for k in ("allocation_cost", "summary", "restarts")}
    # each run's search budget goes with its rows (the parts may differ)
    frames["summary"] = [f.assign(search=r["settings"]["search"])
                         for f, r in zip(frames["summary"], runs, strict=True)]
    settings = {**runs[0]["settings"], "search": "per strategy: the summary's search column"}
    write(out, frames["allocation_cost"], frames["summary"], frames["restarts"], settings,
          {"study": runs[0]["study"],
           "args": [{k: v for k, v in r["args"].items() if k != "out"} for r in runs],
           "results": {k: v for r in runs for k, v in r["results"].items()},
           **version_record()})


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mechanism", choices=("needle", "feed", "combine"))
    p.add_argument("--parts", nargs="*", default=(),
                   help="combine: the --out folders of runs to write as one table")
    p.add_argument("--max-half", type=float, default=None,
                   help="the largest half-width of any zone, mm (needle 1.0, today's cap; feed "
                        "none: 4 x the reference's)")
    p.add_argument("--out", required=True)
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--n", type=int, default=None, help="machines of the search (needle 2000, "
                   "feed 60)")
    p.add_argument("--check-n", type=int, default=None, help="fresh machines (needle 20000, "
                   "feed 600)")
    p.add_argument("--target", type=float, default=None, help="needle 0.9973, feed 0.9")
    p.add_argument("--confidence", type=float, default=0.95)
    p.add_argument("--restarts", type=int, default=2)
    p.add_argument("--popsize", type=int, default=None, help="needle 3, feed 2")
    p.add_argument("--maxiter", type=int, default=None, help="needle 12, feed 3")
    p.add_argument("--sweeps", type=int, default=None, help="needle 2, feed 1")
    p.add_argument("--no-centre-scan", action="store_true",
                   help="needle: polish by pushes alone (the feed always does)")
    p.add_argument("--strategies", default="beta,none,beta+shift",
                   help="needle: comma-separated, of beta, none, beta+shift")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.mechanism == "combine":
        return combine(args, out)
    is_needle = args.mechanism == "needle"
    if is_needle and args.max_half is None:
        args.max_half = 1.0
    for key, n_val, f_val in (("n", 2000, 60), ("check_n", 20000, 600),
                              ("target", 0.9973, 0.9), ("popsize", 3, 2), ("maxiter", 12, 3),
                              ("sweeps", 2, 1)):
        if getattr(args, key) is None:
            setattr(args, key, n_val if is_needle else f_val)
    args.strategies = [s.strip() for s in args.strategies.split(",")]
    (needle if is_needle else feed)(args, out)


if __name__ == "__main__":
    main()
