"""M6 needle drive on the 208 frame: reconstruction, kinematics, reactions, travel tolerances.

    python studies/m6_needle_report.py [--out reports] [--seed 2026] [--n-mc 10000]
        [--samples 3600]

Writes reports/m6_needle/ (tables as CSV + Markdown, motion.png, index.md, run.json).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from sewtol.io import to_json, write_text_atomic  # noqa: E402
from sewtol.mechanism import load as load_mechanism  # noqa: E402
from sewtol.mechanisms.m6_needle import model as m6  # noqa: E402
from sewtol.mechanisms.params import as_dict  # noqa: E402
from sewtol.provenance import now, run_record  # noqa: E402
from sewtol.reports import plots  # noqa: E402
from sewtol.reports.tables import write_table  # noqa: E402
from sewtol.studies import montecarlo as MC  # noqa: E402
from sewtol.studies import scan as S  # noqa: E402
from sewtol.studies import summaries as SU  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "m6_needle.toml"

ORIGIN = {
    "crank_mm": "published (AO1)", "crank_phase_deg": "assumed (q counted from the crank)",
    "crank_sense": "assumed (counter-clockwise; maxima do not depend on it)",
    "pivot_mm": "published (O1O2)", "pivot_deg": "solved (O2 arm_mm left of the needle bar)",
    "slot_offset_mm": "assumed (slot through O2)", "arm_mm": "solved (travel 24.2 mm)",
    "arm_deg": "assumed (arm horizontal in the middle of the swing)",
    "rod_mm": "solved (middle of the travel at y = 13.3)",
    "guide_x_mm": "published (X of the needle-bar point)",
    "guide_y_mm": "published (Y of the needle-bar point)", "guide_deg": "assumed (vertical)",
    "rod_branch": "assumed (J below B)", "lever_com_mm": "assumed (middle of O2-B)",
    "shaft_kg": "published", "shaft_kgm2": "published (no effect at uniform speed)",
    "lever_kg": "published", "lever_kgm2": "published (about its centre of mass)",
    "bar_kg": "published", "bar_kgm2": "published (no effect: the needle bar does not turn)",
    "rpm": "published",
}


# the bound the report states for the balance (N) and the energy check (relative)
CHECK_BOUND = 1e-12


def figures_row(rec: m6.Reconstruction, samples: int) -> dict:
    p = rec.params
    fig = m6.evaluate(p, samples)
    R = m6.reactions(p, samples)
    o2 = p.pivot
    row = {"layout": rec.name, "reading_of_point": rec.reading,
           "pivot_x_mm": o2.real, "pivot_y_mm": o2.imag, "arm_mm": float(p.arm_mm),
           "arm_tilt_deg": rec.arm_tilt_deg, "rod_mm": float(p.rod_mm),
           "travel_mm": float(fig.travel_mm), "speed_max_m_s": float(fig.speed_max_m_s),
           "accel_max_m_s2": float(fig.accel_max_m_s2), **R.peaks(),
           "lever_J_over_mL2_12": float(p.lever_kgm2) / (float(p.lever_kg) * (float(p.arm_mm)
                                                                               * 1e-3) ** 2 / 12),
           # the checks as bounds: the residuals themselves are rounding noise (about 5e-14 N
           # and 1e-15) whose digits differ between CPUs, so the tables print the bound only
           "balance_below_1e-12_N": bool(np.max(R.residual_N) < CHECK_BOUND),
           "energy_check_below_1e-12": bool(np.max(np.abs(R.torque_Nm - R.energy_torque_Nm))
                                            / np.max(np.abs(R.torque_Nm)) < CHECK_BOUND)}
    return row


def scan_travel(mech, ts) -> pd.DataFrame:
    """Each parameter at +tol and -tol (sewtol.studies.scan): travel and its change (mm) and the
    central difference over the limits, sorted by the larger |change|."""
    res = S.scan(mech, ts, ["travel_mm"])
    r, status = SU.scan_table(res, ["travel_mm"]), res.rows["status"].to_numpy()
    up, lo = r[r["side"] == "upper"].reset_index(drop=True), r[r["side"] == "lower"].reset_index(
        drop=True)
    frame = pd.DataFrame({
        "parameter": up["param"], "tolerance": up["deviation"],
        "travel_upper_mm": up["travel_mm"], "travel_lower_mm": lo["travel_mm"],
        "change_upper_mm": up["change_travel_mm"], "change_lower_mm": lo["change_travel_mm"],
        "slope_per_unit": (up["travel_mm"] - lo["travel_mm"]) / (up["deviation"]
                                                                 - lo["deviation"]),
        "status_upper": status[0::2], "status_lower": status[1::2]})
    order = np.argsort(-np.maximum(np.abs(frame["change_upper_mm"]),
                                   np.abs(frame["change_lower_mm"])).to_numpy(), kind="stable")
    return frame.iloc[order].reset_index(drop=True)


def montecarlo_travel(mech, ts, n: int, seed: int) -> pd.DataFrame:
    """n machines of the one sampler (sewtol.studies.montecarlo, the exact travel): the counts
    by status and the travel's summary over the machines that run."""
    m = MC.montecarlo(mech, ts, n, seed, ["travel_mm"], fast=True).machines
    f = SU.output_summary(m, ["travel_mm"], (0.00135, 0.5, 0.99865), m["status"] == "ok")
    counts = {s: int((m["status"] == s).sum()) for s in ("ok", "cannot_close", "dead_point")}
    return pd.DataFrame([{"n": n, **counts, **{f"{k}_mm": f.iloc[0][k] for k in (
        "mean", "std", "p0.135", "p50", "p99.865", "min", "max")}}])


def main(argv=None) -> None:
    ap = plots.study_parser(__doc__, n_mc=10_000, samples=3600)
    args = ap.parse_args(argv)
    started = now()
    out = Path(args.out) / "m6_needle"
    p = m6.M6Needle()
    rec = m6.reconstruct()
    settings = {"speed": f"{p.rpm:g} rpm, uniform crank speed",
                "samples": f"{args.samples} crank angles per turn (travel: exact, from the "
                           "lever's closed-form extremes)",
                "frame": "origin at the main shaft O1, x right, y up, mm"}

    # layout
    layout = pd.DataFrame({"parameter": list(as_dict(p)),
                           "value": [float(v) for v in as_dict(p).values()],
                           "origin": [ORIGIN[k] for k in as_dict(p)]})
    write_table(layout, out, "layout", "Reconstructed layout of the M6 needle drive (nominal)",
                {**settings, "lever pivot O2 (mm)": f"({p.pivot.real:.4f}, {p.pivot.imag:.4f})",
                 "travel residual (mm)": f"{rec.residual_travel_mm:.2e}",
                 "needle-bar point residual (mm)": f"{rec.residual_point_mm:.2e}"},
                floatfmt=".6f")

    # alternatives and the spread over those that fit equally well
    alts = m6.alternatives()
    rows = pd.DataFrame([figures_row(a, args.samples) for a in alts])
    write_table(rows, out, "alternatives",
                "Layouts meeting travel 24.2 mm and the point (50.1, 13.3) equally well, and the "
                "other reading of the point", {**settings, "units": "mm, deg, m/s, m/s^2, N, N m",
                                               "lever_J_over_mL2_12": "published lever inertia "
                                               "over that of a uniform bar as long as the arm"},
                floatfmt=".4f")
    fitting = rows[rows["layout"] != "point_from_pivot"]
    cols = ["travel_mm", "speed_max_m_s", "accel_max_m_s2", *m6.REACTIONS, "torque_max_Nm"]
    spread = pd.DataFrame({"output": cols, "nominal": rows.iloc[0][cols].to_numpy(float),
                           "min": fitting[cols].min().to_numpy(float),
                           "max": fitting[cols].max().to_numpy(float)})
    spread["published"] = [m6.PUBLISHED.get(c, np.nan) for c in cols]
    write_table(spread, out, "spread", f"Spread of the outputs over the {len(fitting)} layouts "
                "that meet travel and point", settings, floatfmt=".4f")

    # residuals against the published figures
    nominal_row, other_row = rows.iloc[0], rows.iloc[-1]
    fitted_row = rows[rows["layout"] == "pivot_above_tilt_fitted_R50"].iloc[0]
    res = []
    for c in ["travel_mm", "speed_max_m_s", "accel_max_m_s2", *m6.REACTIONS]:
        pub = m6.PUBLISHED[c]
        res.append({"figure": c, "published": pub, "model": nominal_row[c],
                    "residual": nominal_row[c] - pub,
                    "residual_pct": 100 * (nominal_row[c] - pub) / pub,
                    "model_tilt_fitted_R50": fitted_row[c],
                    "model_point_from_pivot": other_row[c],
                    "residual_point_from_pivot": other_row[c] - pub})
    write_table(pd.DataFrame(res), out, "residuals",
                "Model against the published figures (residual = model - published)",
                {**settings, "model": "nominal reconstruction (travel 24.2 mm)",
                 "model_tilt_fitted_R50": f"the same with the arm tilted "
                 f"{fitted_row['arm_tilt_deg']:.3f} deg, the tilt that gives the published R50",
                 "model_point_from_pivot": "the point (50.1, 13.3) read as the lever's pin "
                 "from O2 (travel not imposed)",
                 "reactions": "numbering 0 frame, 1 main-shaft bearing, 2 main shaft with crank, "
                 "3 block (massless), 4 lever, 5 needle bar; rod massless; no needle load"},
                floatfmt=".3f")

    # where the lever's centre of mass sits (not published) moves the crank-side reactions
    com = []
    for frac in (0.0, 0.25, 0.5, 0.75):
        pk = m6.reactions(p.override(lever_com_mm=frac * float(p.arm_mm)), args.samples).peaks()
        com.append({"lever_com_mm": frac * float(p.arm_mm), "fraction_of_arm": frac, **pk})
    write_table(pd.DataFrame(com), out, "lever_com",
                "Peak reactions against the lever's centre of mass on the arm O2-B (nominal layout)",
                {**settings, "nominal": "0.5 (a uniform bar: the published inertia is 0.95 of "
                 "m L^2 / 12 with L = arm_mm)"}, floatfmt=".3f")

    # over a turn
    mo = m6.motion(p, 360)
    R = m6.reactions(p, 360)
    turn = mo.to_dataframe().merge(R.magnitudes(), on="phi_deg")
    turn["energy_torque_Nm"] = R.energy_torque_Nm
    write_table(turn, out, "turn", "Needle bar and joint reactions over a turn (1 deg steps)",
                {**settings, "needle_s_mm": "J along the guide from (50.1, 13.3), + up"},
                floatfmt=".4f")
    f, axes = plt.subplots(4, 1, figsize=(7, 9), sharex=True)
    axes[0].plot(turn["phi_deg"], turn["needle_s_mm"], color="C0")
    axes[0].set_ylabel("needle bar s (mm)")
    axes[0].set_title(f"M6 needle drive at {p.rpm:g} rpm: travel {float(m6.travel_mm(p)):.2f} mm",
                      fontsize=10)
    axes[1].plot(turn["phi_deg"], turn["v_along_m_s"], color="C1")
    axes[1].axhline(4.0, color="0.4", ls="--", lw=0.8, label="published max 4 m/s")
    axes[1].axhline(-4.0, color="0.4", ls="--", lw=0.8)
    axes[1].set_ylabel("velocity (m/s)")
    axes[2].plot(turn["phi_deg"], turn["a_along_m_s2"], color="C2")
    axes[2].axhline(1640, color="0.4", ls="--", lw=0.8, label="published max 1640 m/s^2")
    axes[2].axhline(-1640, color="0.4", ls="--", lw=0.8)
    axes[2].set_ylabel("acceleration (m/s^2)")
    styles = {"R12_N": ("C0", "--"), "R34_N": ("C2", "-"), "R40_N": ("C3", "-"),
              "R45_N": ("C4", "-"), "R50_N": ("C5", "-")}
    for k, (c, ls) in styles.items():  # R23 = R34 (massless block); R12 dashed on top of it
        label = k.replace("_N", "") + (" = R23" if k == "R34_N" else "")
        axes[3].plot(turn["phi_deg"], turn[k], color=c, ls=ls, lw=1, label=label,
                     zorder=3 if k == "R12_N" else 2)
    axes[3].set_ylim(0, 1.35 * turn[list(styles)].to_numpy().max())
    axes[3].set_ylabel("reaction (N)")
    axes[3].set_xlabel("crank angle q (deg, counter-clockwise from +x)")
    axes[3].legend(fontsize=7, ncol=5, loc="upper center")
    for ax in axes:
        ax.grid(True, lw=0.3)
        ax.set_xlim(0, 360)
        ax.set_xticks(np.arange(0, 361, 60))
    for ax in axes[1:3]:
        ax.legend(fontsize=7, loc="lower right")
    plots.save(f, out / "motion.png")

    # tolerances of the travel: the file's illustrative set (+/- limits, uniform) through the
    # generic scan and Monte-Carlo, the travel exact by the folder's kernel plug-in
    mech = load_mechanism(EXAMPLE)
    ts = mech.tolerance_sets["illustrative"]
    tol = {t.param: t.upper for t in ts.items}
    tset = {**settings, "tolerance set": "illustrative (mechanisms/m6_needle/mechanism.toml; the source "
            "gives none): " + ", ".join(f"{k} +/-{v:g}" for k, v in tol.items())}
    write_table(scan_travel(mech, ts), out, "scan_travel",
                "Needle travel with each parameter at its limits (sorted by effect)", tset,
                floatfmt=".6f")
    write_table(montecarlo_travel(mech, ts, args.n_mc, args.seed), out, "montecarlo_travel",
                f"Needle travel over {args.n_mc} machines (uniform within the limits)",
                {**tset, "seed": args.seed, "machines": "the one sampler (sewtol.law.InputLaw)",
                 "std_mm": "ddof 1"}, floatfmt=".5f")

    rn = rows.iloc[0]
    index = [
        "# M6 needle drive on the 208 frame: reports",
        "",
        f"Reconstructed layout (docs/m6_needle.md): lever pivot O2 = ({p.pivot.real:.3f}, "
        f"{p.pivot.imag:.3f}) mm, arm O2-B {float(p.arm_mm):.4f} mm, rod {float(p.rod_mm):.4f} "
        f"mm; travel {rn['travel_mm']:.6f} mm, needle-bar pin in the middle of its travel at "
        "(50.1, 13.3).",
        f"At {p.rpm:g} rpm: largest speed {rn['speed_max_m_s']:.3f} m/s (published about 4), "
        f"acceleration {rn['accel_max_m_s2']:.0f} m/s^2 (published about 1640). The published "
        "speed and acceleration belong to a travel of about 16 mm: read as the lever's pin "
        f"51.84 mm from O2, the point gives {other_row['speed_max_m_s']:.2f} m/s, "
        f"{other_row['accel_max_m_s2']:.0f} m/s^2 and {other_row['travel_mm']:.2f} mm.",
        "Peak reactions (N): " + ", ".join(f"{k.replace('_N', '')} {rn[k]:.1f} "
                                           f"({m6.PUBLISHED[k]:g})" for k in m6.REACTIONS)
        + " (published in brackets).",
        "Checks: force and moment balance of every body "
        + ("below 1e-12 N" if rn["balance_below_1e-12_N"] else "NOT below 1e-12 N")
        + "; driving torque from the linear system against d(energy)/dt / omega "
        + ("below 1e-12 (relative)." if rn["energy_check_below_1e-12"] else
           "NOT below 1e-12 (relative)."),
        "",
        "- [layout.md](layout.md): every parameter and where it comes from",
        "- [residuals.md](residuals.md): the model against every published figure",
        "- [alternatives.md](alternatives.md), [spread.md](spread.md): layouts that fit equally "
        "well and the spread of the outputs over them",
        "- [lever_com.md](lever_com.md): reactions against the lever's (unpublished) centre of "
        "mass",
        "- [turn.md](turn.md), motion.png: needle bar and reactions over a turn",
        "- [scan_travel.md](scan_travel.md), [montecarlo_travel.md](montecarlo_travel.md): "
        "travel over an illustrative tolerance set",
    ]
    write_text_atomic(out / "index.md", "\n".join(index) + "\n")
    record = run_record(started, {"mechanism": "M6 needle drive (reconstruction)",
                                  "params": as_dict(p), "tolerances": tol, "seed": args.seed,
                                  "n_mc": args.n_mc, "samples": args.samples})
    write_text_atomic(out / "run.json", to_json(record))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
