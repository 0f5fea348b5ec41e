"""Relational tolerances: a limit on a quantity derived from several deviations of a set.

    relations = [{ expr = "AB - BE", lower = -0.01, upper = 0.01 }]
    relations = [{ expr = "hypot(Ax, Ay)", upper = 0.05 }]    # a true-position tolerance

`expr` names the parameters' deviations from nominal (their units) and is read by the safe
parser of `sewtol.mechanism.expressions`; `lower` and `upper` bound it (one may be left out). A
relation is inspection: machines that break it are rejected before assembly, so the machines
built follow the set's joint law conditioned on every relation, drawn by rejection
(`sewtol.law.InputLaw`; the acceptance is counted). The worst case searches what the relations
leave of the tolerance box: for linear relations (`Relation.linear`) a polytope whose vertices
replace the box's corners. docs/mechanism_files.md, "Relational tolerances".
"""

from __future__ import annotations

import ast
import itertools
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from sewtol.errors import ParameterError, number, real

# sewtol.mechanism.expressions is imported where it is used: it depends on nothing of sewtol, but
# importing it runs sewtol.mechanism's __init__, whose loader imports sewtol.tolerances, which
# imports this module while it loads

KEY = "relations"
ALLOWED_KEYS = ("expr", "lower", "upper")


@dataclass(frozen=True)
class Relation:
    """A limit lower <= expr(deviations) <= upper on a derived quantity.

    Parameters
    ----------
    expr : str
        The quantity, in the parameters' deviations from nominal (e.g. ``"AB - BE"``).
    lower, upper : float
        Its limits, in the deviations' units; -inf / +inf when not given (not both).
    where : str
        The field errors name (e.g. ``"base.relations[0]"``).
    """

    expr: str
    lower: float = -np.inf
    upper: float = np.inf
    where: str = field(default="relations", compare=False)

    def __post_init__(self):
        from sewtol.mechanism import expressions

        try:
            expressions.parse(self.expr)
        except expressions.ExpressionError as exc:
            raise ParameterError(f"{self.where}.expr", exc.rule, self.expr) from None
        if not self.parsed.names:
            raise ParameterError(f"{self.where}.expr", "must name at least one parameter",
                                 self.expr)
        for side in ("lower", "upper"):
            v = getattr(self, side)
            if not real(v) or np.isnan(v):
                raise ParameterError(f"{self.where}.{side}", "must be a number", v)
        if not (np.isfinite(self.lower) or np.isfinite(self.upper)):
            raise ParameterError(self.where, "needs a lower or an upper limit (or both)",
                                 self.expr)
        if not self.lower < self.upper:
            raise ParameterError(f"{self.where}.lower", "must be below upper (an equality "
                                 "leaves no machine to draw; to make parts equal, tie them with "
                                 "setup share 1)", (self.lower, self.upper))

    @cached_property
    def parsed(self):
        """The checked expression (sewtol.mechanism.expressions.Expression)."""
        from sewtol.mechanism import expressions

        return expressions.parse(self.expr)

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters the relation reads."""
        return self.parsed.names

    def value(self, dev: dict[str, np.ndarray], n: int) -> np.ndarray:
        """The derived quantity of n machines' deviations (a parameter not in dev: 0, nominal)."""
        v = self.parsed({k: np.asarray(dev[k], float) if k in dev else np.zeros(n)
                         for k in self.names})
        return np.broadcast_to(np.asarray(v, float), (n,))

    def holds(self, dev: dict[str, np.ndarray], n: int) -> np.ndarray:
        """True per machine where the relation holds (a NaN quantity does not hold)."""
        v = self.value(dev, n)
        return (v >= self.lower) & (v <= self.upper)

    @cached_property
    def linear(self) -> tuple[dict[str, float], float] | None:
        """(coefficient per name, constant) when expr is affine in the deviations, read from
        its syntax tree; None otherwise (a product of two names, a function of a name)."""
        return _affine(self.parsed.tree.body)

    def as_dict(self) -> dict:
        return {"expr": self.expr,
                **({"lower": float(self.lower)} if np.isfinite(self.lower) else {}),
                **({"upper": float(self.upper)} if np.isfinite(self.upper) else {})}


def _constant(node) -> float | None:
    """The value of a subtree that names no parameter (e.g. 2 * pi, sqrt(2)); else None."""
    from sewtol.mechanism import expressions

    e = expressions.parse(ast.unparse(node))
    return None if e.names else float(e({}))


def _affine(node) -> tuple[dict[str, float], float] | None:
    c = _constant(node)
    if c is not None:
        return {}, c
    if isinstance(node, ast.Name):
        return {node.id: 1.0}, 0.0
    if isinstance(node, ast.UnaryOp):
        inner = _affine(node.operand)
        if inner is None:
            return None
        s = -1.0 if isinstance(node.op, ast.USub) else 1.0
        return {k: s * v for k, v in inner[0].items()}, s * inner[1]
    if isinstance(node, ast.BinOp):
        if isinstance(node.op, (ast.Add, ast.Sub)):
            a, b = _affine(node.left), _affine(node.right)
            if a is None or b is None:
                return None
            s = 1.0 if isinstance(node.op, ast.Add) else -1.0
            coef = dict(a[0])
            for k, v in b[0].items():
                coef[k] = coef.get(k, 0.0) + s * v
            return coef, a[1] + s * b[1]
        if isinstance(node.op, ast.Mult):
            for const, other in ((node.left, node.right), (node.right, node.left)):
                c = _constant(const)
                if c is not None:
                    inner = _affine(other)
                    return None if inner is None else \
                        ({k: c * v for k, v in inner[0].items()}, c * inner[1])
            return None
        if isinstance(node.op, ast.Div):
            c = _constant(node.right)
            inner = _affine(node.left)
            if c is None or c == 0 or not np.isfinite(c) or inner is None:
                return None
            return {k: v / c for k, v in inner[0].items()}, inner[1] / c
    return None


def parse(set_name: str, body: dict, known: list[str]) -> tuple[Relation, ...]:
    """The relations a tolerance set's table declares (key `relations`, the module docstring),
    over the set's parameters `known`."""
    from sewtol.mechanism import expressions

    entries = body.get(KEY, [])
    where = f"{set_name}.{KEY}"
    if not isinstance(entries, list):
        raise ParameterError(where, 'must be a list of { expr = "...", lower = x, upper = y }',
                             entries)
    out = []
    for k, e in enumerate(entries):
        at = f"{where}[{k}]"
        if not isinstance(e, dict) or "expr" not in e:
            raise ParameterError(at, 'must be a table { expr = "...", lower = x, upper = y }', e)
        extra = sorted(set(e) - set(ALLOWED_KEYS))
        if extra:
            raise ParameterError(at, f"unknown keys {extra}; allowed: {list(ALLOWED_KEYS)}", e)
        if not isinstance(e["expr"], str):
            raise ParameterError(f"{at}.expr", "must be an expression in quotes", e["expr"])
        try:
            parsed = expressions.parse(e["expr"], known)
        except expressions.ExpressionError as exc:
            rule = exc.rule.replace("a parameter of the file", "a toleranced parameter of the "
                                    f"set ({', '.join(known)})")
            raise ParameterError(f"{at}.expr", rule, e["expr"]) from None
        del parsed
        out.append(Relation(e["expr"], number(f"{at}.lower", e.get("lower", -np.inf)),
                            number(f"{at}.upper", e.get("upper", np.inf)), at))
    return tuple(out)


def polytope_vertices(lo: np.ndarray, hi: np.ndarray, a: np.ndarray, lower: np.ndarray,
                      upper: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """The vertices of {lo <= x <= hi, lower <= a x <= upper} (a: one row per linear relation,
    over x's coordinates): every point where d independent constraints are active, kept when it
    satisfies the others. A vertex has at most m = len(a) relations active, so at least d - m
    coordinates at a bound: for each choice of s <= m active relation sides and s free
    coordinates, the 2^(d - s) bound patterns of the others are solved at once. Empty when the
    relations leave nothing of the box."""
    d, m = len(lo), len(a)
    scale = np.maximum(hi - lo, 1e-300)
    tol = rtol * (1.0 + np.abs(a) @ np.maximum(np.abs(lo), np.abs(hi)))
    found = []
    for s in range(0, min(m, d) + 1):
        for rows in itertools.combinations(range(m), s):
            for sides in itertools.product((0, 1), repeat=s):
                rhs = np.array([(lower, upper)[side][r] for r, side in zip(rows, sides,
                                                                             strict=True)])
                if not np.all(np.isfinite(rhs)):
                    continue
                for free in itertools.combinations(range(d), s):
                    fixed = [i for i in range(d) if i not in free]
                    pats = np.array(list(itertools.product(*[(lo[i], hi[i]) for i in fixed])))
                    pats = pats.reshape(-1, len(fixed))
                    x = np.empty((len(pats), d))
                    x[:, fixed] = pats
                    if s:
                        af = a[np.ix_(rows, free)]
                        if abs(np.linalg.det(af)) < 1e-12 * max(1.0, np.abs(af).max()) ** s:
                            continue
                        b = rhs[None, :] - pats @ a[np.ix_(rows, fixed)].T
                        x[:, list(free)] = np.linalg.solve(af, b.T).T
                    inside = np.all((x >= lo - rtol * scale) & (x <= hi + rtol * scale), axis=1)
                    ax = x @ a.T
                    inside &= np.all((ax >= lower - tol) & (ax <= upper + tol), axis=1)
                    found.append(np.clip(x[inside], lo, hi))
    if not found:
        return np.empty((0, d))
    v = np.vstack(found)
    if not len(v):
        return v
    # the same vertex reached from several active sets (a degenerate vertex): keep one
    key = np.round((v - lo) / scale, 9)
    _, first = np.unique(key, axis=0, return_index=True)
    return v[np.sort(first)]
