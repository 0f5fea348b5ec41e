"""Nominal 208 needle drive: figures, d(phi) at beta* and the window, SumDelta against beta.

    python studies/needle_208_nominal.py [--out reports]

Writes reports/needle_208/{nominal,deviation,sum_delta_vs_beta}.{csv,md}, deviation.png,
sum_delta_vs_beta.png (index.md is written by needle_208_tolerances.py).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.needle_208.single import deviation_table, nominal_figures
from sewtol.reports import plots
from sewtol.reports.tables import write_table


def main(argv=None) -> None:
    ap = plots.study_parser(__doc__, seed=None, figures=True)
    args = ap.parse_args(argv)
    out = Path(args.out) / "needle_208"

    p = Needle208.nominal()
    fig = nominal_figures(p)
    guide = (f"fixed, through ({p.guide_x:.3f}, {p.guide_y:.3f}) mm at {p.guide_angle:.4f} deg "
             f"from the vertical, shift {p.guide_shift_um:g} um")
    settings = {"mechanism": "208 needle drive, reconstructed nominal (calibration.md)",
                "guide": guide}
    write_table(fig.to_dataframe(), out, "nominal", "Nominal figures", settings, floatfmt=".4f")

    curves = {}
    for label, beta in [(f"\u03b2* = {fig.beta_opt_deg:.2f}\u00b0", fig.beta_opt_deg),
                        (f"window low {fig.window_deg[0]:.2f}\u00b0", fig.window_deg[0]),
                        (f"window high {fig.window_deg[1]:.2f}\u00b0", fig.window_deg[1])]:
        curves[label] = deviation_table(p.override(beta=beta), step_deg=1.0)
    table = pd.DataFrame({"phi_deg": curves[next(iter(curves))]["phi_deg"]})
    for frame, key in zip(curves.values(), ("at_beta_opt", "at_window_low",
                                            "at_window_high"), strict=True):
        table[f"d_um_{key}"] = frame["d_um"]
    write_table(table, out, "deviation", "Deviation d(phi) from the fixed guide (um)",
                {**settings, "betas (deg)": ", ".join(f"{b:.4f}" for b in
                                                      (fig.beta_opt_deg, *fig.window_deg))})
    f, ax = plt.subplots(figsize=(7, 4))
    plots.deviation_vs_crank(curves, ax, limit_um=10.0)
    ax.set_title("208 needle drive: deviation from the fixed guide")
    plots.save(f, out / "deviation.png", args.figure_format)

    betas = np.round(np.arange(15.0, 30.0001, 0.1), 10)
    c, _ = nm.columns(p)
    totals = sb.totals_on_grid(c, betas)[0]
    write_table(pd.DataFrame({"beta_deg": betas, "total_um": totals}), out, "sum_delta_vs_beta",
                "SumDelta against beta, guide fixed", settings)
    f, ax = plt.subplots(figsize=(7, 4))
    plots.sum_delta_vs_beta(betas, totals, fig.beta_opt_deg, fig.window_deg, 10.0, ax)
    ax.set_title("208 needle drive: \u03a3\u0394 against \u03b2, guide fixed")
    plots.save(f, out / "sum_delta_vs_beta.png", args.figure_format)

    print(f"wrote {out}")


if __name__ == "__main__":
    main()
