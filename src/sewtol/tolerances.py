"""Tolerance specifications: limits and distributions for any parameter, built-in sets, TOML.

A `Tolerance` gives a parameter's limits and how machines scatter inside them; the built-in
sets restate the source study (docs/needle_208.md, "Tolerances").

TOML form (a file of one or more sets):

    [sets.mine]
    description = "what it is"
    LF = { lower = -0.05, upper = 0.05, dist = "uniform" }
    CD = { plus_minus = 0.01 }
    AB = { plus_minus = 0.05, dist = "normal", shift = 0.01 }   # process mean off centre (Cpk)
    correlation = [["AB", "BE", 0.9]]                           # sewtol.dependence
    relations = [{ expr = "AB - BE", lower = -0.01, upper = 0.01 }]   # sewtol.relations
    selective = { params = ["AB", "BE"], groups = 4, by = "count" }  # sewtol.selective
    cost = { model = "reciprocal", AB = { a = 1.0, b = 0.02 } }      # sewtol.costs
"""

from __future__ import annotations

import re
import stat
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sewtol import costs, dependence, relations, selective
from sewtol.costs import CostModel
from sewtol.dependence import Dependence
from sewtol.errors import ParameterError, number, real
from sewtol.relations import Relation
from sewtol.selective import Selective

DISTRIBUTIONS = ("uniform", "normal", "truncnorm")
# a limit beyond this (mm, deg or um) is a typo, not a tolerance
MAX_ABS_LIMIT = 1e6
# the largest |z| a normal draw can reach: ppf of the smallest and largest doubles rng.random()
# gives (2**-53 and 1 - 2**-53) is -8.29 and +8.13 sigma
NORMAL_REACH_SIGMA = 8.3
# a tolerance file is a few lines; anything bigger (or not a regular file) is refused unread
MAX_TOML_BYTES = 1 << 20


def is_branch(param: str) -> bool:
    """Branch choices (branch_M, branch_C, beta_sense, upper_sense) are signs +1/-1 that pick an
    assembly, not dimensions: a tolerance on one is refused when the set is loaded."""
    return param.startswith("branch_") or param.endswith("_sense")


@dataclass(frozen=True)
class Tolerance:
    """The limits and distribution of one parameter's deviation from nominal.

    Validated at construction: finite limits, ``lower <= upper``, a known distribution.

    Parameters
    ----------
    param : str
        The parameter's name, as the mechanism names it (``"CD"``, ``"Ax"``, ...).
    lower, upper : float
        The lower and upper deviation from nominal, in the parameter's unit (mm for lengths and
        coordinates, deg for angles, um for ``guide_shift_um``); e.g. ``-0.8, 0.25``.
    dist : str
        How machines scatter inside: ``"uniform"`` over the limits, ``"normal"`` with the
        limits at +/-3 sigma around their midpoint, or ``"truncnorm"``, that normal cut at the
        limits.
    shift : float
        The process mean's offset from the middle of the limits (normal and truncnorm only;
        the parameter's unit): sigma stays a sixth of the width, so Cp = 1 and
        Cpk = 1 - |shift| / (3 sigma) (`cpk`); truncnorm is that shifted normal cut at the limits.
    """

    param: str
    lower: float
    upper: float
    dist: str = "uniform"
    shift: float = 0.0

    def __post_init__(self):
        for side in ("lower", "upper"):
            v = getattr(self, side)
            number(f"{self.param}.{side}", v)
        if not (np.isfinite(self.lower) and np.isfinite(self.upper)):
            raise ParameterError(f"{self.param}.limits", "must be finite numbers",
                                 (self.lower, self.upper))
        if max(abs(self.lower), abs(self.upper)) > MAX_ABS_LIMIT:
            raise ParameterError(f"{self.param}.limits", f"must be within +/-{MAX_ABS_LIMIT:g} "
                                 "(mm, deg or um)", (self.lower, self.upper))
        if self.lower > self.upper:
            raise ParameterError(f"{self.param}.lower", "must not be above the upper limit",
                                 (self.lower, self.upper))
        if self.dist not in DISTRIBUTIONS:
            raise ParameterError(f"{self.param}.dist",
                                 f"must be one of {', '.join(DISTRIBUTIONS)}", self.dist)
        self._check_shift()

    def _check_shift(self):
        if not real(self.shift, finite=True):
            raise ParameterError(f"{self.param}.shift", "must be a finite number", self.shift)
        if self.shift and self.dist == "uniform":
            raise ParameterError(f"{self.param}.shift", "needs dist normal or truncnorm (a "
                                 "uniform fills its limits: it has no mean to shift)", self.shift)
        if abs(self.shift) >= 0.5 * (self.upper - self.lower) and self.shift:
            raise ParameterError(f"{self.param}.shift", "must keep the mean inside the limits "
                                 f"(|shift| < {0.5 * (self.upper - self.lower):g})", self.shift)

    @property
    def mean(self) -> float:
        """The process mean: the middle of the limits plus the shift (normal, truncnorm)."""
        return self.mid + self.shift

    @property
    def cpk(self) -> float:
        """The process capability of a normal or truncnorm tolerance, 1 - |shift| / (3 sigma)."""
        return 1.0 - abs(self.shift) / (3.0 * self.sigma)

    @property
    def mid(self) -> float:
        """The middle of the limits (mm, or the parameter's unit)."""
        return 0.5 * (self.lower + self.upper)

    @property
    def sigma(self) -> float:
        """A sixth of the width: the normal's sigma with the limits at +/-3 sigma."""
        return (self.upper - self.lower) / 6.0

    def reach(self) -> tuple[float, float]:
        """The smallest and largest deviation a machine can draw."""
        if self.dist == "normal":
            return (self.mean - NORMAL_REACH_SIGMA * self.sigma,
                    self.mean + NORMAL_REACH_SIGMA * self.sigma)
        return self.lower, self.upper

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Deviations for uniform numbers u in (0, 1) (inverse CDF; SALib and Monte-Carlo share it)."""
        if self.upper == self.lower:
            return np.full_like(u, self.lower, dtype=float)
        if self.dist == "uniform":
            return self.lower + (self.upper - self.lower) * u
        from scipy import stats  # here: a second of start-up that uniform sets never need

        if self.dist == "normal":
            return self.mean + self.sigma * stats.norm.ppf(u)
        cut = (-3.0, 3.0) if not self.shift else \
            ((self.lower - self.mean) / self.sigma, (self.upper - self.mean) / self.sigma)
        return self.mean + self.sigma * stats.truncnorm.ppf(u, *cut)

    def salib_dist(self) -> tuple[str, list[float]]:
        """The same distribution as SALib's problem 'dists' and 'bounds' entries."""
        if self.dist == "uniform":
            return "unif", [self.lower, self.upper]
        if self.dist == "normal":
            return "norm", [self.mean, self.sigma]
        return "truncnorm", [self.lower, self.upper, self.mean, self.sigma]


@dataclass(frozen=True)
class ToleranceSet:
    """A named set of tolerances, one per parameter: what a study draws machines from.

    Built in (`NEEDLE_208_SETS`, or ``sewtol.tolerance_set("recommended")``), read from a TOML
    file, or built here. Vary it by copying: ``scaled({"CD": 0.5})`` halves CD's limits.

    Parameters
    ----------
    name : str
        The set's name (it labels tables and study folders).
    items : tuple of Tolerance
        The tolerances; a parameter may appear once. Parameters not named stay nominal.
    description : str
        What the set is, in words.
    nominal_names : tuple of str
        The mechanism's parameter names, if known (not compared).
    dependence : Dependence or None
        A Gaussian copula tying some of the parameters (`sewtol.dependence`); None: every
        deviation is drawn on its own.
    relations : tuple of Relation
        Limits on quantities derived from several deviations (`sewtol.relations`, e.g.
        AB - BE): the machines built are the joint law's conditioned on every one.
    selective : Selective or None
        Two parts measured, sorted into classes and matched at assembly (`sewtol.selective`).
    cost : tuple of CostModel
        What each tolerance costs to make, as a function of its half-width (`sewtol.costs`;
        read by the least-cost allocation, sewtol.studies.least_cost); empty: not given.
    """

    name: str
    items: tuple[Tolerance, ...]
    description: str = ""
    nominal_names: tuple[str, ...] = field(default=(), compare=False)
    dependence: Dependence | None = None
    relations: tuple[Relation, ...] = ()
    selective: Selective | None = None
    cost: tuple[CostModel, ...] = ()

    def __post_init__(self):
        seen = set()
        for t in self.items:
            if t.param in seen:
                raise ParameterError(t.param, f"is named twice in tolerance set '{self.name}'",
                                     t.param)
            seen.add(t.param)
        if self.dependence is not None and not set(self.dependence.params) <= seen:
            raise ParameterError(self.dependence.where, f"ties parameters the set '{self.name}' "
                                 "does not tolerance", sorted(set(self.dependence.params) - seen))
        for r in self.relations:
            if not set(r.names) <= seen:
                raise ParameterError(f"{r.where}.expr", f"names parameters the set '{self.name}' "
                                     "does not tolerance", sorted(set(r.names) - seen))
        if self.selective is not None and not set(self.selective.params) <= seen:
            raise ParameterError(f"{self.selective.where}.params", f"names parameters the set "
                                 f"'{self.name}' does not tolerance",
                                 sorted(set(self.selective.params) - seen))
        for c in self.cost:
            if c.param not in seen:
                raise ParameterError(c.where or f"cost.{c.param}", f"names a parameter the set "
                                     f"'{self.name}' does not tolerance", c.param)

    def check_against(self, nominal) -> ToleranceSet:
        """Refuse a set that can draw a machine the parameter rules reject (a length <= 0, a
        branch sign other than +/-1, a non-finite value) before anything runs."""
        from sewtol.mechanisms import params as P

        valid = P.field_names(type(nominal))
        self.check_names(valid)
        for t in self.active().items:
            for side, d in zip(("lower", "upper"), t.reach(), strict=True):
                try:
                    P.with_deviations(nominal, {t.param: np.array([d])})
                except ParameterError as exc:
                    value = float(np.asarray(getattr(nominal, t.param), float)) + d
                    where = side if t.dist != "normal" else f"{side} reach ({NORMAL_REACH_SIGMA:g} sigma)"
                    raise ParameterError(f"{self.name}.{t.param}.{side}",
                                         f"its {where} gives machines with {t.param} = "
                                         f"{value:.6g}, but {t.param} {exc.rule}", d) from None
        return self

    @property
    def params(self) -> list[str]:
        """The toleranced parameters, in the set's order."""
        return [t.param for t in self.items]

    def active(self) -> ToleranceSet:
        """Only the tolerances with a non-zero width (the ones that scatter)."""
        items = tuple(t for t in self.items if t.upper > t.lower)
        # a relation keeps a parameter of zero width: its deviation is 0 (sewtol.relations)
        return ToleranceSet(self.name, items, self.description, dependence=None
                            if self.dependence is None else
                            self.dependence.restrict([t.param for t in items]),
                            relations=self.relations,
                            # a part of zero width needs no sorting (every one is the same size)
                            selective=self.selective if self.selective is not None and set(
                                self.selective.params) <= {t.param for t in items} else None,
                            cost=tuple(c for c in self.cost if c.param in {t.param for t in items}))

    def check_names(self, valid: list[str]) -> ToleranceSet:
        """This set, if every parameter is in `valid`; otherwise ParameterError listing the valid names."""
        for t in self.items:
            if t.param not in valid:
                raise ParameterError(t.param, f"unknown parameter in tolerance set '{self.name}'; "
                                     f"valid names are {', '.join(valid)}", t.param)
            if is_branch(t.param) and t.upper > t.lower:
                raise ParameterError(f"{self.name}.{t.param}", "is a branch choice (+1 or -1), "
                                     "not a dimension, and cannot be toleranced; choose the "
                                     "branch with --set", (t.lower, t.upper))
        return self

    def sample(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        """n machines' deviations from nominal, one array per parameter, each drawn on its own
        (the marginals only: the set's dependence is the input law's, sewtol.law.InputLaw,
        whose `draw` is the one sampler of every study)."""
        return self.from_unit(rng.random((n, len(self.items))))

    def from_unit(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """Deviations for standard uniforms u (n, one column per tolerance, in order), each
        column through its own marginal (no dependence: InputLaw.of_uniforms ties them)."""
        return {t.param: t.from_unit(u[:, i]) for i, t in enumerate(self.items)}

    def limit_variants(self) -> tuple[list[str], list[str], list[float], dict[str, np.ndarray]]:
        """One machine per tolerance and side (upper, then lower), the others nominal:
        (param, side, deviation) per machine and the deviations as a batch."""
        params, sides, deltas = [], [], []
        for t in self.items:
            for side, d in (("upper", t.upper), ("lower", t.lower)):
                params.append(t.param)
                sides.append(side)
                deltas.append(d)
        dev = {k: np.array([d if p == k else 0.0 for p, d in zip(params, deltas, strict=True)])
               for k in dict.fromkeys(params)}
        return params, sides, deltas, dev

    def scaled(self, factors: dict[str, float], name: str | None = None) -> ToleranceSet:
        """Each named tolerance's limits times its factor. The copy gets a new name (by default
        the factors appended, e.g. "recommended*CD=0.5"), so results of a scaled set are never
        labelled as the original set."""
        unknown = sorted(set(factors) - set(self.params))
        if unknown:
            raise ParameterError("factors", f"name tolerances not in set '{self.name}' "
                                 f"({', '.join(self.params)})", unknown)
        for k, f in factors.items():
            if not real(f, finite=True) or f < 0:
                raise ParameterError(f"factors.{k}", "must be a finite number >= 0", f)
        changed = {k: f for k, f in factors.items() if f != 1.0}
        if name is None:
            name = self.name + "".join(f"*{k}={float(f):g}" for k, f in changed.items())
        return ToleranceSet(name, tuple(
            Tolerance(t.param, t.lower * factors.get(t.param, 1.0),
                      t.upper * factors.get(t.param, 1.0), t.dist,
                      t.shift * factors.get(t.param, 1.0)) for t in self.items),
            self.description + (f" (scaled: {', '.join(f'{k} x{float(f):g}' for k, f in changed.items())})"
                                if changed else ""), dependence=self.dependence,
            relations=self.relations, selective=self.selective, cost=self.cost)

    def as_dict(self) -> dict:
        """The set as plain data: per parameter its lower and upper limit and distribution."""
        return {t.param: {"lower": t.lower, "upper": t.upper, "dist": t.dist,
                          **({"shift": t.shift} if t.shift else {})} for t in self.items}

    def as_record(self) -> dict:
        """What a study's manifest and run.json record of the set: its name, items and, for a
        set that ties parameters, the copula's matrix, and its relations (a set without either
        records no key, so its records are as before)."""
        tied = self.dependence
        return {"name": self.name, "items": self.as_dict(),
                **({} if tied is None else {"dependence": {
                    "params": list(tied.params), "matrix": [list(r) for r in tied.matrix]}}),
                **({"relations": [r.as_dict() for r in self.relations]} if self.relations
                   else {}),
                **({} if self.selective is None else {"selective": self.selective.as_dict()}),
                **({"cost": {c.param: c.as_dict() for c in self.cost}} if self.cost else {})}


def _sym(param, pm, dist="uniform"):
    return Tolerance(param, -pm, pm, dist)


NEEDLE_208_SETS = {
    "base": ToleranceSet("base", (
        _sym("LF", 0.05), _sym("LM", 0.5), _sym("AM", 0.1), _sym("AB", 0.05), _sym("BC", 0.05),
        _sym("BE", 0.05)),
        "source study, base tolerances (CD not toleranced in the source)"),
    "recommended": ToleranceSet("recommended", (
        Tolerance("LF", -0.8, 0.25), _sym("LM", 0.5), _sym("AM", 0.5), _sym("AB", 0.05),
        _sym("BC", 0.05), _sym("BE", 0.05), _sym("CD", 0.01)),
        "source study, recommended tolerances"),
}
"""The source study's tolerance sets of the 208 needle drive, by name (lengths in mm).

``base``: LF +/-0.05, LM +/-0.5, AM +/-0.1, AB, BC, BE +/-0.05, CD exact (the source gives it no
base tolerance). ``recommended``: LF +0.25/-0.8, LM +/-0.5, AM +/-0.5, AB, BC, BE +/-0.05,
CD +/-0.01. All uniform.
"""


# The housing bores of the 208, A, D and the guide (ASSUMED: the source tolerances none of them;
# docs/needle_208.md, "Housing tolerances"): ISO 1101 position diameter 0.04 mm, drawn as +-0.02
# mm per coordinate; the guide's direction 0.02 mm over its 50 mm, +-0.0229 deg.
NEEDLE_208_HOUSING = (
    _sym("Ax", 0.02), _sym("Ay", 0.02), _sym("Dx", 0.02), _sym("Dy", 0.02),
    _sym("guide_x", 0.02), _sym("guide_y", 0.02), _sym("guide_angle", 0.0229))
HOUSING_DESCRIPTION = ("housing bores A, D and the guide (assumed: position +-0.02 mm per "
                       "coordinate, guide direction +-0.0229 deg)")


def with_housing(tolerances: ToleranceSet, housing=NEEDLE_208_HOUSING,
                 name: str | None = None) -> ToleranceSet:
    """The set plus the housing tolerances (default: the 208's, `NEEDLE_208_HOUSING`), named
    ``NAME_housing``. A parameter the set already tolerances is refused (the housing would
    replace its tolerance silently)."""
    own = {t.param for t in tolerances.items}
    twice = [t.param for t in housing if t.param in own]
    if twice:
        raise ParameterError(twice[0], f"is toleranced by set '{tolerances.name}' already; the "
                             "housing tolerances would replace it", tolerances.name)
    return replace(tolerances, name=name or f"{tolerances.name}_housing",
                   items=tolerances.items + tuple(housing),
                   description=f"{tolerances.name} set plus {HOUSING_DESCRIPTION}")


NEEDLE_208_HOUSING_SETS = {f"{k}_housing": with_housing(v) for k, v in NEEDLE_208_SETS.items()}
"""Every built-in set of the 208 with the housing tolerances added (`with_housing`):
``base_housing``, ``recommended_housing``. Kept apart from NEEDLE_208_SETS (the sets the
committed reports rest on); every needle study takes them by name."""


def needle_builtin_sets() -> dict[str, ToleranceSet]:
    """The names a needle study takes as built-in sets: NEEDLE_208_SETS and their housing
    variants (NEEDLE_208_HOUSING_SETS)."""
    return {**NEEDLE_208_SETS, **NEEDLE_208_HOUSING_SETS}


SYMMETRIC_RULE = ("must not be negative: a symmetric tolerance +/-X needs X >= 0 (give lower "
                  "and upper for a one-sided one)")


def parse_item(set_name: str, param: str, spec) -> Tolerance:
    where = f"{set_name}.{param}"
    if not isinstance(spec, dict):
        if not real(spec):
            raise ParameterError(where, "must be a number (+/-) or a table with lower/upper or "
                                 "plus_minus", spec)
        pm = float(spec)
        if pm < 0:
            raise ParameterError(where, SYMMETRIC_RULE, pm)
        return _sym(param, pm)
    allowed = {"lower", "upper", "plus_minus", "dist", "shift"}
    extra = set(spec) - allowed
    if extra:
        raise ParameterError(where, f"unknown keys {sorted(extra)}; allowed: {sorted(allowed)}",
                             spec)
    dist = spec.get("dist", "uniform")
    if not isinstance(dist, str):
        raise ParameterError(f"{where}.dist", f"must be one of {', '.join(DISTRIBUTIONS)}", dist)
    shift = number(f"{where}.shift", spec.get("shift", 0.0))
    if "plus_minus" in spec:
        if "lower" in spec or "upper" in spec:
            raise ParameterError(where, "give either plus_minus or lower and upper, not both",
                                 spec)
        pm = number(f"{where}.plus_minus", spec["plus_minus"])
        if pm < 0:
            raise ParameterError(f"{where}.plus_minus", SYMMETRIC_RULE, pm)
        return Tolerance(param, -pm, pm, dist, shift)
    if "lower" not in spec or "upper" not in spec:
        raise ParameterError(where, "needs both lower and upper (or plus_minus)", spec)
    return Tolerance(param, number(f"{where}.lower", spec["lower"]),
                     number(f"{where}.upper", spec["upper"]), dist, shift)


def parse_toml(text: str, field) -> dict:
    """tomllib.loads, every refusal one ParameterError; field(line) names the place (line 1
    when the parser gives none)."""
    if text.startswith("\ufeff"):
        raise ParameterError(field(1), "starts with a UTF-8 byte-order mark (BOM); save it as "
                             "UTF-8 without BOM", "\ufeff")
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise ParameterError(field(1), "nests arrays or inline tables too deeply to parse",
                             "thousands of levels") from None
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        m = re.search(r"line (\d+)", str(exc))
        raise ParameterError(field(int(m.group(1)) if m else 1), "is not valid TOML",
                             str(exc)) from None


def read_toml_text(path: str | Path, limit: int = MAX_TOML_BYTES,
                   what: str = "a tolerance file is a few lines") -> str:
    """The text of a small UTF-8 file; every refusal one ParameterError naming the path."""
    path = Path(path)
    try:
        # stat first: a FIFO would block and /dev/zero would never end
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):
            raise ParameterError(str(path), "is not a regular file", _kind(st.st_mode))
        if st.st_size > limit:
            raise ParameterError(str(path), f"is larger than {limit} bytes; {what}", st.st_size)
        with open(path, "rb") as fh:
            raw = fh.read(limit + 1)
        if len(raw) > limit:
            raise ParameterError(str(path), f"is larger than {limit} bytes", len(raw))
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError(str(path), "is not UTF-8 text (TOML files are UTF-8)",
                             f"byte {exc.object[exc.start]:#04x} at offset {exc.start}") from None
    except OSError as exc:
        raise ParameterError(str(path), "cannot be read", exc.strerror) from None


def load_toml(path: str | Path, valid_params: list[str] | None = None) -> dict[str, ToleranceSet]:
    """Tolerance sets from a TOML file; a syntax error reports its line and column."""
    data = parse_toml(read_toml_text(path), lambda line: str(path))
    sets = data.get("sets")
    if not isinstance(sets, dict) or not sets:
        raise ParameterError(str(path), "must hold at least one [sets.NAME] table", list(data))
    out = {}
    for name, body in sets.items():
        if not isinstance(body, dict):
            raise ParameterError(f"sets.{name}", "must be a table", body)
        desc = str(body.get("description", ""))
        items = tuple(parse_item(name, k, v) for k, v in body.items()
                      if k != "description" and k not in dependence.KEYS
                      and k not in (relations.KEY, selective.KEY, costs.KEY))
        known = [t.param for t in items]
        ts = ToleranceSet(name, items, desc, dependence=dependence.parse(name, body, known),
                          relations=relations.parse(name, body, known),
                          selective=selective.parse(name, body, known),
                          cost=costs.parse(name, body, known))
        if valid_params is not None:
            ts.check_names(valid_params)
        out[name] = ts
    return out


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _file_and_set(spec: str) -> tuple[str, str]:
    """'FILE' or 'FILE:SET' split at the last ':' (a folder may be named x.toml.d; a file
    that exists is taken whole)."""
    if ":" in spec and not Path(spec).is_file():
        path, _, set_name = spec.rpartition(":")
        return path, set_name
    return spec, ""


def resolve(name_or_path: str, builtin: dict[str, ToleranceSet],
            valid_params: list[str]) -> ToleranceSet:
    """A built-in set by name, or 'file.toml' (its only set) / 'file.toml:NAME'."""
    if name_or_path in builtin:
        return builtin[name_or_path]
    if ".toml" not in name_or_path:
        raise ParameterError("--tolerances", f"must be one of {', '.join(builtin)} or a .toml "
                             "file", name_or_path)
    path, set_name = _file_and_set(name_or_path)
    sets = load_toml(path, valid_params)
    if not set_name:
        if len(sets) != 1:
            raise ParameterError("--tolerances", f"the file holds several sets; name one as "
                                 f"FILE.toml:NAME, one of {', '.join(sets)}", name_or_path)
        return next(iter(sets.values()))
    if set_name not in sets:
        raise ParameterError("--tolerances", f"no set '{set_name}' in the file; sets are "
                             f"{', '.join(sets)}", name_or_path)
    return sets[set_name]


def resolve_all(specs: list[str] | None, builtin: dict[str, ToleranceSet],
                valid_params: list[str]) -> dict[str, ToleranceSet]:
    """The tolerance sets a report runs on: every built-in set when specs is empty; otherwise,
    for each spec, a built-in name, 'file.toml' (every set in the file) or 'file.toml:NAME'."""
    if not specs:
        return dict(builtin)
    out: dict[str, ToleranceSet] = {}
    for spec in specs:
        path, name = _file_and_set(spec)
        if spec not in builtin and ".toml" in spec and not name:
            found = load_toml(path, valid_params)
        else:
            ts = resolve(spec, builtin, valid_params)
            found = {ts.name: ts}
        for set_name, ts in found.items():
            if set_name in out:
                raise ParameterError("--tolerances", "names a set twice; every set of a report "
                                     "needs its own name", set_name)
            out[set_name] = ts
    return out


def needle_set(tolerances: ToleranceSet | str) -> ToleranceSet:
    """The needle tolerance set a study was given: a ToleranceSet as it is, or a built-in name
    ("base", "recommended", "base_housing", "recommended_housing") or "FILE.toml[:SET]"."""
    if isinstance(tolerances, ToleranceSet):
        return tolerances
    if isinstance(tolerances, str):
        from sewtol.mechanisms.needle_208.model import Needle208
        from sewtol.mechanisms.params import field_names

        return resolve(tolerances, needle_builtin_sets(), field_names(Needle208))
    raise ParameterError("tolerances", "must be a ToleranceSet, a set name (base, recommended, "
                         "base_housing, recommended_housing) or 'FILE.toml[:SET]'",
                         type(tolerances).__name__)
