"""Named settings of a design compared in one table: one row per setting, the same study figures.

A setting is a name and new nominal values of some parameters (a guide moved or turned, a link
made longer, a frame point placed elsewhere); each row is the study's figures of the mechanism
with those nominals (`override`), so the rows differ by the setting alone (a study that draws
machines draws the same ones from its seed on every row: common random numbers).

    compare(mech, [Setting("long crank", {"LF": 7.0}), Setting("short crank", {"LF": 6.5})])

`figures(machine, setting) -> dict` is the study of each row; the default is the nominal
machine's status and every output (`sewtol run FILE settings --set NAME:PARAM=V,...`).
`yield_figures(tolerances, n, seed, cases)` is the Monte-Carlo of each row: the strategies study
of the setting's machine (the seed's deviations added to its nominals: the same on every row)
under each case (compensators set per machine; none: as built), with per case counts adding up
to n, the yield and p95 (`run FILE settings --n N --adjust C`). A mechanism's own comparison
(the needle's guide placements, tables/needle_208.py: `run needle_208 settings` without named
settings, alias `needle guides`) is an instance: settings as data, its own nominal figures and
the cases' columns in its words.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from sewtol.adjuster import Objective
from sewtol.errors import ParameterError
from sewtol.studies.strategies import STATUSES, strategies

if TYPE_CHECKING:
    import pandas as pd


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


def case_columns(res) -> dict:
    """A settings row's yield columns of a strategies result (sewtol.studies.strategies): n, and
    per case NAME `yield_NAME`, `ok_NAME`, `out_of_spec_NAME`, `cannot_close_NAME`,
    `dead_point_NAME` (ok + out_of_spec + cannot_close + dead_point = n) and `p95_NAME` (of the
    case's output; a machine that cannot run ranks as infinitely bad)."""
    row = {"n": res.n}
    for i, name in enumerate(res.names):
        c = res.row(i)  # the strategies row: its counts and quantiles, in the generic words
        row.update({f"yield_{name}": c["ok"] / c["n"], **{f"{k}_{name}": c[k] for k in STATUSES},
                    f"p95_{name}": c["p95"]})
    return row


def yield_figures(tolerances, n: int, seed: int, cases: Mapping | None = None,
                  output: str | None = None, spec=None, *, columns: Callable = case_columns,
                  fast: bool = True, n_jobs: int = 1, progress=False, **options) -> Callable:
    """figures(machine, setting) for `compare`: the strategies study (sewtol.studies.strategies:
    the machines 0 .. n-1 of `seed`, cases name -> compensators, default {"fixed": ()}, output
    and spec as it takes them, options to the adjuster) of the setting's machine, as
    `columns(result)` (default `case_columns`). Every row draws the same deviations: the rows
    differ by the setting alone. With a two-sided spec the compensators centre the output in it
    (sewtol.adjuster.Objective "centre"; minimising it would push it out below) unless options
    give another objective."""
    cases = {"fixed": ()} if cases is None else dict(cases)
    if spec is not None and spec.lower is not None and spec.upper is not None:
        options.setdefault("objective", Objective("centre", low=spec.lower, high=spec.upper))

    def figures(machine, setting):
        return columns(strategies(machine, tolerances, n, seed, cases, output, spec, fast=fast,
                                  n_jobs=n_jobs, progress=progress, **options))
    return figures


def compare(base, settings: Sequence[Setting], figures: Callable | None = None,
            name_column: str = "setting") -> SettingsResult:
    """One row per setting: its name (column `name_column`), its columns, and
    figures(base.override(**setting.values), setting). Names must be distinct."""
    import pandas as pd

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
