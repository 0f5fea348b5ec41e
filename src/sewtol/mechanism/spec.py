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


@dataclass(frozen=True)
class Compensator:
    name: str
    parameter: str
    low: float
    high: float
    line: int = 0


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
