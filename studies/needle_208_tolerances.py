"""Tolerance studies of the 208 needle drive: scans, worst case, Monte-Carlo, Sobol, allocation,
guide comparison. Writes reports/needle_208/ tables (CSV + Markdown) and plots (index.md is
written last, by needle_208_index.py).

    python studies/needle_208_tolerances.py [--out reports] [--seed 2026] [--n-mc 10000]
        [--n-sobol 4096] [--n-jobs 1] [--progress] [--tolerances FILE.toml[:SET] ...]

Without --tolerances the built-in sets (base, recommended) are studied; with it, the named sets
(a built-in name, every set of a TOML file, or FILE.toml:SET; repeatable).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib.pyplot as plt

from sewtol.errors import ParameterError
from sewtol.io import to_json, write_text_atomic
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.needle_208.single import deviation_table
from sewtol.mechanisms.params import as_dict, field_names
from sewtol.provenance import now, run_record
from sewtol.reports import plots
from sewtol.reports.tables import write_table
from sewtol.tables.needle_208 import (
    allocate,
    compare_guides,
    largest_tolerances,
    montecarlo,
    needle_sobol,
    scan,
    worst_case_table,
)
from sewtol.tolerances import NEEDLE_208_SETS, resolve_all

SCAN_COLUMNS = {"param": "parameter", "side": "limit", "delta_mm": "deviation (mm)",
                "value_mm": "value (mm)", "beta_deg": "beta* (deg)", "plus_um": "Delta+ (um)",
                "minus_um": "Delta- (um)", "total_um": "SumDelta (um)",
                # beta*'s plateau: SumDelta within 1e-3 um of the optimum; beta* is its centre
                "beta_low_deg": "beta* plateau from (deg)", "beta_high_deg": "beta* plateau to (deg)"}


def tol_text(ts) -> str:
    return "; ".join(f"{t.param} {t.lower:+g}/{t.upper:+g} mm {t.dist}" for t in ts.items)


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=True, progress=True, figures=True, n_mc=10000,
                            n_sobol=4096, n_alloc=2000, n_guides=2000)
    ap.add_argument("--tolerances", action="append", metavar="FILE.toml[:SET]",
                    help="study these sets instead of the built-in ones (repeatable)")
    args = ap.parse_args(argv)
    try:
        sets = resolve_all(args.tolerances, NEEDLE_208_SETS, field_names(Needle208))
        for ts in sets.values():
            ts.check_against(Needle208.nominal())
    except ParameterError as exc:
        print(f"needle_208_tolerances.py: error: {exc}", file=sys.stderr)
        return 2
    started = now()
    out = Path(args.out) / "needle_208"
    p = Needle208.nominal()
    guide = (f"fixed through ({p.guide_x:.3f}, {p.guide_y:.3f}) mm at {p.guide_angle:.4f} deg "
             "from the vertical")
    summary = {}

    nominal_curve = deviation_table(p)
    for name, ts in sets.items():
        base = {"tolerance set": f"{name} ({tol_text(ts)})", "guide": guide,
                "units": "deviation and value mm, beta deg, Delta um"}
        for shift in (0.0, 50.0, -50.0):
            sc = scan(p, ts, guide_shift_um=shift)
            suffix = "" if shift == 0 else f"_shift{shift:+.0f}um"
            frame = sc.to_dataframe().rename(columns=SCAN_COLUMNS)
            write_table(frame, out, f"scan_{name}{suffix}",
                        f"Per-parameter scan, {name} tolerances, guide shift {shift:+g} um",
                        {**base, "guide shift (um)": shift,
                         "beta_at_bound": "True where beta*'s plateau (the plateau columns) "
                         "reaches an end of the searched 10 ... 35 deg: SumDelta stays within "
                         "1e-3 um of its least value up to that end; a plateau narrower than "
                         "0.1 deg there means SumDelta is still falling at the end",
                         "nominal at this guide": f"beta* {sc.nominal_row['beta_deg']:.4f} deg, "
                         f"SumDelta {sc.nominal_row['total_um']:.4f} um"})
            if shift == 0:
                curves = {}
                for t in ts.items:
                    curves[t.param] = {}
                    for side, d in (("upper", t.upper), ("lower", t.lower)):
                        row = sc.rows[(sc.rows.param == t.param) & (sc.rows.side == side)].iloc[0]
                        q = p.override(**{t.param: getattr(p, t.param) + d, "beta": row.beta_deg})
                        label = (f"{side} {d:+g} mm: \u03b2* {row.beta_deg:.2f}\u00b0, "
                                 f"\u03a3\u0394 {row.total_um:.2f} {plots.MICRO}")
                        curves[t.param][label] = deviation_table(q, step_deg=2.0)
                fig = plots.scan_deviation_grid(nominal_curve, curves,
                                                nominal_total_um=sc.nominal_row["total_um"])
                fig.suptitle(f"d(\u03c6) at each limit, {name} tolerances, \u03b2 re-optimised, "
                             f"guide fixed; limit \u03a3\u0394 \u2264 10 {plots.MICRO} "
                             f"(dotted: \u00b15 {plots.MICRO})", fontsize=10, y=1.01)
                plots.save(fig, out / f"scan_{name}_deviation.png", args.figure_format)

        wc = worst_case_table(p, ts)
        write_table(wc, out, f"worst_case_{name}", f"Worst case over the {name} tolerance box",
                    {**base, "method": "all corners and the centre, best 3 polished by L-BFGS-B"})

        mc = montecarlo(p, ts, args.n_mc, args.seed, n_jobs=args.n_jobs, progress=args.progress)
        mset = {**base, "machines": mc.n, "seed": args.seed, "failed (cannot assemble)": mc.failed,
                "limit": "SumDelta <= 10 um", "beta range searched": "10 ... 35 deg",
                "fixed beta": f"{mc.extra['nominal_beta_deg']:.4f} deg (the nominal machine's beta*)"}
        rng = mc.extra["beta_search_range_deg"]
        low, high = plots.at_bound(mc.machines["beta_opt_deg"], rng)
        mset["beta* at a search bound"] = (
            f"{low} machines at {rng[0]:g} deg, {high} at {rng[1]:g} deg (their "
            "optimum may lie beyond: adjusted as far as the range goes); columns beta_at_bound: "
            f"{mc.at_bound('beta')} machines whose optimum plateau reaches a bound, "
            f"beta_pinned_at_bound: {mc.at_bound('beta', pinned=True)} of them with a plateau "
            "narrower than 0.1 deg (the others sit on a flat plateau)")
        # beta is only searched in the adjusted case; the fixed case never sits at a bound
        summary_table = mc.summary_frame()
        write_table(summary_table, out, f"montecarlo_{name}",
                    f"Monte-Carlo, {name} tolerances", mset)
        write_table(mc.pareto(), out, f"montecarlo_{name}_pareto",
                    f"Contributors to SumDelta after beta adjustment, {name} tolerances",
                    {**mset, "measure": "bias-corrected correlation ratio eta^2 on 20 quantile bins"})
        summary[name] = mc.to_dict()
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        plots.montecarlo_histograms(mc.machines["total_fixed_um"], mc.machines["total_adjusted_um"],
                                    10.0, (mc.yield_of("fixed"), mc.yield_of("adjusted")), axes[0])
        axes[0].set_title(f"\u03a3\u0394 of {mc.n} machines, {name} tolerances, seed "
                          f"{args.seed}", fontsize=9)
        plots.beta_histogram(mc.machines["beta_opt_deg"], rng, axes[1])
        axes[1].set_title(f"\u03b2* per machine ({mc.n - mc.counts('adjusted')['failed']} that "
                          "run; red: at a bound of the searched range)", fontsize=9)
        plots.save(fig, out / f"montecarlo_{name}.png", args.figure_format)

        # second order: the AB x BE interaction behind ST >> S1 made visible (N (2D + 2) rows)
        sob = needle_sobol(p, ts, args.n_sobol, args.seed, n_jobs=args.n_jobs,
                           progress=args.progress, second_order=True)
        sset = {**base, "base samples N": args.n_sobol, "seed": args.seed,
                "intervals": "95 % bootstrap, 200 resamples"}
        write_table(sob.to_dataframe(), out, f"sobol_{name}", f"Sobol indices, {name} tolerances",
                    sset)
        s2 = sob.second_order_frame().sort_values(["case", "S2"], ascending=[True, False])
        write_table(s2.reset_index(drop=True), out, f"sobol_{name}_second_order",
                    f"Second-order Sobol indices (every pair), {name} tolerances", sset)
        write_table(sob.convergence, out, f"sobol_{name}_convergence",
                    f"Sobol convergence: indices at N/2 against N, {name} tolerances", sset)
        fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
        idx = sob.to_dataframe()
        for ax, case in zip(axes, ("fixed_beta", "adjusted_beta"), strict=True):
            plots.sobol_bars(idx[idx.case == case].reset_index(drop=True), ax,
                             f"\u03a3\u0394, {case.replace('_', ' ')}, {name} tolerances, "
                             f"N = {args.n_sobol}")
        plots.save(fig, out / f"sobol_{name}.png", args.figure_format)

    largest = largest_tolerances(p, ["LF", "LM", "AM", "AB", "BC", "BE", "CD"])
    write_table(largest, out, "largest_tolerances",
                "Largest deviation per parameter and side with SumDelta(beta*) <= 10 um",
                {"guide": guide, "searched up to": "1 mm (reaches_max: the limit holds there)",
                 "units": "mm"})

    # the allocation starts from the recommended set's shape, the guide comparison draws from the
    # base set; a run on other sets uses its first set for both
    first = next(iter(sets))
    alloc_set = "recommended" if "recommended" in sets else first
    guide_set = "base" if "base" in sets else first
    alloc = allocate(p, sets[alloc_set], target=0.9973, n=args.n_alloc,
                     seed=args.seed, steps=10)
    write_table(alloc.to_dataframe(), out, "allocation",
                "Tolerance allocation for 99.73 % yield after beta adjustment",
                {"cost model": "sum of 1/t_i (equal weights), RSS shape t_i ~ (c_i/s_i^2)^(1/3)",
                 "yield check": f"Monte-Carlo, {args.n_alloc} machines, seed {args.seed}, "
                 "uniform within +/- t_i",
                 "achieved yield": f"{alloc.yield_:.4f}", "guide": guide,
                 "reference set": f"{alloc_set} ({tol_text(sets[alloc_set])})",
                 "units": "tolerance mm, slope um per mm"}, floatfmt=".5f")

    guides = compare_guides(p, sets[guide_set], args.n_guides, args.seed,
                            n_jobs=args.n_jobs)
    write_table(guides, out, "guides", f"Guide settings compared ({guide_set} tolerances)",
                {"machines per setting": args.n_guides, "seed": args.seed,
                 "tolerance set": f"{guide_set} ({tol_text(sets[guide_set])})",
                 "units": "shift um, angles deg, SumDelta um, yields fractions"})
    write_text_atomic(out / "montecarlo_summary.json", to_json(summary))

    record = run_record(started, {"mechanism": "208 needle drive", "params": as_dict(p),
                     "tolerance_sets": {k: v.as_dict() for k, v in sets.items()},
                     "seed": args.seed, "n_mc": args.n_mc, "n_sobol": args.n_sobol,
                     "n_alloc": args.n_alloc, "n_guides": args.n_guides, "n_jobs": args.n_jobs,
                     "beta_search_range_deg": [10.0, 35.0], "limit_um": 10.0})
    write_text_atomic(out / "run.json", to_json(record))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
