"""Cost-tolerance models: what it costs to make a parameter within a tolerance.

The three models of Chase, Greenwood & Loosli (1990), Manufacturing Review 3(1), of the
half-width t = (upper - lower) / 2 (the parameter's unit; where the zone sits costs nothing):

    reciprocal     c(t) = a + b / t
    power          c(t) = a + b / t**k
    exponential    c(t) = a + b * exp(-m t)

with a >= 0, b > 0, k > 0, m > 0. A set's `cost` table (docs/mechanism_files.md, "Cost of a
tolerance") gives the coefficients; sewtol states no defaults (they are the shop's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sewtol.errors import ParameterError, number, real

KEY = "cost"
# each model's coefficients (every one required)
MODELS = {"reciprocal": ("a", "b"), "power": ("a", "b", "k"), "exponential": ("a", "b", "m")}


@dataclass(frozen=True)
class CostModel:
    """The cost of one parameter's tolerance as a function of the zone's half-width t.

    Validated at construction: a known model, a >= 0, b > 0, k > 0 (power), m > 0 (exponential),
    all finite; the error names `where` (e.g. ``"mine.cost.AB"``)."""

    param: str
    model: str
    a: float
    b: float
    k: float = 1.0
    m: float = 0.0
    where: str = ""

    def __post_init__(self):
        at = self.where or f"cost.{self.param}"
        if self.model not in MODELS:
            raise ParameterError(f"{at}.model", f"must be one of {', '.join(MODELS)}",
                                 self.model)
        for key in ("a", "b", "k", "m"):
            v = getattr(self, key)
            if not real(v, finite=True):
                raise ParameterError(f"{at}.{key}", "must be a finite number", v)
        if self.a < 0:
            raise ParameterError(f"{at}.a", "must be >= 0 (the fixed cost)", self.a)
        if self.b <= 0:
            raise ParameterError(f"{at}.b", "must be > 0 (the cost of precision)", self.b)
        if self.model == "power" and self.k <= 0:
            raise ParameterError(f"{at}.k", "must be > 0 (the exponent of 1/t)", self.k)
        if self.model == "exponential" and self.m <= 0:
            raise ParameterError(f"{at}.m", "must be > 0 (the decay rate, 1/unit)", self.m)

    def cost(self, t) -> np.ndarray:
        """The cost of half-width(s) t (> 0; the parameter's unit)."""
        t = np.asarray(t, float)
        if self.model == "reciprocal":
            return self.a + self.b / t
        if self.model == "power":
            return self.a + self.b / t**self.k
        return self.a + self.b * np.exp(-self.m * t)

    def formula(self) -> str:
        """The model with its coefficients, e.g. "0.5 + 0.02/t"."""
        if self.model == "reciprocal":
            return f"{self.a:g} + {self.b:g}/t"
        if self.model == "power":
            return f"{self.a:g} + {self.b:g}/t^{self.k:g}"
        return f"{self.a:g} + {self.b:g}*exp(-{self.m:g} t)"

    def as_dict(self) -> dict:
        return {"model": self.model, **{k: float(getattr(self, k)) for k in MODELS[self.model]}}


def model_of(param: str, spec, where: str, default: str | None = None) -> CostModel:
    """A CostModel from its table {model = .., a = .., b = .., k|m = ..} (model defaults to
    `default`); unknown or missing keys are refused in one line."""
    if not isinstance(spec, dict):
        raise ParameterError(where, "must be a table { model = \"reciprocal\", a = .., b = .. }",
                             spec)
    model = spec.get("model", default)
    if model is None:
        raise ParameterError(f"{where}.model", "must be given (here or as the table's default "
                             f"model): one of {', '.join(MODELS)}", None)
    if model not in MODELS:
        raise ParameterError(f"{where}.model", f"must be one of {', '.join(MODELS)}", model)
    need = MODELS[model]
    extra = sorted(set(spec) - {"model", *need})
    if extra:
        raise ParameterError(where, f"unknown keys {extra} for model {model}; it takes "
                             f"{', '.join(need)}", spec)
    missing = [k for k in need if k not in spec]
    if missing:
        raise ParameterError(f"{where}.{missing[0]}", f"is required by model {model} "
                             f"({model_text(model)})", None)
    v = {k: number(f"{where}.{k}", spec[k]) for k in need}
    return CostModel(param, model, v["a"], v["b"], k=v.get("k", 1.0), m=v.get("m", 0.0),
                     where=where)


def model_text(model: str) -> str:
    return {"reciprocal": "c = a + b/t", "power": "c = a + b/t^k",
            "exponential": "c = a + b exp(-m t)"}[model]


def parse(set_name: str, body: dict, known: list[str]) -> tuple[CostModel, ...]:
    """The cost models a tolerance set's table declares (key `cost`, the module docstring), for
    the set's parameters `known`."""
    table = body.get(KEY)
    if table is None:
        return ()
    where = f"{set_name}.{KEY}"
    if not isinstance(table, dict):
        raise ParameterError(where, "must be a table: model = \"...\" and PARAM = { a = .., "
                             "b = .. }", table)
    default = table.get("model")
    if default is not None and default not in MODELS:
        raise ParameterError(f"{where}.model", f"must be one of {', '.join(MODELS)}", default)
    out = []
    for param, spec in table.items():
        if param == "model":
            continue
        if param not in known:
            raise ParameterError(f"{where}.{param}", "must name a toleranced parameter of the "
                                 f"set ({', '.join(known)})", param)
        out.append(model_of(param, spec, f"{where}.{param}", default))
    return tuple(out)


def parse_flag(text: str) -> tuple[str | None, CostModel]:
    """`--cost [NAME=]MODEL:a=A,b=B[,k=K|m=M]`: (NAME or None for every parameter, the model
    with param NAME or "*")."""
    name, eq, rest = text.partition("=")
    if eq and ":" not in name and name.strip() not in MODELS:
        param, body = name.strip(), rest
    else:
        param, body = None, text
    model, colon, coeffs = body.partition(":")
    spec: dict = {"model": model.strip()}
    for item in filter(None, (c.strip() for c in coeffs.split(","))) if colon else ():
        key, eq2, value = item.partition("=")
        try:
            spec[key.strip()] = float(value)
        except ValueError:
            raise ParameterError("--cost", "must be [NAME=]MODEL:a=A,b=B[,k=K|m=M] (numbers)",
                                 text) from None
        if not eq2:
            raise ParameterError("--cost", "must be [NAME=]MODEL:a=A,b=B[,k=K|m=M]", text)
    return param, model_of(param or "*", spec, "--cost")
