"""The two outputs every needle tolerance study needs, for a batch of machines.

fixed: SumDelta with beta left at the nominal machine's beta* (no adjustment at assembly);
adjusted: SumDelta after beta is re-optimised on each machine (the assembly adjustment): the
exact global optimum in the range (mechanisms/needle_208/adjust.py), the centre of its plateau where SumDelta
is flat. Both keep the guide fixed unless other compensators are passed. A machine that cannot
assemble gives NaN and is counted by the study.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError
from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import adjust as ad
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208 import model as nd


@dataclass(frozen=True)
class NeedleOutputs:
    total_fixed_um: np.ndarray
    beta_opt_deg: np.ndarray
    total_adjusted_um: np.ndarray
    plus_adjusted_um: np.ndarray
    minus_adjusted_um: np.ndarray
    # the plateau of the adjusted optimum (beta_opt_deg is its centre), whether it reaches the
    # end of the range, and the full per-machine result (every compensator, status)
    beta_low_deg: np.ndarray | None = None
    beta_high_deg: np.ndarray | None = None
    beta_at_bound: np.ndarray | None = None
    adjusted: ad.AdjustResult | None = None


def evaluate(nominal, deviations: dict[str, np.ndarray], adjust: bool = True,
             range_deg=sb.DEFAULT_RANGE_DEG, grid_step_deg: float = 1.0,
             engine: str = "numba", compensators: dict | None = None) -> NeedleOutputs:
    """SumDelta fixed and adjusted for machines nominal + deviations.

    The adjusted figures are the exact joint optimum of the compensators (default: beta in
    range_deg; e.g. {"beta": (10, 35), "guide_shift_um": (-100, 100)}): engine="numba" runs
    mechanisms/needle_208/kernels/window.py, engine="numpy" the reference in mechanisms/needle_208/adjust.py.
    grid_step_deg is kept for compatibility (the exact optimum needs no grid).
    """
    if engine not in ("numba", "numpy"):
        raise ParameterError("engine", "must be 'numba' or 'numpy'", engine)
    m = len(next(iter(deviations.values())))
    batch = P.with_deviations(nominal, deviations)
    c, _ = nm.columns(batch)
    c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
    if compensators is None:
        sb.check_range(range_deg, sb.DEFAULT_LIMIT_UM)
        compensators = {"beta": tuple(map(float, range_deg))}
    feas = nm.feasibility(c)
    if engine == "numpy":
        fixed = nm.deviation_figures(c, feas).total_um
    else:
        fixed = _fixed_numba(c, feas)
    if not adjust:
        nan = np.full(m, np.nan)
        return NeedleOutputs(fixed, nan, nan, nan, nan)
    r = ad.optimise(c, compensators, engine=engine, feas=feas)
    return NeedleOutputs(fixed, r.settings["beta"], r.total_um, r.plus_um, r.minus_um,
                         r.low["beta"], r.high["beta"], r.at_bound["beta"], r)


def fixed_sumdelta_um(c: dict[str, np.ndarray]) -> np.ndarray:
    """SumDelta (um) of machines given as parameter columns (n, 1), beta as it is: the exact
    extremes on the rocker interval by the fused kernel; NaN where a machine does not run."""
    return _fixed_numba(c, nm.feasibility(c))


def _fixed_numba(c, rocker):
    from sewtol.mechanisms.needle_208.kernels import fused as K
    from sewtol.mechanisms.needle_208.kernels import window as KW

    packed = K.pack(c)
    # the rocker interval depends on the first four-bar only (not on beta)
    first_ok = (rocker.miss_LMA_mm == 0) & (rocker.transmission_LMA_deg >= nd.DEAD_POINT_DEG)
    r_lo = np.where(first_ok, rocker.lo, np.nan)
    r_hi = np.where(np.isnan(r_lo), np.nan, rocker.hi)
    fixed_ok = rocker.ok
    dev = KW.fixed_batch(packed, c["beta"][:, 0].copy(), np.where(fixed_ok, r_lo, np.nan),
                         np.where(fixed_ok, r_hi, np.nan))
    return dev[:, 0] + dev[:, 1]
