"""Tables a designer can paste into a report: CSV for tools, Markdown for people.

Column names carry their units (total_um, beta_deg). The Markdown file starts with a title and
the settings the table depends on (tolerance set, seed, guide), the CSV with the same settings
as '#' comment lines, so a table read alone still says where it came from.
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from sewtol.io import write_text_atomic


def to_markdown(frame: pd.DataFrame, title: str, settings: dict | None = None,
                floatfmt: str = ".4f") -> str:
    lines = [f"# {title}", ""]
    for k, v in (settings or {}).items():
        lines.append(f"- {k}: {v}")
    if settings:
        lines.append("")
    lines.append(frame.to_markdown(index=False, floatfmt=floatfmt))
    return "\n".join(lines) + "\n"


# Absolute printed resolution of columns by their unit suffix. Last bits differ between CPUs
# (OpenBLAS kernels, numpy's SIMD dispatch, numba's target): measured spread on the needle's
# deviations about 1e-10 um. A fixed resolution 1e4 times coarser keeps the printed digits the
# same on any machine except for the rare number that sits on a rounding boundary (about one in
# 10^4; the reproducibility test allows one unit in the last place). Columns without a unit
# suffix (yields, indices, probabilities) keep 9 significant digits.
DECIMALS_BY_UNIT = {"um": 6, "mm": 9, "deg": 7}


_UNIT = re.compile(r"(?:_|\()(um|mm|deg)(?:_|\)|$)")


def unit_of(column: str) -> str | None:
    """The unit a column name carries: d_um_at_beta_opt -> um, "SumDelta (um)" -> um."""
    m = _UNIT.search(str(column))
    return m.group(1) if m else None


def _printable(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    for col in out.columns:
        unit = unit_of(col)
        if unit and pd.api.types.is_float_dtype(out[col]):
            out[col] = out[col].round(DECIMALS_BY_UNIT[unit])
    return out


def to_csv(frame: pd.DataFrame, settings: dict | None = None) -> str:
    head = "".join(f"# {k}: {v}\n" for k, v in (settings or {}).items())
    return head + _printable(frame).to_csv(index=False, float_format="%.9g",
                                           lineterminator="\n")


def csv_pieces(frames):
    """`to_csv` of the frames (the chunks of one table, same columns) joined, piece by piece:
    the header with the first, every value formatted as to_csv formats the whole."""
    for i, frame in enumerate(frames):
        yield _printable(frame).to_csv(index=False, float_format="%.9g", lineterminator="\n",
                                       header=i == 0)


def write_table(frame: pd.DataFrame, folder: Path, name: str, title: str,
                settings: dict | None = None, floatfmt: str = ".4f") -> list[Path]:
    """Write folder/name.csv and folder/name.md atomically; returns the paths."""
    folder = Path(folder)
    csv_path, md_path = folder / f"{name}.csv", folder / f"{name}.md"
    write_text_atomic(csv_path, to_csv(frame, settings))
    write_text_atomic(md_path, to_markdown(frame, title, settings, floatfmt))
    return [csv_path, md_path]
