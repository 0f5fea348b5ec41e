"""Joint clearances of the 208 needle drive: the pins' share of the error and the guide pair as
the criterion.

The needle file (the built-in needle_208) with H7/g6 on 8 mm pins at its seven revolute pairs
(F, L, M, A, B, C, D: the issue's example of a designer's first choice), and an 8 mm needle-bar
guide rod (assumed: the sources give no diameter). Writes reports/needle_208/clearances.md,
clearance_share.csv, clearance_worst.csv, clearance_guide_fits.csv and clearances_run.json.

    python studies/needle_208_clearances.py [--out reports] [--seed 2026] [--n 400]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from sewtol import mechanisms as M
from sewtol.io import write_text_atomic
from sewtol.mechanism import loads
from sewtol.provenance import now, version_record
from sewtol.studies import clearance as K
from sewtol.tolerances import load_toml

PIN_FIT, PIN_DIAMETER_MM, GUIDE_DIAMETER_MM = "H7/g6", 8.0, 8.0
PLAY_LIMIT_UM, TARGET_YIELD = 20.0, 0.95
PINS = "".join(f'\n[[clearances]]\njoint = "{j}"\nfit = "{PIN_FIT}"\ndiameter_mm = '
               f"{PIN_DIAMETER_MM:g}\n" for j in "FLMABCD")
STRATEGIES = ((), ("beta",), ("beta", "guide_shift"))


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
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="reports")
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--n", type=int, default=400)
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
    share.to_csv(folder / "clearance_share.csv", index=False)
    worst.to_csv(folder / "clearance_worst.csv", index=False)
    fits.to_csv(folder / "clearance_guide_fits.csv", index=False)
    reach.to_csv(folder / "clearance_guide.csv", index=False)
    pins = pd.DataFrame({"pair": [c.joint for c in mech.clearances],
                         "fit": [c.fit for c in mech.clearances],
                         "radial_min_um": [1e3 * c.radial_min_mm for c in mech.clearances],
                         "radial_max_um": [1e3 * c.radial_max_mm for c in mech.clearances]})
    write_text_atomic(folder / "clearances.md", report(args, share, worst, fits, reach, pins))
    write_text_atomic(folder / "clearances_run.json", json.dumps({
        "study": "studies/needle_208_clearances.py", "made": now(), "n": args.n,
        "seed": args.seed, "pins": PINS.strip(), "guide_diameter_mm": GUIDE_DIAMETER_MM,
        "play_limit_um": PLAY_LIMIT_UM, "target_yield": TARGET_YIELD,
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
        "- model: rigid links, small clearances, no impact dynamics, no load (the journal's "
        "place is chosen, not found from the joint force); worst case to first order "
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


if __name__ == "__main__":
    main()
