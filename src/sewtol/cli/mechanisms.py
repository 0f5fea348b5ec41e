"""`sewtol mechanisms`: the built-in mechanisms, each a folder of sewtol.mechanisms (name, title,
file, docs page, fast path, custom output kinds)."""

from __future__ import annotations

from pathlib import Path

from sewtol.cli.common import emit


def add_mechanisms(sub) -> None:
    p = sub.add_parser("mechanisms", help="the built-in mechanisms: name, file, docs, fast path")
    p.add_argument("--format", choices=("text", "csv", "json"), default="text")
    p.set_defaults(func=cmd_mechanisms)


def mechanisms_table():
    """One row per built-in mechanism: its name, title, file, docs page, fast path and custom
    output kinds (what `sewtol mechanisms` prints)."""
    import tomllib

    import pandas as pd

    from sewtol import mechanisms as M

    root = Path(M.__file__).parent
    fast, kinds = M.declared("FAST_PATHS"), M.declared("OUTPUT_KINDS")
    rows = []
    for name in M.names():
        head = tomllib.loads(M.mechanism_file(name).read_text())["mechanism"]
        own = f"sewtol.mechanisms.{name}."
        rows.append({"name": name, "title": head.get("title", ""),
                     "file": str(M.mechanism_file(name).relative_to(root.parent.parent)),
                     "docs": str((M.folder(name) / M.DOCS).relative_to(root.parent.parent)),
                     "fast_path": ", ".join(k for k, v in fast.items() if v.startswith(own)),
                     "output_kinds": ", ".join(k for k, v in kinds.items()
                                               if v.startswith(own))})
    return pd.DataFrame(rows)


def cmd_mechanisms(args) -> None:
    frame = mechanisms_table()
    fmt = "table" if args.format == "text" else args.format
    emit(fmt, obj={"mechanisms": frame.to_dict("records")}, frame=frame)
