"""Failures per million of the 208 needle drive after adjustment.

For each tolerance set (the source study's base and recommended sets, the allocation study's set
for 99.73 % after beta adjustment, and that set tightened) and each strategy (beta fixed at the
nominal beta*, beta adjusted per machine): P(SumDelta > 10 um or no value) with its c.o.v.,
95 % interval, model calls and failures per mode; a brute-force Monte-Carlo of --n-brute machines
as the reference for the allocated set; the exceedance curve P(SumDelta > x) on a log axis down
to 1e-6 with its 95 % band; the most probable failing machines of each mode.

    python studies/needle_208_ppm.py [--out reports] [--seed 2026] [--budget 20000]
        [--n-brute 1000000] [--n-jobs 1] [--progress]

Writes reports/needle_208/ppm.{md,csv}, ppm_bruteforce.{md,csv}, ppm_failing_machines.{md,csv},
ppm_exceedance.{md,csv}, ppm_exceedance.png, allocated_tolerances.toml (for
`sewtol needle ppm --tolerances reports/needle_208/allocated_tolerances.toml`), ppm_run.json.
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
from sewtol.mechanisms.needle_208.model import Needle208  # noqa: E402
from sewtol.mechanisms.params import as_dict  # noqa: E402
from sewtol.provenance import now, run_record  # noqa: E402
from sewtol.reports import plots  # noqa: E402
from sewtol.reports.tables import write_table  # noqa: E402
from sewtol.studies import rare_event as R  # noqa: E402
from sewtol.tables import needle_208 as NR
from sewtol.tables.needle_208 import allocate  # noqa: E402
from sewtol.tolerances import NEEDLE_208_SETS, ToleranceSet  # noqa: E402

LIMIT_UM = 10.0
TARGET = 1e-6
STRATEGIES = {"none": "beta fixed (nominal beta*)", "beta": "beta adjusted per machine"}


def tol_text(ts) -> str:
    return "; ".join(f"{t.param} {t.lower:+.5g}/{t.upper:+.5g} mm {t.dist}" for t in ts.items)


def toml_of(ts: ToleranceSet) -> str:
    lines = [f"[sets.{ts.name}]", f'description = "{ts.description}"']
    lines += [f'{t.param} = {{ lower = {t.lower!r}, upper = {t.upper!r}, dist = "{t.dist}" }}'
              for t in ts.items]
    return "\n".join(lines) + "\n"


def check_args(args) -> None:
    if args.seed < 0:
        raise ParameterError("--seed", "must be a whole number >= 0", args.seed)
    if args.budget < 1000:
        raise ParameterError("--budget", "must be >= 1000 model calls", args.budget)
    if args.n_brute < 1000:
        raise ParameterError("--n-brute", "must be >= 1000 machines", args.n_brute)
    if args.n_jobs == 0 or args.n_jobs < -1:
        raise ParameterError("--n-jobs", "must be a positive number of workers or -1",
                             args.n_jobs)


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=True, progress=True, figures=True)
    ap.add_argument("--budget", type=int, default=20000, help="model calls per estimate")
    ap.add_argument("--n-brute", type=int, default=1_000_000,
                    help="brute-force Monte-Carlo machines for the allocated set")
    ap.add_argument("--n-alloc", type=int, default=2000, help="as in needle_208_tolerances.py")
    args = ap.parse_args(argv)
    try:
        check_args(args)
    except ParameterError as exc:
        print(f"needle_208_ppm: error: {exc}", file=sys.stderr)
        return 2
    started = now()
    out = Path(args.out) / "needle_208"
    p = Needle208.nominal()
    seeds = np.random.SeedSequence(args.seed)

    # the allocation study's set, recomputed with the settings of needle_208_tolerances.py
    alloc = allocate(p, NEEDLE_208_SETS["recommended"], target=0.9973, n=args.n_alloc,
                     seed=args.seed, steps=10)
    allocated = alloc.as_tolerance_set("allocated")
    allocated = ToleranceSet("allocated", allocated.items,
                             f"allocation for 99.73 % after beta adjustment ({args.n_alloc} "
                             f"machines, seed {args.seed}; yield there {alloc.yield_:.4f})")
    write_text_atomic(out / "allocated_tolerances.toml", toml_of(allocated))
    sets = {"base": NEEDLE_208_SETS["base"], "recommended": NEEDLE_208_SETS["recommended"],
            "allocated": allocated,
            **{f"allocated_x{k:g}": allocated.scaled(dict.fromkeys(allocated.params, k),
                                                     f"allocated_x{k:g}") for k in (0.8, 0.6)}}

    rows, examples, results = [], [], {}
    child = iter(seeds.spawn(len(sets) * len(STRATEGIES) + 4))
    for name, ts in sets.items():
        for strategy, label in STRATEGIES.items():
            ls = NR.needle_limit_state(p, ts, LIMIT_UM, strategy)
            res = R.estimate(ls, np.random.default_rng(next(child)), "auto", TARGET,
                             args.budget, n_jobs=args.n_jobs)
            results[(name, strategy)] = res
            row = {"tolerance set": name, "strategy": label}
            row.update(res.to_dataframe().iloc[0].to_dict())
            rows.append(row)
            if len(res.examples):
                examples.append(res.examples.assign(**{"tolerance set": name,
                                                       "strategy": label}))
            print(f"{name:16s} {strategy:5s} {res.statement}", file=sys.stderr)
    table = pd.DataFrame(rows)
    settings = {"event": f"SumDelta > {LIMIT_UM:g} um, or the machine cannot assemble, or a dead "
                "point (a union; shares per mode)",
                "method": f"auto: Monte-Carlo if budget x {TARGET:g} >= 10, else subset "
                "simulation (aCS, p0 = 0.1); budget "
                f"{args.budget} model calls per row; seed {args.seed}",
                "interval": "95 %: Clopper-Pearson for Monte-Carlo, log-normal from the c.o.v. "
                "(fully correlated levels) for subset simulation",
                "zero failures": "'< X at 95 %' (one-sided bound), never 0 ppm",
                **{f"set {k}": tol_text(v) for k, v in sets.items()},
                "guide": "fixed (nominal); beta range searched 10 ... 35 deg"}
    write_table(table, out, "ppm", "Failures per million after adjustment", settings,
                floatfmt=".4g")
    ex = pd.concat(examples, ignore_index=True) if examples else pd.DataFrame()
    write_table(ex, out, "ppm_failing_machines",
                "Most probable failing machines per mode (smallest |z|), per set and strategy",
                {"units": "deviations mm, SumDelta um; z_norm: distance from the nominal in "
                 "standard-normal space (smaller = more probable)"}, floatfmt=".5g")

    # brute force on the allocated set, both strategies, and the exceedance curve
    brute_rows, curves = [], {}
    x = np.linspace(0.0, 25.0, 251)
    for strategy, label in STRATEGIES.items():
        ls = NR.needle_limit_state(p, allocated, LIMIT_UM, strategy)
        mc = R.monte_carlo(ls, args.n_brute, np.random.default_rng(next(child)),
                           n_jobs=args.n_jobs, progress=args.progress)
        sus = results[("allocated", strategy)]
        brute_rows += [{"strategy": label, **r.to_dataframe().iloc[0].to_dict()}
                       for r in (mc, sus)]
        print(f"brute force {strategy}: {mc.statement}", file=sys.stderr)
        tail = R.subset_simulation(ls, max(args.budget // 8, 500),
                                   np.random.default_rng(next(child)), down_to=TARGET)
        curves[strategy] = (mc, tail)
    brute = pd.DataFrame(brute_rows)
    inside = []
    for label in STRATEGIES.values():
        mc = brute[(brute.strategy == label) & (brute.method == "montecarlo")].iloc[0]
        est = brute[(brute.strategy == label) & (brute.method != "montecarlo")].iloc[0]
        inside.append(f"{label}: brute force {mc.ppm:.4g} ppm in the estimate's interval "
                      f"{est.ci_low_ppm:.4g} ... {est.ci_high_ppm:.4g}: "
                      f"{est.ci_low_ppm <= mc.ppm <= est.ci_high_ppm}")
    write_table(brute, out, "ppm_bruteforce",
                "Rare-event estimate against brute-force Monte-Carlo, allocated set",
                {"set": tol_text(allocated), "brute force": f"{args.n_brute} machines",
                 "agreement": "; ".join(inside)}, floatfmt=".4g")

    frames = []
    fig, ax = plt.subplots(figsize=(8, 5))
    colors = {"none": "tab:red", "beta": "tab:blue"}
    for strategy, (mc, tail) in curves.items():
        e_mc, e_ss = mc.exceedance(x), tail.exceedance(x)
        frames += [e_mc.assign(strategy=strategy, method="montecarlo"),
                   e_ss.assign(strategy=strategy, method="subset")]
        tail.plot(x, ax, label=f"{STRATEGIES[strategy]}: subset simulation, "
                  f"{tail.model_calls} calls", color=colors[strategy])
        ok = e_mc.probability > 0
        ax.semilogy(e_mc.x[ok], e_mc.probability[ok], ls="--", color="k", lw=0.8,
                    label=f"brute-force Monte-Carlo, {mc.model_calls} machines per strategy"
                    if strategy == "beta" else None)
        ax.fill_between(e_mc.x[ok], e_mc.low[ok], e_mc.high[ok], color="0.6", alpha=0.3, lw=0)
    ax.axvline(LIMIT_UM, color="k", lw=0.8, ls=":")
    ax.axhline(1e-6, color="0.5", lw=0.6, ls=":")
    ax.set_ylim(1e-8, 1.2)
    ax.set_xlabel(f"\u03a3\u0394 x ({plots.MICRO})")
    ax.set_ylabel("P(\u03a3\u0394 > x)")
    ax.set_title("Allocated tolerances (99.73 % after \u03b2 adjustment): exceedance with 95 % "
                 "band\n(dashed black / grey: brute-force Monte-Carlo; dotted: the "
                 f"{LIMIT_UM:g} {plots.MICRO} limit)", fontsize=9)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8, loc="lower left")
    plots.save(fig, out / "ppm_exceedance.png", args.figure_format)
    write_table(pd.concat(frames, ignore_index=True), out, "ppm_exceedance",
                "Exceedance P(SumDelta > x) of the allocated set, with 95 % band",
                {"set": tol_text(allocated), "units": "x um",
                 "band": "Monte-Carlo: normal approx. of the binomial (log-normal); subset: "
                 "log-normal from the fully correlated c.o.v."}, floatfmt=".4g")

    record = run_record(started, {"mechanism": "208 needle drive", "params": as_dict(p),
                                  "tolerance_sets": {k: v.as_dict() for k, v in sets.items()},
                                  "seed": args.seed, "budget": args.budget,
                                  "n_brute": args.n_brute, "n_alloc": args.n_alloc,
                                  "n_jobs": args.n_jobs, "target": TARGET,
                                  "limit_um": LIMIT_UM, "beta_search_range_deg": [10.0, 35.0]})
    write_text_atomic(out / "ppm_run.json", json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}/ppm*")
    return 0


if __name__ == "__main__":
    sys.exit(main())
