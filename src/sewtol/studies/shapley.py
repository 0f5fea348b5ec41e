"""Shapley effects: each tolerance's share of an output's variance, for dependent inputs too
(non-negative, summing to Var(Y) for any law). The estimator is Song, Nelson & Staum (2016),
random permutations, as R sensitivity::shapleyPermRand, with conditional draws exact for the
law's Gaussian copula. `shapley_effects(model, law, m, seed)` takes any vectorised model;
`shapley(mech, tolerances, output, m, seed)` is the study of a protocol mechanism. Machines
without a value are counted (`failed`) and left out. See docs/studies.md.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import special, stats

from sewtol.errors import ParameterError
from sewtol.law import InputLaw, refuse_conditioned

N_INNER, N_OUTER, N_VAR = 3, 1, 1000


def correlation_of(law: InputLaw) -> np.ndarray:
    """The copula's correlation matrix over all of the law's parameters (identity: independent)."""
    r = np.eye(law.dim)
    if law.dependence is not None:
        idx = [law.params.index(p) for p in law.dependence.params]
        r[np.ix_(idx, idx)] = law.dependence.array
    return r


def _root(cov: np.ndarray) -> np.ndarray:
    """A square root A A^T = cov of a positive semi-definite matrix (singular ones too)."""
    w, v = np.linalg.eigh(cov)
    return v * np.sqrt(np.clip(w, 0.0, None))


def _conditional(r: np.ndarray, given: np.ndarray, drawn: np.ndarray):
    """(root of the marginal of z_given, the regression of z_drawn on it, root of the
    conditional covariance of z_drawn) of normal scores with correlation r."""
    r_gg = r[np.ix_(given, given)]
    a = r[np.ix_(drawn, given)] @ np.linalg.pinv(r_gg)
    return _root(r_gg), a, _root(r[np.ix_(drawn, drawn)] - a @ r[np.ix_(given, drawn)])


def _scores(law: InputLaw, m: int, rng: np.random.Generator, n_outer: int, n_inner: int):
    """The permutations (m, d) and the normal scores (m, d - 1, n_outer, n_inner, d) whose
    inner variances estimate c(first j of each permutation) for j = 1 .. d - 1."""
    d = law.dim
    r = correlation_of(law)
    perms = np.array([rng.permutation(d) for _ in range(m)])
    z = np.empty((m, d - 1, n_outer, n_inner, d))
    cache = {}
    for k in range(m):
        for j in range(1, d):
            drawn, given = np.sort(perms[k, :j]), np.sort(perms[k, j:])
            key = tuple(drawn)
            if key not in cache:
                cache[key] = _conditional(r, given, drawn)
            root_g, a, root_c = cache[key]
            zg = rng.standard_normal((n_outer, len(given))) @ root_g.T
            zd = (zg @ a.T)[:, None, :] + rng.standard_normal((n_outer, n_inner, j)) @ root_c.T
            z[k, j - 1][..., given] = zg[:, None, :]
            z[k, j - 1][..., drawn] = zd
    return perms, z


def shapley_effects(model, law: InputLaw, m: int, seed: int | np.random.Generator, *,
                    n_var: int = N_VAR, n_inner: int = N_INNER, n_outer: int = N_OUTER):
    """Shapley effects of `model` (an (N, d) matrix of deviations, columns in law.params ->
    N outputs) under `law`, by m random permutations (the module docstring).

    Returns (effects, se, variance, failed): per parameter its effect in the output's unit
    squared and the standard error over the permutations, Var(Y) from n_var machines (the
    effects sum to it), and how many model values were NaN."""
    for name, v, low in (("m", m, 2), ("n_var", n_var, 2), ("n_inner", n_inner, 2),
                         ("n_outer", n_outer, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise ParameterError(name, f"must be a whole number >= {low}", v)
    if law.dim < 2:
        raise ParameterError("tolerances", "needs two or more tolerances with a non-zero width "
                             "to share the variance among", law.params)
    # the estimator draws X_J given X_-J from the copula; a relation truncates that
    # conditional law, which it does not sample: refused, not ignored
    refuse_conditioned(law, "conditions the law on a relation, which the Shapley estimator does "
                       "not sample; remove the relations", "matches parts within lots, which "
                       "the Shapley estimator does not draw; remove the selective assembly")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(int(seed))
    d = law.dim
    z_var = rng.standard_normal((n_var, d)) @ _root(correlation_of(law)).T
    perms, z = _scores(law, m, rng, n_outer, n_inner)
    rows = np.concatenate([z_var, z.reshape(-1, d)])
    dev = law.deviations(special.ndtr(rows))
    y = np.asarray(model(np.column_stack([dev[p] for p in law.params])), float)
    failed = int(np.count_nonzero(~np.isfinite(y)))
    y = np.where(np.isfinite(y), y, np.nan)
    variance = float(np.nanvar(y[:n_var], ddof=1))
    inner = y[n_var:].reshape(m, d - 1, n_outer, n_inner)
    per_perm = np.empty((m, d))
    with warnings.catch_warnings():
        # all-NaN slices (every machine of a step failed) stay NaN, counted in `failed`
        warnings.simplefilter("ignore", RuntimeWarning)
        cost = np.nanmean(np.nanvar(inner, axis=3, ddof=1), axis=2)
        cost = np.concatenate([np.zeros((m, 1)), cost, np.full((m, 1), variance)], axis=1)
        np.put_along_axis(per_perm, perms, np.diff(cost, axis=1), axis=1)
        effects = np.nanmean(per_perm, axis=0)
        se = np.nanstd(per_perm, axis=0, ddof=1) / np.sqrt(np.sum(np.isfinite(per_perm), axis=0))
    return effects, se, variance, failed


@dataclass(frozen=True)
class ShapleyResult:
    """Shapley effects of one output: per parameter the effect (output unit squared), its share
    of Var(Y) and the share's confidence interval (`to_dataframe`)."""

    mechanism: str
    output: str
    case: str
    tolerances: str
    independent: bool
    m: int
    seed: int
    n_var: int
    params: tuple[str, ...]
    effects: tuple[float, ...]
    se: tuple[float, ...]
    variance: float
    failed: int
    conf_level: float = 0.95

    method = ("Shapley effects, Song, Nelson & Staum (2016) random permutations (R "
              "sensitivity::shapleyPermRand), exact conditional draws of the Gaussian copula; "
              "normal intervals over the permutations")

    def to_dataframe(self) -> pd.DataFrame:
        q = stats.norm.ppf(0.5 + self.conf_level / 2)
        eff, se = np.array(self.effects), np.array(self.se)
        return pd.DataFrame({"param": self.params, "shapley": eff / self.variance,
                             "ci_low": (eff - q * se) / self.variance,
                             "ci_high": (eff + q * se) / self.variance,
                             "effect": eff, "se": se, "case": self.case})

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "output": self.output, "case": self.case,
                "tolerances": self.tolerances, "independent": self.independent,
                "permutations": self.m, "seed": self.seed, "n_var": self.n_var,
                "n_inner": N_INNER, "n_outer": N_OUTER, "variance": self.variance,
                "failed": self.failed, "conf_level": self.conf_level, "method": self.method,
                "rows": self.to_dataframe().to_dict("records")}


def shapley(mech, tolerances, output: str, m: int, seed: int, *, adjust=None,
            n_var: int = N_VAR, fast: bool = True, **options) -> ShapleyResult:
    """Shapley effects of `output` of a protocol mechanism under a tolerance set (by name or
    given; its dependence honoured), m random permutations; adjust: compensators (as
    `adjusting.adjusted` takes them) to study the adjusted output; options go to the
    mechanism's strategy adjuster."""
    from sewtol.protocol import input_law, tolerance_set
    from sewtol.studies.sobol import case_values

    mech.output(output)
    tolerance_set(mech, tolerances).check_against(mech.parameter_record())
    law = input_law(mech, tolerances)
    case = output if adjust is None else f"{output}_adjusted"
    cases = {case: adjust}

    def model(x):
        return case_values(mech, output, cases, law.params, x, fast, options)[0]

    eff, se, var, failed = shapley_effects(model, law, m, seed, n_var=n_var)
    return ShapleyResult(mech.name, output, case, law.name, law.independent, int(m), int(seed),
                         int(n_var), tuple(law.params), tuple(map(float, eff)),
                         tuple(map(float, se)), var, failed)
