"""The parts of a mechanism file once checked: parameters, groups, outputs, compensators, specs.

Every part keeps the line of the file it came from, so later errors can point at it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sewtol.errors import ParameterError, real
from sewtol.setting_error import SettingError

FORMAT = "sewtol-mechanism/1"
UNITS = ("mm", "deg", "um", "1")
RULES = ("positive", "finite", "nonnegative", "branch")


@dataclass(frozen=True)
class Parameter:
    name: str
    nominal: float
    unit: str
    rule: str = "finite"
    doc: str = ""
    line: int = 0


@dataclass(frozen=True)
class Group:
    """One [[groups]] entry: its type, name, resolved fields (Expression for numbers and
    expressions, a name for points and angles, (P, Q) for a direction) and its line."""

    type: str
    name: str
    fields: dict
    line: int = 0


@dataclass(frozen=True)
class Output:
    name: str
    unit: str
    type: str
    doc: str
    fields: dict
    kind: str = ""  # the registered kind of a custom output
    line: int = 0


MODES = ("absolute", "offset")


@dataclass(frozen=True)
class Compensator:
    """A [compensators.NAME]: a parameter the assembler sets on each machine.

    `low`, `high` bound the setting (the parameter's unit); mode "absolute": the setting
    replaces the parameter, "offset": it is added to the machine's as-built value. `step`
    (None: continuous): only the settings low + k * step exist. `resolution` (how finely a
    fitter can set it: a setting made is rounded to a multiple of it; 0: exactly) and
    `setting_error` (sewtol.setting_error.SettingError: how far a setting made lands from the
    one aimed at; None: exactly) are what the strategies study sets the machines with
    (sewtol.studies.strategies.set_in_order)."""

    name: str
    parameter: str
    low: float
    high: float
    line: int = 0
    step: float | None = None
    resolution: float = 0.0
    setting_error: SettingError | None = None
    mode: str = "absolute"

    def settings(self):
        """The allowed settings of a stepped compensator: low + k * step inside [low, high]."""
        k = int(np.floor((self.high - self.low) / self.step * (1 + 1e-12)))
        return self.low + self.step * np.arange(k + 1)


@dataclass(frozen=True)
class Spec:
    """The limits one output must keep (a [[specs]] entry, or --limit/--lower-limit): an upper
    limit, a lower limit or both, in the output's unit. Checked at construction: at least one
    limit, each finite, lower below upper."""

    output: str
    upper: float | None = None
    lower: float | None = None
    doc: str = ""
    line: int = 0

    def __post_init__(self):
        if self.upper is None and self.lower is None:
            raise ParameterError("upper", "give an upper and/or a lower limit", None)
        for name in ("upper", "lower"):
            v = getattr(self, name)
            if v is not None and not real(v, finite=True):
                raise ParameterError(name, "must be a finite number", v)
            if v is not None:
                object.__setattr__(self, name, float(v))
        if self.upper is not None and self.lower is not None and not self.lower < self.upper:
            raise ParameterError("lower", f"must be below the upper limit {self.upper:g}",
                                 self.lower)

    def excess(self, y) -> np.ndarray:
        """How far each value lies beyond the limits (output units; <= 0 inside, NaN stays)."""
        y = np.asarray(y, float)
        up = y - self.upper if self.upper is not None else np.full_like(y, -np.inf)
        return up if self.lower is None else np.maximum(up, self.lower - y)

    def passes(self, y) -> np.ndarray:
        """Per value: True inside the limits (NaN, a machine that gives no value, fails)."""
        with np.errstate(invalid="ignore"):
            return np.asarray(self.excess(y) <= 0)

    def to_dict(self) -> dict:
        return {"output": self.output, "upper": self.upper, "lower": self.lower, "doc": self.doc}


@dataclass(frozen=True)
class Header:
    name: str
    title: str = ""
    source: str = ""
    assumptions: tuple[str, ...] = ()
    samples: int = 720
    rpm: float | None = None
    driver: str | None = None
    fast_path: str | None = None
    extra: dict = field(default_factory=dict)
