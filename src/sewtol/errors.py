"""Domain exceptions. Both derive from ValueError so callers that expect bad values keep working."""

from __future__ import annotations

import math
from numbers import Real


class ParameterError(ValueError):
    """A parameter broke a rule. The message names the field, the rule and the value.

    The command line prints it as one line on stderr and exits with status 2.

    Parameters
    ----------
    field : str
        The parameter, field or flag that broke the rule (e.g. ``"CD"``, ``"LF.lower"``,
        ``"n"``); kept as the attribute ``field``.
    rule : str
        The rule, in words (e.g. ``"must be a positive length in mm"``); attribute ``rule``.
    value : object
        The offending value, shown with ``repr``; attribute ``value``.

    Examples
    --------
    >>> from sewtol import ParameterError
    >>> str(ParameterError("n", "must be an integer >= 1", 0))
    'n: must be an integer >= 1 (got 0)'
    """

    def __init__(self, field: str, rule: str, value: object) -> None:
        self.field = field
        self.rule = rule
        self.value = value
        # a name typed with control characters is shown quoted, so the message stays one line
        shown = field if str(field).isprintable() else repr(field)
        super().__init__(f"{shown}: {rule} (got {value!r})")


class AssemblyError(ValueError):
    """A group of the mechanism cannot close.

    Carries the group (e.g. the dyad "B-C-D"), the crank or rocker angle where it fails, by how much
    it misses (mm) and the parameters that were used, so a single run can say exactly where.
    Studies never raise it for one machine: they count such a machine as failed
    (``cannot_close``) and go on.

    Parameters
    ----------
    group : str
        The group that cannot close, e.g. ``"L-M-A"`` or ``"B-C-D"``; attribute ``group``.
    angle_deg : float
        Where it fails: the crank angle for L-M-A, the rocker angle for B-C-D (deg).
    miss_mm : float
        By how much the links miss each other there (mm).
    params : dict or None
        The parameters of the machine that failed (copied; attribute ``params``).
    detail : str
        Anything else the message should say (appended after a semicolon).
    """

    def __init__(self, group: str, angle_deg: float, miss_mm: float, params: dict | None = None,
                 detail: str = "") -> None:
        self.group = group
        self.angle_deg = float(angle_deg)
        self.miss_mm = float(miss_mm)
        self.params = dict(params or {})
        extra = f"; {detail}" if detail else ""
        super().__init__(
            f"dyad {group} cannot close at angle {self.angle_deg:.3f} deg: misses by "
            f"{self.miss_mm:.6g} mm{extra}"
        )


def real(v, finite: bool = False) -> bool:
    """True for an int or float (NumPy's too) but not a bool (TOML's true is no number);
    `finite`: and finite."""
    try:
        return isinstance(v, Real) and not isinstance(v, bool) and (not finite or math.isfinite(v))
    except OverflowError:  # an int of hundreds of digits
        return False


def number(where: str, v) -> float:
    """v as a float, or ParameterError: `where` must be a number."""
    if not real(v):
        raise ParameterError(where, "must be a number", v)
    return float(v)
