"""The two outputs every needle tolerance study needs, for a batch of machines.

fixed: SumDelta with beta left at the nominal machine's beta* (no adjustment at assembly);
adjusted: SumDelta after beta is re-optimised on each machine (the assembly adjustment).
Both keep the guide fixed. A machine that cannot assemble gives NaN and is counted by the study.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..mechanisms import needle_208 as nd
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
             range_deg=sb.DEFAULT_RANGE_DEG, grid_step_deg: float = 1.0,
             engine: str = "numba") -> NeedleOutputs:
    """SumDelta fixed and adjusted for machines nominal + deviations.

    engine="numba" runs the fused kernel (kernels/needle_numba.py, warm-started search);
    engine="numpy" the batched reference (studies/beta.py). Both use the same exact extremes.
    """
    if engine not in ("numba", "numpy"):
        raise ParameterError("engine", "must be 'numba' or 'numpy'", engine)
    m = len(next(iter(deviations.values())))
    batch = P.with_deviations(nominal, deviations)
    c, _ = nm.columns(batch)
    c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
    if engine == "numpy":
        fixed = nm.deviation_figures(c).total_um
        if not adjust:
            nan = np.full(m, np.nan)
            return NeedleOutputs(fixed, nan, nan, nan, nan)
        opt = sb.optimise_beta_columns(c, range_deg, grid_step_deg=grid_step_deg, window=False)
        return NeedleOutputs(fixed, opt.beta_deg, opt.total_um, opt.plus_um, opt.minus_um)
    return _evaluate_numba(c, m, adjust, range_deg, grid_step_deg)


def _evaluate_numba(c, m, adjust, range_deg, grid_step_deg):
    from ..kernels import needle_numba as K

    lo, hi = float(range_deg[0]), float(range_deg[1])
    sb.check_range((lo, hi), sb.DEFAULT_LIMIT_UM)
    n_beta = max(int(np.ceil((hi - lo) / grid_step_deg)) + 1, 3)
    packed = K.pack(c)
    # the rocker interval depends on the first four-bar only (not on beta)
    rocker = nm.feasibility(c)
    first_ok = (rocker.miss_LMA_mm == 0) & (rocker.transmission_LMA_deg >= nd.DEAD_POINT_DEG)
    r_lo = np.where(first_ok, rocker.lo, np.nan)
    r_hi = np.where(np.isnan(r_lo), np.nan, rocker.hi)
    fixed_ok = rocker.ok
    dev = K.deviation_batch(packed, c["beta"][:, 0].copy(), np.where(fixed_ok, r_lo, np.nan),
                            np.where(fixed_ok, r_hi, np.nan), 48)
    fixed = dev[:, 0] + dev[:, 1]
    if not adjust:
        nan = np.full(m, np.nan)
        return NeedleOutputs(fixed, nan, nan, nan, nan)
    out = K.optimise_beta_batch(packed, r_lo, r_hi, lo, hi, n_beta, 1e-7, 48, True)
    return NeedleOutputs(fixed, out[:, 0], out[:, 1] + out[:, 2], out[:, 1], out[:, 2])
