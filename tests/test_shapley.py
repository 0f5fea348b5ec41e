"""Shapley effects (studies/shapley.py) against the closed form of a linear model with
correlated Gaussian inputs (Iooss & Prieur 2019)."""

from itertools import combinations
from math import factorial

import numpy as np
import pytest

from sewtol.dependence import Dependence
from sewtol.law import InputLaw
from sewtol.studies.shapley import shapley_effects
from sewtol.tolerances import Tolerance, ToleranceSet


def gaussian_law(sigma, r):
    """X ~ N(0, diag(sigma) r diag(sigma)): normal tolerances (+/-3 sigma) and their copula."""
    items = tuple(Tolerance(f"x{i}", -3 * s, 3 * s, "normal") for i, s in enumerate(sigma))
    names = tuple(t.param for t in items)
    return InputLaw.of(ToleranceSet("gauss", items, dependence=Dependence(
        names, tuple(map(tuple, np.asarray(r, float).tolist())))))


def exact_shapley(beta, cov):
    """The definition, summed over every subset: c(J) = E[Var(Y | X_-J)] of Y = beta^T X, the
    conditional covariance of X_J given X_-J for Gaussian X."""
    d = len(beta)

    def c(J):
        J = list(J)
        if not J:
            return 0.0
        rest = [k for k in range(d) if k not in J]
        s = cov[np.ix_(J, J)]
        if rest:
            # pinv: the conditional law of a singular (one-setup) Gaussian too
            s = s - cov[np.ix_(J, rest)] @ np.linalg.pinv(cov[np.ix_(rest, rest)]) \
                @ cov[np.ix_(rest, J)]
        return float(beta[J] @ s @ beta[J])

    sh = np.zeros(d)
    for i in range(d):
        others = [k for k in range(d) if k != i]
        for size in range(d):
            w = factorial(size) * factorial(d - size - 1) / factorial(d)
            for J in combinations(others, size):
                sh[i] += w * (c(J + (i,)) - c(J))
    return sh


def test_exact_shapley_is_iooss_prieur_closed_form():
    # Iooss & Prieur (2019), linear model with X1 independent of (X2, X3), corr(X2, X3) = rho
    b, s, rho = np.array([1.0, 1.0, 1.0]), np.array([1.0, 1.0, 2.0]), 0.7
    cov = np.diag(s) @ np.array([[1, 0, 0], [0, 1, rho], [0, rho, 1]]) @ np.diag(s)
    cross = rho * b[1] * b[2] * s[1] * s[2]
    closed = [b[0] ** 2 * s[0] ** 2,
              b[1] ** 2 * s[1] ** 2 * (1 - rho ** 2 / 2) + rho ** 2 * b[2] ** 2 * s[2] ** 2 / 2 + cross,
              b[2] ** 2 * s[2] ** 2 * (1 - rho ** 2 / 2) + rho ** 2 * b[1] ** 2 * s[1] ** 2 / 2 + cross]
    np.testing.assert_allclose(exact_shapley(b, cov), closed, rtol=1e-12)
    assert exact_shapley(b, cov).sum() == pytest.approx(b @ cov @ b)


@pytest.mark.parametrize("r", [
    [[1, 0, 0], [0, 1, 0.7], [0, 0.7, 1]],
    [[1, -0.5, 0.3, 0], [-0.5, 1, 0.2, 0], [0.3, 0.2, 1, 0.6], [0, 0, 0.6, 1]],
    [[1, 1, 0], [1, 1, 0], [0, 0, 1]],   # one setup, share 1: a singular copula
])
def test_shapley_matches_the_linear_gaussian_case_within_its_interval(r):
    r = np.asarray(r, float)
    d = len(r)
    sigma = np.array([0.01, 0.02, 0.03, 0.015][:d])
    beta = np.array([3.0, -1.0, 2.0, 1.5][:d])
    law = gaussian_law(sigma, r)
    eff, se, var, failed = shapley_effects(lambda x: x @ beta, law, 4000, 3, n_var=20000)
    cov = np.diag(sigma) @ r @ np.diag(sigma)
    exact = exact_shapley(beta, cov)
    assert failed == 0
    # every effect within its 99 % interval of the exact one; the sum is Var(Y) exactly
    # (each permutation's increments add up to it) and Var(Y) within 3 % of beta^T cov beta
    assert np.all(np.abs(eff - exact) <= 2.58 * se), (eff, exact, se)
    assert eff.sum() == pytest.approx(var, rel=1e-12)
    assert var == pytest.approx(beta @ cov @ beta, rel=0.03)
    assert np.all(se < 0.05 * var)


def test_same_seed_same_effects_and_nan_counted():
    law = gaussian_law([0.01, 0.02], [[1, 0.5], [0.5, 1]])
    a = shapley_effects(lambda x: x.sum(1), law, 50, 9, n_var=100)
    b = shapley_effects(lambda x: x.sum(1), law, 50, 9, n_var=100)
    np.testing.assert_array_equal(a[0], b[0])
    _, _, _, failed = shapley_effects(lambda x: np.where(x[:, 0] > 0.02, np.nan, x.sum(1)),
                                      law, 50, 9, n_var=100)
    assert failed > 0


def test_run_shapley_on_the_needle_with_a_correlated_set(tmp_path):
    from cli_helpers import run, strict_loads

    p = tmp_path / "tied.toml"
    p.write_text('[sets.tied]\nAB = 0.05\nBE = 0.05\nBC = 0.05\ncorrelation = [["AB", "BE", 0.9]]\n')
    code, out, err = run("run", "needle_208", "shapley", "--tolerances", f"{p}:tied", "--n", "30",
                         "--seed", "2", "--adjust", "beta", "--format", "json")
    assert code == 0, err
    obj = strict_loads(out)
    assert obj["independent"] is False and obj["case"] == "SumDelta_um_adjusted"
    assert [r["param"] for r in obj["rows"]] == ["AB", "BE", "BC"]
    assert sum(r["shapley"] for r in obj["rows"]) == pytest.approx(1.0, abs=1e-12)
    assert obj["failed"] == 0 and obj["permutations"] == 30
