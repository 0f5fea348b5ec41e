"""Joint clearances of the 208 needle drive: the pins' share of the error and the guide pair as
the criterion.

The needle file (the built-in needle_208) with H7/g6 on 8 mm pins at its seven revolute pairs
(F, L, M, A, B, C, D: the issue's example of a designer's first choice), and an 8 mm needle-bar
guide rod (assumed: the sources give no diameter). Writes reports/needle_208/clearances.md,
clearance_share.csv, clearance_worst.csv, clearance_guide_fits.csv, clearance_sobol.csv,
clearance_loaded.csv, clearance_crossings.csv and clearances_run.json.

    python studies/needle_208_clearances.py [--out reports] [--seed 2026] [--n 400]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from sewtol import mechanisms as M
from sewtol.io import write_text_atomic
from sewtol.mechanism import loads
from sewtol.mechanism.kinetostatics import PointLoad
from sewtol.provenance import now, version_record
from sewtol.reports import plots
from sewtol.studies import clearance as K
from sewtol.tolerances import load_toml

PIN_FIT, PIN_DIAMETER_MM, GUIDE_DIAMETER_MM = "H7/g6", 8.0, 8.0
PLAY_LIMIT_UM, TARGET_YIELD = 20.0, 0.95
PINS = "".join(f'\n[[clearances]]\njoint = "{j}"\nfit = "{PIN_FIT}"\ndiameter_mm = '
               f"{PIN_DIAMETER_MM:g}\n" for j in "FLMABCD")
STRATEGIES = ((), ("beta",), ("beta", "guide_shift"))
# the loaded mode's assumed values: the 208's masses are not published; its needle bar is taken
# as the M6's (the new design on the same frame: 0.0136 kg, published); links massless; the
# needle's force is not stated by the sources: 5 N against the bar's motion over the whole turn
# (an assumption, a round value of a needle's penetration and friction); the speeds are the
# source's (main shaft up to 4000-5000 rpm)
BAR_KG, NEEDLE_N, SPEEDS_RPM = 0.0136, 5.0, (4000.0, 5000.0)
SOBOL_N = 256  # base samples of the Sobol share (21 inputs: 23 x 256 machines per set)


def needle_with_pins():
    text = M.mechanism_file("needle_208").read_text()
    return loads(text + PINS, "sewtol/mechanisms/needle_208/mechanism.toml + H7/g6 pins")


def tolerance_sets(mech, out: Path) -> dict:
    sets = dict(mech.tolerance_sets)
    allocated = out / "needle_208" / "allocated_tolerances.toml"
    if allocated.exists():
        sets.update(load_toml(allocated, mech.parameter_names))
    return sets


def md_table(frame: pd.DataFrame, digits: int = 3) -> str:
    return frame.to_markdown(index=False, floatfmt=f".{digits}f")


def main(argv=None) -> None:
    p = plots.study_parser(__doc__, n=400)
    args = p.parse_args(argv)
    out = Path(args.out)
    folder = out / "needle_208"
    folder.mkdir(parents=True, exist_ok=True)
    mech = needle_with_pins()
    sets = tolerance_sets(mech, out)

    shares, worst = [], None
    for name in ("recommended", "allocated"):
        if name not in sets:
            continue
        s = K.clearance_share(mech, sets[name], args.n, args.seed, adjust=("beta",))
        shares.append(s.cases.assign(tolerances=name, strategy=s.strategy, pins=s.pins))
        worst = s.worst
        worst.attrs["tolerances"] = name
    share = pd.concat(shares, ignore_index=True)
    sobol = pd.concat([K.sobol_share(mech, sets[name], "SumDelta_um", SOBOL_N, args.seed)
                       .sources.assign(tolerances=name)
                       for name in ("recommended", "allocated") if name in sets],
                      ignore_index=True)
    fits, reaching = [], []
    for name, ts in sets.items():
        for adjust in STRATEGIES:
            g = K.guide_criterion(mech, ts, args.n, args.seed, adjust=adjust,
                                  guide_diameter_mm=GUIDE_DIAMETER_MM,
                                  play_limit_um=PLAY_LIMIT_UM, target_yield=TARGET_YIELD)
            fits.append(g.fits.assign(tolerances=name, strategy=g.strategy))
            runs = g.fit_reaching("runs_share")
            both = g.fit_reaching("yield")
            med = g.machines["needed_gap_um"]
            reaching.append({
                "tolerances": name, "strategy": g.strategy,
                "needed_gap_median_um": float(med.median()),
                "needed_gap_q95_um": float(med.quantile(0.95)),
                "failed": int((g.machines["status"] != "ok").sum()),
                "tightest_fit_95pct_run": runs[0] or "none",
                "tightest_fit_95pct_run_and_play": both[0] or "none",
                "loosest_fit_95pct_run_and_play": both[1] or "none"})
    fits = pd.concat(fits, ignore_index=True)
    reach = pd.DataFrame(reaching)
    loaded, crossings = loaded_mode(mech)
    loaded.to_csv(folder / "clearance_loaded.csv", index=False)
    crossings.to_csv(folder / "clearance_crossings.csv", index=False)
    share.to_csv(folder / "clearance_share.csv", index=False)
    worst.to_csv(folder / "clearance_worst.csv", index=False)
    fits.to_csv(folder / "clearance_guide_fits.csv", index=False)
    reach.to_csv(folder / "clearance_guide.csv", index=False)
    pins = pd.DataFrame({"pair": [c.joint for c in mech.clearances],
                         "fit": [c.fit for c in mech.clearances],
                         "radial_min_um": [1e3 * c.radial_min_mm for c in mech.clearances],
                         "radial_max_um": [1e3 * c.radial_max_mm for c in mech.clearances]})
    sobol.to_csv(folder / "clearance_sobol.csv", index=False)
    write_text_atomic(folder / "clearances.md", report(args, share, worst, fits, reach, pins)
                      + sobol_report(args, sobol) + loaded_report(loaded, crossings))
    write_text_atomic(folder / "clearances_run.json", json.dumps({
        "study": "studies/needle_208_clearances.py", "made": now(), "n": args.n,
        "seed": args.seed, "pins": PINS.strip(), "guide_diameter_mm": GUIDE_DIAMETER_MM,
        "play_limit_um": PLAY_LIMIT_UM, "target_yield": TARGET_YIELD,
        "loaded": {"bar_kg": BAR_KG, "needle_force_N": NEEDLE_N, "rpm": list(SPEEDS_RPM)},
        "sobol_n": SOBOL_N,
        "tolerance_sets": {k: v.as_record() for k, v in sets.items()}, **version_record()},
        indent=2) + "\n")


def report(args, share, worst, fits, reach, pins) -> str:
    unit = "um"
    links = worst[worst.source == "links"][f"worst_{unit}"].iloc[0]
    pin_sum = worst[worst.source == "pins"][f"worst_{unit}"].iloc[0]
    lines = [
        "# Joint clearances of the 208 needle drive",
        "",
        f"- pins: {PIN_FIT} on {PIN_DIAMETER_MM:g} mm at the seven revolute pairs F, L, M, A, B, "
        "C, D (the built-in needle file plus [[clearances]]; the needle-bar pin E and the "
        "needle bar's own guide are not pairs of the model)",
        f"- needle-bar guide rod: {GUIDE_DIAMETER_MM:g} mm (assumed; the sources give no "
        f"diameter); play limit at the stitch {PLAY_LIMIT_UM:g} um (assumed); target yield "
        f"{TARGET_YIELD:.0%}",
        f"- machines: {args.n} per tolerance set, seed {args.seed} (the Monte-Carlo's draw); "
        "journals: uniform in their circle, radial clearance uniform between the fit's "
        "smallest and largest, held over the turn (stream SeedSequence(seed, spawn_key=(1,)))",
        "- model: rigid links, small clearances, no impact dynamics; no load in the sections "
        "before the last (the journal's place is chosen, not found from the joint force: the "
        "loaded mode, at the end, finds it); worst case to first order "
        "(sum c_j |J_j|, J_j by central differences of the real model)",
        "",
        "## The pins",
        "",
        md_table(pins, 1),
        "",
        "## Worst case at the nominal machine, links against pins",
        "",
        f"At the crank angle {worst.attrs['q_deg']:.1f} deg, where the two together are "
        "largest, the first-order worst case of the deviation d of E from the guide: the link "
        f"tolerances of the {worst.attrs['tolerances']} set (half-widths) against the pins at "
        f"their largest clearance. Links {links:.2f} um, pins {pin_sum:.2f} um.",
        "",
        md_table(worst, 3),
        "",
        "## Their share of SumDelta after beta adjustment",
        "",
        "`links`: the set's machines with ideal pins; `pins`: nominal links with the journals "
        "random; `both`. Beta re-adjusted on every machine (the needle's exact adjuster where "
        "the journals are centred, the generic one where they are not: the plug-in does not see "
        "them). variance_share: the case's variance over both's.",
        "",
        md_table(share[["tolerances", "case", "n", "failed", "mean", "std", "within_limit",
                        "yield", "variance_share"]], 3),
        "",
        "## The guide pair as the criterion",
        "",
        "Per machine after adjustment: the journals let E lie within W of its path, W = sum "
        "c_j |J_j| (pins at their smallest clearance for binding, largest for play); the guide "
        "lets it lie within g/2 of the rod's axis. The machine runs without binding when the two "
        "overlap at every crank angle: it needs a diametral guide gap of 2 max(0, max(|d| - "
        "W_min)). The play at the stitch (E lowest) is the overlap's length with the fit's "
        "largest gap. A fit's machines run when the needed gap is within its smallest "
        "clearance.",
        "",
        md_table(reach, 1),
        "",
        "Per fit (runs: needed gap within the fit's smallest clearance; play_ok: play at the "
        f"stitch <= {PLAY_LIMIT_UM:g} um with its largest; yield: both):",
        "",
        md_table(fits[["tolerances", "strategy", "fit", "gap_min_um", "gap_max_um", "runs",
                       "binds", "failed", "play_ok", "play_median_um", "runs_share",
                       "yield"]], 3),
        "",
    ]
    return "\n".join(lines)


def sobol_report(args, sobol: pd.DataFrame) -> str:
    lines = [
        "## Their share by Sobol indices, SumDelta as built",
        "",
        f"The journals as variables beside the links (uniform over the disc of the fit's largest "
        f"clearance: |r|^2 and phi uniform), SumDelta without adjustment, {SOBOL_N} base "
        f"samples, seed {args.seed}; the indices summed over each source (a source's share of "
        "the variance lies between its S1 and its ST; SumDelta, max d + max -d, is far from "
        "additive, so the two differ much).",
        "",
        md_table(sobol[["tolerances", "source", "S1", "ST"]], 3),
        "",
    ]
    return "\n".join(lines)


def load_cases(mech) -> dict:
    """The loaded mode's load cases on the needle-bar pin E (see BAR_KG, NEEDLE_N)."""
    guide = 90.0 - mech.nominal_values()["guide_angle"]  # the guide's direction from +x
    bar = PointLoad("E", mass_kg=BAR_KG, doc="needle bar: weight and inertia")
    needle = PointLoad("E", force_N=NEEDLE_N, direction_deg=guide, against_motion=True,
                       doc="needle force against the bar's motion")
    return {"bar": (bar,), f"bar + needle {NEEDLE_N:g} N": (bar, needle)}


def loaded_mode(mech) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The nominal machine's pins in loaded mode (largest clearance), per speed and load case:
    per pair the largest force, the crossings, the largest move of d; per case d's move and
    SumDelta with the journals where the load puts them."""
    output = "SumDelta_um"
    d0 = K.signal(mech, mech.state(), output)[0]
    wc = K.worst_case(mech, None, output).total[0]
    rows, cross = [], []
    for rpm in SPEEDS_RPM:
        for case, ld in load_cases(mech).items():
            res = K.loaded(mech, None, output, ld, rpm=rpm)
            d = d0 + res.total[0]
            rows.append({"rpm": rpm, "load": case, "pair": "all",
                         "force_max_N": np.nan, "crossings": sum(len(v[0]) for v in
                                                                 res.crossings_deg.values()),
                         "move_min_um": float(res.total[0].min()),
                         "move_max_um": float(res.total[0].max()),
                         "worst_case_max_um": float(wc.max()),
                         "SumDelta_ideal_um": float(max(d0.max(), 0) + max(-d0.min(), 0)),
                         "SumDelta_loaded_um": float(max(d.max(), 0) + max(-d.min(), 0))})
            for j in res.by_pair:
                f = np.abs(res.force_N[j][0])
                rows.append({"rpm": rpm, "load": case, "pair": j,
                             "force_max_N": float(f.max()), "force_min_N": float(f.min()),
                             "crossings": len(res.crossings_deg[j][0]),
                             "move_min_um": float(res.by_pair[j][0].min()),
                             "move_max_um": float(res.by_pair[j][0].max())})
                cross += [{"rpm": rpm, "load": case, "pair": j, "q_deg": q}
                          for q in res.crossings_deg[j][0]]
    return pd.DataFrame(rows), pd.DataFrame(cross, columns=["rpm", "load", "pair", "q_deg"])


def loaded_report(loaded: pd.DataFrame, crossings: pd.DataFrame) -> str:
    summary = loaded[loaded.pair == "all"]
    per_pair = loaded[loaded.pair != "all"]
    angles = (crossings.groupby(["rpm", "load", "pair"], sort=False)["q_deg"]
              .apply(lambda q: ", ".join(f"{v:.1f}" for v in q)).reset_index()
              .rename(columns={"q_deg": "crossing_angles_deg"}))
    lines = [
        "## Loaded mode: the journals where the joint forces put them",
        "",
        "The nominal machine, each journal on the rim of its largest clearance in the direction "
        "of the force it presses its bearing with, from a quasi-static force analysis "
        "(kinetostatics at a uniform crank speed: virtual work through the pair parameters; the "
        "same analysis reproduces the M6 needle's Newton-Euler reactions to 1e-6 N). Assumed "
        f"values: the needle bar at E, {BAR_KG:g} kg (the M6's published needle bar, the new "
        "design on the same frame; the 208's masses are not published), its weight and inertia; "
        f"links massless; a needle force of {NEEDLE_N:g} N along the guide against the bar's "
        "motion over the whole turn (the sources state none); the guide holds the bar's "
        "direction and carries no side load (the drive runs in its clearance). move: the "
        "first-order move of d (sum_j c_j J_j . u_j) against the worst case W.",
        "",
        md_table(summary.drop(columns=["pair", "force_max_N", "force_min_N"]), 2),
        "",
        "Per pair: the force's range over the turn, how often its direction reverses (the "
        "journal crosses its clearance, an impact the model does not follow) and its term of "
        "the move:",
        "",
        md_table(per_pair.drop(columns=["worst_case_max_um", "SumDelta_ideal_um",
                                        "SumDelta_loaded_um"]), 2),
        "",
        "Crossing angles (crank angle, deg):",
        "",
        md_table(angles, 1) if not angles.empty else "none",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
