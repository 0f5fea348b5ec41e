"""The two outputs every needle tolerance study needs, for a batch of machines.

fixed: SumDelta with beta left at the nominal machine's beta* (no adjustment at assembly);
adjusted: SumDelta after beta is re-optimised on each machine (the assembly adjustment).
Both keep the guide fixed. A machine that cannot assemble gives NaN and is counted by the study.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mechanisms import params as P
from ..metrics import needle as nm
from . import beta as sb


@dataclass(frozen=True)
class NeedleOutputs:
    total_fixed_um: np.ndarray
    beta_opt_deg: np.ndarray
    total_adjusted_um: np.ndarray
    plus_adjusted_um: np.ndarray
    minus_adjusted_um: np.ndarray


def evaluate(nominal, deviations: dict[str, np.ndarray], adjust: bool = True,
             range_deg=sb.DEFAULT_RANGE_DEG, grid_step_deg: float = 1.0) -> NeedleOutputs:
    """SumDelta fixed and adjusted for machines nominal + deviations."""
    m = len(next(iter(deviations.values())))
    batch = P.with_deviations(nominal, deviations)
    c, _ = nm.columns(batch)
    c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
    fixed = nm.deviation_figures(c).total_um
    if not adjust:
        nan = np.full(m, np.nan)
        return NeedleOutputs(fixed, nan, nan, nan, nan)
    opt = sb.optimise_beta_columns(c, range_deg, grid_step_deg=grid_step_deg, window=False)
    return NeedleOutputs(fixed, opt.beta_deg, opt.total_um, opt.plus_um, opt.minus_um)
