"""Domain exceptions. Both derive from ValueError so callers that expect bad values keep working."""

from __future__ import annotations


class ParameterError(ValueError):
    """A parameter broke a rule. The message names the field, the rule and the value."""

    def __init__(self, field: str, rule: str, value: object):
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
    """

    def __init__(self, group: str, angle_deg: float, miss_mm: float, params: dict | None = None,
                 detail: str = ""):
        self.group = group
        self.angle_deg = float(angle_deg)
        self.miss_mm = float(miss_mm)
        self.params = dict(params or {})
        extra = f"; {detail}" if detail else ""
        super().__init__(
            f"dyad {group} cannot close at angle {self.angle_deg:.3f} deg: misses by "
            f"{self.miss_mm:.6g} mm{extra}"
        )
