"""`sewtol fit FIT DIAMETER_MM`: the hole and shaft limits of an ISO 286 fit and its clearance
range (sewtol.fits)."""

from __future__ import annotations

import sys

from sewtol.cli.common import emit
from sewtol.errors import ParameterError


def add_fit(sub) -> None:
    p = sub.add_parser("fit", help="ISO 286 fit: hole and shaft limits and the clearance range",
                       description="The hole and shaft limits of a hole-basis ISO 286 fit at a "
                                   "nominal diameter, and its clearance range (um).")
    p.add_argument("fit", metavar="FIT", help="a hole-basis fit, e.g. H7/g6")
    p.add_argument("diameter", metavar="DIAMETER_MM", help="the nominal diameter (mm)")
    p.add_argument("--format", choices=("table", "json"), default="table")
    p.set_defaults(func=cmd_fit)


def _um(value: float) -> str:
    return f"{value:+g}" if value else "0"


def cmd_fit(args) -> None:
    from sewtol.fits import check_diameter, iso_fit

    try:
        diameter = float(args.diameter)
    except ValueError:
        raise ParameterError("DIAMETER_MM", "must be a number (mm)", args.diameter) from None
    f = iso_fit(args.fit, check_diameter(diameter, "DIAMETER_MM"))
    if args.format == "json":
        emit("json", obj=f.to_dict())
        return
    hole, shaft = args.fit.split("/")
    d = f.diameter_mm
    rows = [(hole, f.hole_grade, f.hole_upper_um, f.hole_lower_um, "hole"),
            (shaft, f.shaft_grade, f.shaft_upper_um, f.shaft_lower_um, "shaft")]
    lines = [f"{args.fit} at {d:g} mm: {f.kind} fit ({f.source})"]
    for name, grade, upper, lower, part in rows:
        lines.append(f"{part:<6}{name:<5} IT{grade} = {upper - lower:g} um   "
                     f"{_um(upper)} / {_um(lower)} um   "
                     f"{d + upper / 1000:.4f} / {d + lower / 1000:.4f} mm")
    lines.append(f"clearance {f.clearance_min_um:g} to {f.clearance_max_um:g} um "
                 "(diametral; negative is interference)")
    sys.stdout.write("\n".join(lines) + "\n")
