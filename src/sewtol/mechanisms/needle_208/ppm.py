"""The needle's SumDelta after the assembly adjustment as a rare-event LimitState
(sewtol.studies.rare_event estimates its failures per million).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import ParameterError
from sewtol.tolerances import ToleranceSet, needle_set

if TYPE_CHECKING:
    from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.studies.rare_event import LimitState, StandardNormalMap

# --------------------------------------------------------------------------- the needle


NEEDLE_MODES = ("cannot assemble", "dead point")
ADJUSTMENTS = ("none", "beta")


def needle_limit_state(nominal: Needle208, tolerances: ToleranceSet | str, limit_um: float = 10.0,
                       adjust: str = "beta", range_deg: tuple[float, float] | None = None,
                       engine: str = "numba") -> LimitState:
    """SumDelta of the 208 needle drive after the assembly adjustment, as a LimitState.

    adjust "beta": beta re-optimised per machine in range_deg (total_adjusted_um); "none": beta
    left at the nominal beta* (total_fixed_um). A machine without a value is "cannot assemble"
    (a dyad misses at the nominal beta) or else "dead point" (a dyad passes within the dead-point
    angle, or no beta in the range assembles it).

    Parameters
    ----------
    nominal : Needle208
        The nominal machine (scalar parameters).
    tolerances : ToleranceSet or str
        The inputs, mapped from independent standard normals through each tolerance's
        distribution.
    limit_um : float
        A machine fails when its SumDelta exceeds this (um), or when it cannot run.
    adjust : str
        ``"beta"`` (beta re-optimised per machine) or ``"none"`` (beta at the nominal's beta*).
    range_deg : tuple of float or None
        The regulating range for beta, (low, high) in deg; None: (10, 35).
    engine : str
        ``"numba"`` (the kernel) or ``"numpy"`` (the reference).

    Returns
    -------
    LimitState
        The failure event for `estimate`, with failure modes ``"cannot assemble"`` and
        ``"dead point"`` and the deviations (mm) of failing machines.

    Raises
    ------
    ParameterError
        For an unknown adjustment, a non-positive limit, or a set without any tolerance.
    """
    tolerances = needle_set(tolerances)
    from sewtol.mechanisms.needle_208 import beta as sb

    if adjust not in ADJUSTMENTS:
        raise ParameterError("adjust", f"must be one of {', '.join(ADJUSTMENTS)}", adjust)
    if not (np.isfinite(limit_um) and limit_um > 0):
        raise ParameterError("limit_um", "must be a positive number of um", limit_um)
    range_deg = sb.DEFAULT_RANGE_DEG if range_deg is None else tuple(map(float, range_deg))
    tol = tolerances.active()
    if not tol.items:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width",
                             tolerances.name)
    zmap = StandardNormalMap(tol)
    return LimitState(_NeedleResponse(nominal, zmap, adjust, range_deg, engine), zmap.dim,
                      float(limit_um), NEEDLE_MODES,
                      "total_adjusted_um" if adjust == "beta" else "total_fixed_um",
                      zmap.to_physical)


@dataclass(frozen=True)
class _NeedleResponse:
    """Picklable response of the needle (joblib workers receive it)."""

    nominal: object
    zmap: StandardNormalMap
    adjust: str
    range_deg: tuple
    engine: str

    def __call__(self, z):
        from sewtol.mechanisms import params as P
        from sewtol.mechanisms.needle_208 import metrics as nm
        from sewtol.mechanisms.needle_208.evaluate import evaluate

        dev = self.zmap.to_physical(z)
        out = evaluate(self.nominal, dev, adjust=self.adjust == "beta",
                       range_deg=self.range_deg, engine=self.engine)
        y = out.total_adjusted_um if self.adjust == "beta" else out.total_fixed_um
        mode = np.zeros(y.size, dtype=int)
        bad = ~np.isfinite(y)
        if bad.any():
            sub = {k: v[bad] for k, v in dev.items()}
            c, _ = nm.columns(P.with_deviations(self.nominal, sub))
            m = int(bad.sum())
            c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
            f = nm.feasibility(c)
            misses = (f.miss_LMA_mm > 0) | (f.miss_BCD_mm > 0)
            mode[bad] = np.where(misses, 1, 2)
        return y, mode
