"""Yield of the 208's adjustment strategies against the measurement error of the needle path.

The fitter sets the compensators from a reading of the needle bar's deviation at 36 handwheel
positions (every 10 deg), each reading with a normal error of sd 0 ... 3 um
(sewtol.measurement_error; typical: about 3 um for a dial gauge graduated in 0.01 mm, 0.5-1 um
for one in 0.001 mm, docs/adjustment.md); the machine's SumDelta is the true one at the settings
chosen. The same machines as the strategies report (seed, n) and the same reading errors at every
sd (only the scale changes). Writes reports/needle_208/strategies_measurement_error.csv/.md/.png.

    python studies/needle_208_measurement.py [--out reports] [--seed 2026] [--n 500]
        [--n-jobs 1]
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from sewtol.measurement_error import DEFAULT_POSITIONS  # noqa: E402
from sewtol.mechanism.spec import Spec  # noqa: E402
from sewtol.mechanisms.needle_208.compensators import default_strategies  # noqa: E402
from sewtol.mechanisms.needle_208.model import Needle208  # noqa: E402
from sewtol.reports import plots  # noqa: E402
from sewtol.reports.tables import write_table  # noqa: E402
from sewtol.studies.strategies import measurement_curve  # noqa: E402
from sewtol.tables.needle_208 import as_mechanism  # noqa: E402
from sewtol.tolerances import NEEDLE_208_SETS  # noqa: E402

SDS_UM = (0.0, 0.25, 0.5, 1.0, 2.0, 3.0)
ROWS = ("beta+shift", "beta+shift+angle", "beta+shift+angle exact")


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=True, figures=True, n=500)
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"
    out.mkdir(parents=True, exist_ok=True)
    p = Needle208.nominal()
    mech = as_mechanism(p)
    rows = {r.name: r for r in default_strategies() if r.name in ROWS}
    curves, frames = {}, []
    for set_name in ("base", "recommended"):
        for name in ROWS:
            c = measurement_curve(mech, NEEDLE_208_SETS[set_name], args.n, args.seed,
                                  rows[name], SDS_UM, DEFAULT_POSITIONS, "SumDelta_um",
                                  Spec("SumDelta_um", 10.0), n_jobs=args.n_jobs, limit_um=10.0)
            curves[(set_name, name)] = c
            frames.append(c.to_dataframe().assign(tolerances=set_name))
    table = pd.concat(frames, ignore_index=True)
    table.insert(0, "tolerances", table.pop("tolerances"))
    write_table(table, out, "strategies_measurement_error",
                "Yield by strategy against the measurement error of the needle path",
                {"n per set": args.n, "seed": args.seed,
                 "machines": "the same machines as strategies.md; the same reading errors at "
                 "every sd (only the scale changes)",
                 "model": f"every compensator set to the optimum of the deviation as read at "
                 f"{DEFAULT_POSITIONS} handwheel positions (every 10 deg), each reading with a "
                 "normal error of this sd; SumDelta the true one at those settings; sd 0 is the "
                 "row of strategies.md (set from the true deviation)",
                 "typical sd": "about 3 um: dial gauge graduated in 0.01 mm; 0.5-1 um: 0.001 "
                 "mm (assumptions, docs/adjustment.md)",
                 "counts": "ok + out_of_spec + cannot_close + dead_point = n"})
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, set_name in zip(axes, ("base", "recommended"), strict=True):
        for name in ROWS:
            plots.yield_vs_measurement_error(curves[(set_name, name)], ax, label=name)
        ax.set_title(f"{set_name} tolerances, {args.n} machines (95 % interval)", fontsize=9)
    fig.tight_layout()
    plots.save(fig, out / "strategies_measurement_error.png", args.figure_format)
    print(table[["tolerances", "strategy", "measurement_sd_um", "yield"]].to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
