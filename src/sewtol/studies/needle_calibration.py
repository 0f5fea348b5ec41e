"""Reconstruction of the unpublished frame positions A and D of the 208 needle drive.

The study gives targets, not the frame: (1) with nominal links beta* = 22.7 and the guide through
N1 = (38.5, 79.729) minimise SumDelta; (2) with that guide fixed SumDelta <= 10 um for beta in
19 ... 25; (3) the needle bar leans 20 deg from the vertical. Unknowns: A = (Ax, Ay) and
D = A + |AD| e(g), with the branches fixed by a coarse search (docs/needle_208.md). The guide of
the nominal machine is then its own fitted (minimum-zone) guide at the joint optimum, so beta*
with the guide fixed equals the joint optimum exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..mechanisms.needle_208 import Needle208
from ..metrics import needle as nm
from . import beta as sb

N1 = (38.5, 79.729)
# target value and the scale each residual is divided by (the acceptance band of issue 2 / 2)
TARGETS = {
    "beta_opt_deg": (22.7, 0.25),
    "guide_offset_from_N1_um": (0.0, 0.5),
    "guide_angle_from_vertical_deg": (20.0, 0.1),
    "total_um_at_beta_19": (10.0, 0.75),
    "total_um_at_beta_25": (10.0, 0.75),
}
SOURCE_LINKS = dict(LF=6.75, LM=58.0, AM=17.0, AB=10.0, BC=20.0, BE=40.0, CD=30.0, CBE=180.0)
BRANCHES = dict(branch_M=1.0, branch_C=1.0, beta_sense=-1.0)


def machine(x, guide=(0.0, 0.0, 0.0), beta=22.7) -> Needle208:
    ax, ay, ad, g_deg = x
    d = complex(ax, ay) + ad * np.exp(1j * np.radians(g_deg))
    return Needle208(**SOURCE_LINKS, beta=beta, Ax=ax, Ay=ay, Dx=d.real, Dy=d.imag,
                     guide_x=guide[0], guide_y=guide[1], guide_angle=guide[2], **BRANCHES)


def achieved(x) -> tuple[dict, Needle208]:
    """The target quantities for frame x = (Ax, Ay, |AD|, g deg), and the machine with its guide."""
    c, _ = nm.columns(machine(x))
    fo = sb.optimise_beta_fitted_guide(c)
    zone = fo.zone
    gx, gy = zone.foot_of(*N1)
    m = machine(x, (float(gx[0]), float(gy[0]), float(zone.angle_from_vertical_deg[0])),
                float(fo.beta_deg[0]))
    cm, _ = nm.columns(m)
    values = {
        "beta_opt_deg": float(fo.beta_deg[0]),
        "guide_offset_from_N1_um": float(zone.distance_um(*N1)[0]),
        "guide_angle_from_vertical_deg": float(zone.angle_from_vertical_deg[0]),
        "total_um_at_beta_19": float(sb.total_at(cm, 19.0)[0]),
        "total_um_at_beta_25": float(sb.total_at(cm, 25.0)[0]),
    }
    return values, m


def residuals(x) -> np.ndarray:
    values, _ = achieved(x)
    return np.array([(values[k] - t) / s for k, (t, s) in TARGETS.items()])


@dataclass(frozen=True)
class Calibration:
    x: tuple[float, float, float, float]
    values: dict
    machine: Needle208
    cost: float
    nfev: int


def calibrate(x0=(-5.0, 56.8, 43.2, 110.6)) -> Calibration:
    """Least squares from x0 (a start from the coarse search in the docs)."""
    sol = least_squares(residuals, np.asarray(x0, float), x_scale=[1.0, 1.0, 0.05, 1.0],
                        diff_step=1e-6, xtol=1e-10, ftol=1e-10, gtol=1e-10)
    values, m = achieved(sol.x)
    return Calibration(tuple(map(float, sol.x)), values, m, float(sol.cost), int(sol.nfev))
