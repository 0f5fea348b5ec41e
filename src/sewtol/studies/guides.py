"""Guide settings compared in one table: beta*, SumDelta, window and the Monte-Carlo yields."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..needle import nominal_figures
from ..tolerances import ToleranceSet
from . import beta as sb
from .montecarlo import montecarlo

DEFAULT_VARIANTS = (
    ("nominal", 0.0, 0.0),
    ("shift +50 um", 50.0, 0.0),
    ("shift -50 um", -50.0, 0.0),
    ("angle +0.02 deg", 0.0, 0.02),
    ("angle -0.02 deg", 0.0, -0.02),
)


def compare_guides(nominal, tolerances: ToleranceSet, n: int, seed: int,
                   variants=DEFAULT_VARIANTS, range_deg=sb.DEFAULT_RANGE_DEG,
                   n_jobs: int = 1, progress=False, scheduler=None) -> pd.DataFrame:
    """One row per guide setting (shift um along the guide normal, turn deg about its point)."""
    rows = []
    for label, shift_um, dangle in variants:
        p = nominal.override(guide_shift_um=nominal.guide_shift_um + shift_um,
                             guide_angle=nominal.guide_angle + dangle)
        fig = nominal_figures(p, range_deg)
        mc = montecarlo(p.override(beta=fig.beta_opt_deg), tolerances, n, seed,
                        range_deg=range_deg, n_jobs=n_jobs, progress=progress,
                        scheduler=scheduler)
        rows.append({
            "guide": label, "shift_um": shift_um, "angle_from_vertical_deg": p.guide_angle,
            "beta_opt_deg": fig.beta_opt_deg, "total_um": fig.total_um,
            "window_low_deg": fig.window_deg[0], "window_high_deg": fig.window_deg[1],
            "window_width_deg": fig.window_deg[1] - fig.window_deg[0]
            if np.all(np.isfinite(fig.window_deg)) else np.nan,
            "yield_fixed_beta": mc.yield_of("fixed"), "yield_adjusted_beta": mc.yield_of("adjusted"),
            "failed": mc.failed,
        })
    return pd.DataFrame(rows)
