"""Named settings of a design compared in one table: one row per setting, the same study figures.

A setting is a name and new nominal values of some parameters (a guide moved or turned, a link
made longer, a frame point placed elsewhere); each row is the study's figures of the mechanism
with those nominals (`override`), so the rows differ by the setting alone (a study that draws
machines draws the same ones from its seed on every row: common random numbers).

    compare(mech, [Setting("long crank", {"LF": 7.0}), Setting("short crank", {"LF": 6.5})])

`figures(machine, setting) -> dict` is the study of each row; the default is the nominal
machine's status and every output (`sewtol run FILE settings --set NAME:PARAM=V,...`). A
mechanism's own comparison (the needle's guide placements, tables/needle_208.py) is an instance
with its own figures.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import pandas as pd

from sewtol.errors import ParameterError


@dataclass(frozen=True)
class Setting:
    """A name, the parameters' new nominal values, and columns printed with it (e.g. a shift
    relative to the design's own)."""

    name: str
    values: dict = field(default_factory=dict)
    columns: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SettingsResult:
    settings: tuple[Setting, ...]
    rows: pd.DataFrame

    def to_dataframe(self) -> pd.DataFrame:
        return self.rows.copy()

    def to_dict(self) -> dict:
        return {"settings": [{"name": s.name, "values": dict(s.values)} for s in self.settings],
                "rows": self.rows.to_dict("records")}


def nominal_figures(machine, setting: Setting) -> dict:
    """The setting's nominal machine (a protocol mechanism): its status, the group that failed
    ("" when it runs) and every output (NaN where it does not run: a failure is a row too)."""
    ev = machine.evaluate()
    return {"status": str(ev.status[0]), "failed_group": str(ev.failed_group[0]),
            **{k: float(v[0]) for k, v in ev.outputs.items()}}


def compare(base, settings: Sequence[Setting], figures: Callable | None = None,
            name_column: str = "setting") -> SettingsResult:
    """One row per setting: its name (column `name_column`), its columns, and
    figures(base.override(**setting.values), setting). Names must be distinct."""
    settings = tuple(settings)
    if not settings:
        raise ParameterError("settings", "must name at least one setting", ())
    names = [s.name for s in settings]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ParameterError("settings", "must have distinct names", dup)
    figures = figures or nominal_figures
    rows = [{name_column: s.name, **s.columns, **figures(base.override(**s.values), s)}
            for s in settings]
    return SettingsResult(settings, pd.DataFrame(rows))
