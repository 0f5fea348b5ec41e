"""Where a table or key of a TOML text sits (tomllib keeps no line numbers).

A light scan of the text: table headers ([a.b], [[a]]) and `key =` lines, keyed by their path
(("groups", 2, "r1"), ("parameters", "LF"), ("tolerances", "base", "LF")). Good enough to point
a user at the line of a hand-written file; paths it cannot place fall back to their table."""

from __future__ import annotations

import re

# linear: one class then "]", stripped by _split (a lazy group between two \s* was cubic)
_HEADER = re.compile(r"^\s*(\[\[?)([^\]]*)\]")
_KEY = re.compile(r"""^\s*("[^"]*"|'[^']*'|[A-Za-z0-9_\-]+)\s*=""")


def _split(dotted: str) -> tuple:
    return tuple(p.strip().strip("\"'") for p in dotted.split("."))


class Locator:
    def __init__(self, text: str):
        self.lines: dict[tuple, int] = {}
        counts: dict[tuple, int] = {}
        section: tuple = ()
        depth = 0  # brackets of a multi-line inline table or array
        for no, line in enumerate(text.splitlines(), start=1):
            bare = line.split("#", 1)[0] if '"' not in line and "'" not in line else line
            if depth == 0:
                m = _HEADER.match(bare)
                if m:
                    path = _split(m.group(2))
                    if m.group(1) == "[[":
                        k = counts.get(path, 0)
                        counts[path] = k + 1
                        path = path + (k,)
                    section = path
                    self.lines.setdefault(section, no)
                    continue
                m = _KEY.match(bare)
                if m:
                    self.lines.setdefault(section + (m.group(1).strip("\"'"),), no)
                    # keys of a one-line inline table: a = { nominal = 1, unit = "mm" }
                    inner = bare[m.end():]
                    for k in re.finditer(r"[{,]\s*([A-Za-z0-9_\-]+)\s*=", inner):
                        self.lines.setdefault(section + (m.group(1).strip("\"'"), k.group(1)),
                                              no)
            depth += bare.count("{") + bare.count("[") - bare.count("}") - bare.count("]")
            if _HEADER.match(bare) and depth > 0:
                depth = 0
            depth = max(depth, 0)

    def line(self, *path) -> int:
        """The line of path, else of its nearest enclosing table; 1 when nothing matches."""
        path = tuple(path)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return 1
