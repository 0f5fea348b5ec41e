"""The parts of a mechanism file once checked: parameters, groups, outputs, compensators.

Every part keeps the line of the file it came from, so later errors can point at it."""

from __future__ import annotations

from dataclasses import dataclass, field

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
    fitter can set it) and `setting_error` (the +- error of a setting made) are stored for the
    studies; 0 means exact."""

    name: str
    parameter: str
    low: float
    high: float
    line: int = 0
    step: float | None = None
    resolution: float = 0.0
    setting_error: float = 0.0
    mode: str = "absolute"

    def settings(self):
        """The allowed settings of a stepped compensator: low + k * step inside [low, high]."""
        import numpy as np

        k = int(np.floor((self.high - self.low) / self.step * (1 + 1e-12)))
        return self.low + self.step * np.arange(k + 1)


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
