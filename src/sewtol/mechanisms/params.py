"""Shared machinery of parameter dataclasses: validation rules, overrides by name, batches.

A parameter set holds floats for one machine or equal-length 1-D arrays for a batch of machines
(a Monte-Carlo sample); the kernels broadcast either way. Vary a set with `override` or
`dataclasses.replace`, never by mutation.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from sewtol.errors import ParameterError


def freeze(params) -> None:
    """Called first in __post_init__: every array field becomes a read-only float copy, so a
    frozen set neither shares memory with the caller nor can be changed through an array
    (`p.LF[0] = -1` raises instead of bypassing the checks)."""
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if isinstance(v, (np.ndarray, list, tuple)):
            try:
                a = np.array(v, dtype=float)  # a copy
            except (TypeError, ValueError):
                raise ParameterError(f.name, "must be a number or an array of numbers",
                                     v) from None
            a.setflags(write=False)
            object.__setattr__(params, f.name, a)


def positive(name: str, value) -> None:
    finite(name, value)
    if np.any(np.asarray(value, float) <= 0.0):
        raise ParameterError(name, "must be a positive length in mm", show(value))


def finite(name: str, value) -> None:
    v = np.asarray(value, float)
    if not np.all(np.isfinite(v)):
        raise ParameterError(name, "must be a finite number", show(value))


def branch(name: str, value) -> None:
    v = np.asarray(value, float)
    if not np.all(np.isin(v, (-1.0, 1.0))):
        raise ParameterError(name, "must be +1 (left) or -1 (right)", show(value))


def show(value):
    """A value as an error message shows it: a number, or an array's size and a bad element."""
    v = np.asarray(value, float)
    if v.ndim == 0:
        return float(v)
    bad = v[~np.isfinite(v) | (v <= 0)] if v.size else v
    return f"array of {v.size}, e.g. {float(bad.flat[0]) if bad.size else float(v.flat[0])}"


def check_rule(name: str, rule: str, value) -> None:
    """Raise ParameterError if value (a number or an array) breaks the parameter's rule
    (mechanism files: positive, branch, nonnegative or finite)."""
    if rule == "positive":
        positive(name, value)
    elif rule == "branch":
        branch(name, value)
    else:
        finite(name, value)
        if rule == "nonnegative" and np.any(np.asarray(value, float) < 0):
            raise ParameterError(name, "must not be negative", show(value))


def field_names(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def check_names(names, valid: list[str]) -> None:
    """Refuse the first of `names` that is not in `valid`, listing the valid ones."""
    for name in names:
        if name not in valid:
            raise ParameterError(name, f"unknown parameter; valid names are {', '.join(valid)}",
                                 name)


def override(params, changes: dict[str, Any]):
    """A copy with the named fields changed; unknown names fail and list the valid ones."""
    check_names(changes, field_names(type(params)))
    return dataclasses.replace(params, **changes)


def batch_size(params) -> int | None:
    """Number of machines in a batch set, None for a single machine."""
    sizes = {np.asarray(getattr(params, f)).size for f in field_names(type(params))
             if np.asarray(getattr(params, f)).ndim > 0}
    if not sizes:
        return None
    if len(sizes) > 1:
        raise ParameterError("batch", "all array parameters must have the same length", sorted(sizes))
    return sizes.pop()


def column(params, n: int | None):
    """Fields as arrays shaped (n, 1) so they broadcast against (n, angles); scalars stay scalars."""
    out = {}
    for f in field_names(type(params)):
        v = np.asarray(getattr(params, f), float)
        out[f] = v.reshape(-1, 1) if (n is not None and v.ndim > 0) else v
    return out


def take(params, index):
    """Machine(s) `index` of a batch set (scalars are kept)."""
    changes = {}
    for f in field_names(type(params)):
        v = getattr(params, f)
        if np.asarray(v).ndim > 0:
            sub = np.asarray(v)[index]
            changes[f] = float(sub) if np.ndim(sub) == 0 else sub
    return dataclasses.replace(params, **changes)


def as_dict(params) -> dict[str, Any]:
    out = {}
    for f in field_names(type(params)):
        v = getattr(params, f)
        out[f] = v.tolist() if isinstance(v, np.ndarray) else v
    return out


def with_deviations(params, deviations: dict[str, np.ndarray]):
    """A batch: nominal plus each machine's deviation (arrays of equal length) per named field."""
    check_names(deviations, field_names(type(params)))
    return dataclasses.replace(params, **{
        k: np.asarray(getattr(params, k), float) + np.asarray(v, float)
        for k, v in deviations.items()})
