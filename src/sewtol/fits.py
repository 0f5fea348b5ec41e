"""ISO 286 fits: the hole and shaft limits of a hole-basis fit (``"H7/g6"``) at a nominal
diameter, and the clearance range they give.

The limits come from pressfit 0.1.0, whose tables are ISO 286-1:2010 Table 1 (standard
tolerance grades) and the fundamental deviations of Tables 2-3, entered as data;
tests/test_fits.py holds it to 28 values of those tables (docs/fits.md says how it was checked).
Scope: hole H, IT5 to IT11, shaft letters c d e f g h js k m n p s u, diameters over 0 up to and
including 500 mm (a diameter on a range limit, e.g. 30 mm, belongs to the range below it).
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass

from sewtol.errors import ParameterError, real

SOURCE = "ISO 286-1:2010 Tables 1-3, via pressfit 0.1.0"
GRADES = tuple(range(5, 12))
SHAFT_LETTERS = ("c", "d", "e", "f", "g", "h", "js", "k", "m", "n", "p", "s", "u")
MAX_DIAMETER_MM = 500.0
# no nested or adjacent unbounded quantifiers: a match costs time linear in the text
_FIT = re.compile(r"([A-Za-z]{1,2})([0-9]{1,2})/([A-Za-z]{1,2})([0-9]{1,2})")
_FORM = "must be a hole-basis ISO 286 fit 'H<grade>/<shaft letter><grade>', e.g. 'H7/g6'"


@dataclass(frozen=True)
class Fit:
    """The limits of one fit at one nominal diameter, as deviations from it (um).

    ``clearance_min_um`` and ``clearance_max_um`` are diametral (hole minus shaft); a negative
    value is interference. Build one with `iso_fit`.
    """

    fit: str
    diameter_mm: float
    hole_grade: int
    shaft_grade: int
    hole_upper_um: float
    hole_lower_um: float
    shaft_upper_um: float
    shaft_lower_um: float
    source: str = SOURCE

    @property
    def hole_it_um(self) -> float:
        return self.hole_upper_um - self.hole_lower_um

    @property
    def shaft_it_um(self) -> float:
        return self.shaft_upper_um - self.shaft_lower_um

    @property
    def clearance_min_um(self) -> float:
        return self.hole_lower_um - self.shaft_upper_um

    @property
    def clearance_max_um(self) -> float:
        return self.hole_upper_um - self.shaft_lower_um

    @property
    def kind(self) -> str:
        """"clearance" (never interferes), "interference" (never clears) or "transition"."""
        if self.clearance_min_um >= 0:
            return "clearance"
        return "interference" if self.clearance_max_um <= 0 else "transition"

    def to_dict(self) -> dict:
        """The fields and the derived values (IT widths, clearance range, kind)."""
        return {**asdict(self), "hole_it_um": self.hole_it_um, "shaft_it_um": self.shaft_it_um,
                "clearance_min_um": self.clearance_min_um,
                "clearance_max_um": self.clearance_max_um, "kind": self.kind}


def parse_fit(text: object) -> tuple[int, str, int]:
    """(hole grade, shaft letter, shaft grade) of a fit such as ``"H7/g6"``, or ParameterError."""
    m = _FIT.fullmatch(text) if isinstance(text, str) else None
    if m is None:
        raise ParameterError("fit", _FORM, text)
    hole, hole_grade, letter, shaft_grade = m.group(1), int(m.group(2)), m.group(3), int(m.group(4))
    if hole != "H":
        raise ParameterError("fit", "the hole must be H (hole-basis fits only)", text)
    if letter not in SHAFT_LETTERS:
        raise ParameterError("fit", f"the shaft letter must be one of {', '.join(SHAFT_LETTERS)}",
                             text)
    if hole_grade not in GRADES or shaft_grade not in GRADES:
        raise ParameterError("fit", f"IT grades must be {GRADES[0]} to {GRADES[-1]}", text)
    return hole_grade, letter, shaft_grade


def check_diameter(value: object, field: str = "diameter_mm") -> float:
    """A nominal diameter in ISO 286's range (over 0 up to and including 500 mm), as a float."""
    if not real(value, finite=True) or not 0.0 < value <= MAX_DIAMETER_MM:
        raise ParameterError(field, f"must be a diameter over 0 up to and including "
                                    f"{MAX_DIAMETER_MM:g} mm", value)
    return float(value)


def iso_fit(fit: str, diameter_mm: float) -> Fit:
    """The hole and shaft limits of `fit` (e.g. ``"H7/g6"``) at `diameter_mm`.

    Examples
    --------
    >>> f = iso_fit("H7/g6", 25)
    >>> (f.hole_upper_um, f.shaft_upper_um, f.shaft_lower_um, f.clearance_max_um, f.kind)
    (21.0, -7.0, -20.0, 41.0, 'clearance')
    """
    import pressfit

    hole_grade, letter, shaft_grade = parse_fit(fit)
    d = check_diameter(diameter_mm)
    r = pressfit.fit(f"H{hole_grade}/{letter}{shaft_grade}", d)
    return Fit(fit=fit, diameter_mm=d, hole_grade=hole_grade, shaft_grade=shaft_grade,
               hole_upper_um=float(r.hole_es_um), hole_lower_um=float(r.hole_ei_um),
               shaft_upper_um=float(r.shaft_es_um), shaft_lower_um=float(r.shaft_ei_um))
