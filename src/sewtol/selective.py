"""Selective assembly: two parts measured at assembly, sorted into classes and matched.

    selective = { params = ["AB", "BE"], groups = 4, by = "count" }

Classes of equal count (``by = "count"``, matching by rank) or of equal width over each part's
limits (``"width"``, gauge classes); within a class parts pair in the order made, and those a
class has too many of are left unmatched and counted. Each lot is a stream of the one sampler
(`sewtol.law.STREAM` machines), so machine k is the (k % STREAM)-th matched machine of its
stream's lots; a matched machine takes the second part from its partner's machine.
docs/mechanism_files.md, "Selective assembly".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError

KEY = "selective"
BY = ("count", "width")
# at most this many classes: a lot of 500 parts then still has 5 of each per class on average
MAX_GROUPS = 100


@dataclass(frozen=True)
class Selective:
    """Parts `params` (two) sorted into `groups` classes `by` count or width and matched.

    Validated at construction: two different names, 1 <= groups <= MAX_GROUPS, a known `by`.
    """

    params: tuple[str, str]
    groups: int
    by: str = "count"
    where: str = "selective"

    def __post_init__(self):
        if len(self.params) != 2 or self.params[0] == self.params[1]:
            raise ParameterError(f"{self.where}.params", "must name two different parameters "
                                 "(the parts matched)", list(self.params))
        g = self.groups
        if isinstance(g, bool) or not isinstance(g, (int, np.integer)) or not 1 <= g <= MAX_GROUPS:
            raise ParameterError(f"{self.where}.groups", f"must be a whole number of classes "
                                 f"from 1 to {MAX_GROUPS}", g)
        if self.by not in BY:
            raise ParameterError(f"{self.where}.by", f"must be one of {', '.join(BY)}", self.by)

    def as_dict(self) -> dict:
        return {"params": list(self.params), "groups": int(self.groups), "by": self.by}


def classes(x: np.ndarray, groups: int, by: str, limits: tuple[float, float]) -> np.ndarray:
    """The class (0 .. groups-1) of each part of a lot by its size x: equal count (rank in the
    lot times groups // lot size) or equal width over `limits` (clipped at the end classes)."""
    x = np.asarray(x, float)
    if by == "count":
        rank = np.empty(x.size, int)
        rank[np.argsort(x, kind="stable")] = np.arange(x.size)
        return rank * groups // max(x.size, 1)
    lo, hi = limits
    if hi <= lo:
        return np.zeros(x.size, int)
    return np.clip(np.floor((x - lo) / (hi - lo) * groups).astype(int), 0, groups - 1)


def match(a_class: np.ndarray, b_class: np.ndarray, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows (ia, ib) of the matched pairs of one lot: in each class the i-th first part made
    with the i-th second part made; ordered by the first part's row. The rest are unmatched."""
    ia, ib = [], []
    for c in range(groups):
        a = np.flatnonzero(a_class == c)
        b = np.flatnonzero(b_class == c)
        m = min(len(a), len(b))
        ia.append(a[:m])
        ib.append(b[:m])
    ia, ib = np.concatenate(ia), np.concatenate(ib)
    order = np.argsort(ia, kind="stable")
    return ia[order], ib[order]


def parse(set_name: str, body: dict, known: list[str]) -> Selective | None:
    """The selective assembly a tolerance set's table declares (key `selective`), or None."""
    spec = body.get(KEY)
    if spec is None:
        return None
    where = f"{set_name}.{KEY}"
    if not isinstance(spec, dict) or not {"params", "groups"} <= set(spec) or \
            not set(spec) <= {"params", "groups", "by"}:
        raise ParameterError(where, 'must be a table { params = ["A", "B"], groups = k, '
                             'by = "count" or "width" }', spec)
    params = spec["params"]
    if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
        raise ParameterError(f"{where}.params", "must be a list of two parameter names", params)
    for p in params:
        if p not in known:
            raise ParameterError(f"{where}.params", f"names {p!r}, not a parameter of the set "
                                 f"({', '.join(known)})", p)
    return Selective(tuple(params), spec["groups"], spec.get("by", "count"), where)
