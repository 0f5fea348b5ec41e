"""Safe arithmetic expressions of a mechanism file: parsed with `ast`, checked against a
whitelist, then interpreted node by node over NumPy arrays. Nothing is ever passed to eval.

Allowed: numbers, parameter names, the constant `pi`, + - * / ** (binary), unary - and +,
parentheses, and calls of the functions in FUNCTIONS with positional arguments. Anything else
(attributes, subscripts, keywords, comparisons, lambdas, strings, names that are not
parameters) is refused when the file is loaded, with the rule that was broken.
"""

from __future__ import annotations

import ast
import math
import operator
from dataclasses import dataclass

import numpy as np

# name -> (function, number of arguments); all in the file's units (angles of sin/cos/tan in
# radians, as the functions radians/degrees convert)
FUNCTIONS = {
    "sin": (np.sin, 1), "cos": (np.cos, 1), "tan": (np.tan, 1), "sqrt": (np.sqrt, 1),
    "radians": (np.radians, 1), "degrees": (np.degrees, 1),
    # compatible extension of the contract: inverse functions for triangles in the drawing
    "asin": (np.arcsin, 1), "acos": (np.arccos, 1), "atan": (np.arctan, 1),
    "atan2": (np.arctan2, 2), "hypot": (np.hypot, 2), "abs": (np.abs, 1),
}
CONSTANTS = {"pi": np.float64(np.pi)}
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
ALLOWED = ("numbers, parameter names, pi, + - * / **, unary -, parentheses and the functions "
           + " ".join(FUNCTIONS))
MAX_LENGTH = 500


class ExpressionError(ValueError):
    """An expression broke the whitelist; `rule` says which part."""

    def __init__(self, rule: str):
        self.rule = rule
        super().__init__(rule)


@dataclass(frozen=True)
class Expression:
    """A checked expression: its text, the parameter names it uses, and its syntax tree."""

    text: str
    names: tuple[str, ...]
    tree: ast.AST

    def __call__(self, values: dict) -> np.ndarray | float:
        return _eval(self.tree, values)

    @property
    def constant(self) -> bool:
        return not self.names


def _check(node: ast.AST, names: list[str]) -> None:
    if isinstance(node, ast.Expression):
        _check(node.body, names)
    elif isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ExpressionError(f"the constant {node.value!r} is not a number")
        try:
            finite = math.isfinite(node.value)
        except OverflowError:  # an int of hundreds of digits
            finite = False
        if not finite:
            shown = f"a {len(str(node.value))}-digit number" if isinstance(node.value, int) \
                else f"the number {node.value!r}"
            raise ExpressionError(f"{shown} is not a finite 64-bit float") from None
    elif isinstance(node, ast.Name):
        if node.id in FUNCTIONS:
            raise ExpressionError(f"the function {node.id} must be called, e.g. {node.id}(x)")
        if node.id not in CONSTANTS:
            names.append(node.id)
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in _BINARY:
            raise ExpressionError(f"the operator {type(node.op).__name__} is not allowed")
        _check(node.left, names)
        _check(node.right, names)
    elif isinstance(node, ast.UnaryOp):
        if type(node.op) not in _UNARY:
            raise ExpressionError(f"the operator {type(node.op).__name__} is not allowed")
        _check(node.operand, names)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            what = node.func.id if isinstance(node.func, ast.Name) else type(node.func).__name__
            raise ExpressionError(f"{what}(...) is not an allowed function")
        if node.keywords:
            raise ExpressionError(f"{node.func.id}() takes no keyword arguments")
        nargs = FUNCTIONS[node.func.id][1]
        if len(node.args) != nargs or any(isinstance(a, ast.Starred) for a in node.args):
            raise ExpressionError(f"{node.func.id}() takes {nargs} argument(s)")
        for a in node.args:
            _check(a, names)
    else:
        raise ExpressionError(f"{type(node).__name__} is not allowed")


def parse(text, valid_names=None) -> Expression:
    """A number or an expression text, checked against the whitelist (and, when given, against
    the valid parameter names). Raises ExpressionError naming the rule."""
    if isinstance(text, bool):
        raise ExpressionError("true/false is not a number")
    if isinstance(text, (int, float)):
        _check(ast.Constant(text), [])
        return Expression(repr(float(text)), (), ast.Expression(ast.Constant(float(text))))
    if not isinstance(text, str):
        raise ExpressionError("must be a number or an expression in quotes")
    if len(text) > MAX_LENGTH:
        raise ExpressionError(f"is longer than {MAX_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExpressionError(f"is not an expression ({exc.msg})") from None
    names: list[str] = []
    _check(tree, names)
    if valid_names is not None:
        for n in names:
            if n not in valid_names:
                raise ExpressionError(f"names '{n}', which is not a parameter of the file")
    return Expression(text, tuple(dict.fromkeys(names)), tree)


def _eval(node, values):
    # NumPy floats, so 1/0, 10.0**400 and (-8)**(1/3) give inf or nan (which the loader refuses
    # at the nominal values and a study counts), never a Python exception or a complex number
    if isinstance(node, ast.Expression):
        return _eval(node.body, values)
    if isinstance(node, ast.Constant):
        return np.float64(node.value)
    if isinstance(node, ast.Name):
        v = CONSTANTS[node.id] if node.id in CONSTANTS else values[node.id]
        return np.float64(v) if isinstance(v, (int, float)) else v  # a Python float: as above
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_eval(node.left, values), _eval(node.right, values))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_eval(node.operand, values))
    if isinstance(node, ast.Call):
        return FUNCTIONS[node.func.id][0](*(_eval(a, values) for a in node.args))
    raise ExpressionError(f"{type(node).__name__} is not allowed")  # unreachable after parse
