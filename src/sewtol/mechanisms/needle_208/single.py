"""Single-machine figures of the 208 needle drive, as the CLI and reports present them."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from sewtol.errors import AssemblyError
from sewtol.mechanisms.needle_208 import beta as sb
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.model import Needle208, check_assembly

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class NominalFigures:
    """beta*, deviation figures, window, guide used, fitted guide, stroke and frame of one machine."""

    beta_opt_deg: float
    total_um: float
    plus_um: float
    minus_um: float
    window_deg: tuple[float, float]
    guide: dict
    fitted_guide: dict
    stroke_mm: float
    A_mm: tuple[float, float]
    D_mm: tuple[float, float]
    limit_um: float
    # the searched regulating range; whether beta*'s plateau reaches one of its ends (then the
    # true optimum may lie outside: widen --beta-range) and whether the window ends there
    beta_search_range_deg: tuple[float, float] = (float("nan"), float("nan"))
    beta_at_bound: bool = False
    window_clipped: tuple[bool, bool] = (False, False)

    def notes(self) -> list[str]:
        """Plain sentences for every figure that a bound of the searched range decides."""
        lo, hi = self.beta_search_range_deg
        out = []
        if self.beta_at_bound:
            end = lo if abs(self.beta_opt_deg - lo) <= abs(self.beta_opt_deg - hi) else hi
            out.append(f"beta* = {self.beta_opt_deg:.4f} deg: the optimum reaches the bound "
                       f"{end:g} deg of the searched range [{lo:g}, {hi:g}] (SumDelta is lowest "
                       "there or flat up to it) and may lie outside it (widen --beta-range)")
        for side, clipped, end in (("low", self.window_clipped[0], lo),
                                   ("high", self.window_clipped[1], hi)):
            if clipped:
                out.append(f"the window's {side} end is clipped at the range bound {end:g} deg "
                           f"(SumDelta <= {self.limit_um:g} um continues beyond it)")
        return out

    def to_dict(self) -> dict:
        """The figures as plain data (the JSON of ``sewtol needle nominal``), in field order."""
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}
        d["window_clipped"] = {"low": self.window_clipped[0], "high": self.window_clipped[1]}
        return {**d, "notes": self.notes()}

    def to_dataframe(self) -> pd.DataFrame:
        """The figures as quantity/value rows (the table of ``sewtol needle nominal``)."""
        import pandas as pd

        rows = [
            ("beta* (deg)", self.beta_opt_deg),
            ("beta* on a bound of the searched range (1 = yes)", float(self.beta_at_bound)),
            ("SumDelta at beta* (um)", self.total_um),
            ("Delta+ (um)", self.plus_um),
            ("Delta- (um)", self.minus_um),
            (f"window SumDelta <= {self.limit_um:g} um, low (deg)", self.window_deg[0]),
            (f"window SumDelta <= {self.limit_um:g} um, high (deg)", self.window_deg[1]),
            ("window low end clipped at the range bound (1 = yes)",
             float(self.window_clipped[0])),
            ("window high end clipped at the range bound (1 = yes)",
             float(self.window_clipped[1])),
            ("guide x (mm)", self.guide["x_mm"]),
            ("guide y (mm)", self.guide["y_mm"]),
            ("guide angle from vertical (deg)", self.guide["angle_from_vertical_deg"]),
            ("fitted guide angle at beta* (deg)", self.fitted_guide["angle_from_vertical_deg"]),
            ("fitted zone width at beta* (um)", self.fitted_guide["width_um"]),
            ("stroke (mm)", self.stroke_mm),
            ("A x (mm)", self.A_mm[0]),
            ("A y (mm)", self.A_mm[1]),
            ("D x (mm)", self.D_mm[0]),
            ("D y (mm)", self.D_mm[1]),
        ]
        return pd.DataFrame(rows, columns=["quantity", "value"])


def nominal_figures(params: Needle208, range_deg: tuple[float, float] = sb.DEFAULT_RANGE_DEG,
                    limit_um: float = sb.DEFAULT_LIMIT_UM, window: bool = True) -> NominalFigures:
    """Optimise beta with the guide fixed and collect the figures a designer reads.

    What ``sewtol needle nominal`` prints.

    Parameters
    ----------
    params : Needle208
        One machine (scalar parameters), e.g. ``Needle208.nominal()``.
    range_deg : tuple of float
        The regulating range searched for beta*, (low, high) in deg; default (10, 35).
    limit_um : float
        The SumDelta limit (um) that defines the beta window; default 10.
    window : bool
        False: the window is left NaN (its edges are most of the work; beta* is the same).

    Returns
    -------
    NominalFigures
        beta* (deg), SumDelta, Delta+ and Delta- at beta* (um), the window of beta with
        SumDelta <= limit_um (deg), the guide and the fitted minimum-zone guide at beta*, the
        needle stroke (mm) and the pivots A and D (mm).

    Raises
    ------
    AssemblyError
        If the machine cannot assemble (the dyad, the angle and the miss are named).
    """
    check_assembly(params)
    c, _ = nm.columns(params)
    opt = sb.optimise_beta_columns(c, range_deg, limit_um, window=window)
    if not np.isfinite(opt.beta_deg[0]):
        raise AssemblyError("B-C-D", float("nan"), float("inf"), {},
                            f"no beta in {range_deg} deg assembles")
    at = nm.with_values(c, beta=opt.beta_deg)
    zone = nm.minimum_zone(at)
    _, n, G = nm.nd.guide_frame(at)
    gx, gy = float(G.real.ravel()[0]), float(G.imag.ravel()[0])
    fx, fy = zone.foot_of(gx, gy)
    lo, hi = map(float, range_deg)
    w_lo, w_hi = float(opt.window_low_deg[0]), float(opt.window_high_deg[0])
    clipped = bool(opt.window_clipped[0])
    return NominalFigures(
        beta_opt_deg=float(opt.beta_deg[0]),
        total_um=float(opt.total_um[0]),
        plus_um=float(opt.plus_um[0]),
        minus_um=float(opt.minus_um[0]),
        window_deg=(w_lo, w_hi),
        guide={"x_mm": gx, "y_mm": gy, "angle_from_vertical_deg": float(params.guide_angle)},
        fitted_guide={"x_mm": float(fx[0]), "y_mm": float(fy[0]),
                      "angle_from_vertical_deg": float(zone.angle_from_vertical_deg[0]),
                      "width_um": float(zone.width_um[0])},
        stroke_mm=float(nm.stroke_mm(at)[0]),
        A_mm=(float(params.Ax), float(params.Ay)),
        D_mm=(float(params.Dx), float(params.Dy)),
        limit_um=float(limit_um),
        beta_search_range_deg=(lo, hi),
        beta_at_bound=bool(opt.at_bound[0]),
        window_clipped=(clipped and w_lo == lo, clipped and w_hi == hi),
    )


def deviation_table(params: Needle208, step_deg: float = 1.0) -> pd.DataFrame:
    """E and d(phi) over one crank turn at the machine's beta, guide fixed.

    What ``sewtol needle deviation`` prints.

    Parameters
    ----------
    params : Needle208
        One machine (scalar parameters); its own ``beta`` is used, not beta*.
    step_deg : float
        The crank-angle step (deg); the table runs from 0 up to, not including, 360.

    Returns
    -------
    pandas.DataFrame
        Columns ``phi_deg`` (crank angle, deg), ``x_mm`` and ``y_mm`` (the needle-bar point E)
        and ``d_um`` (its signed distance from the guide line, um).

    Raises
    ------
    AssemblyError
        If the machine cannot assemble.
    """
    import pandas as pd

    check_assembly(params)
    phi = np.arange(0.0, 360.0, step_deg)
    c, _ = nm.columns(params)
    cur = nm.deviation_curve(c, np.radians(phi))
    return pd.DataFrame({"phi_deg": phi, "x_mm": cur["x_mm"][0], "y_mm": cur["y_mm"][0],
                         "d_um": cur["d_um"][0]})
