"""The Clopper-Pearson interval: the same doubles as scipy.stats.binomtest's exact interval (which
every committed table and JSON quotes), from scipy.special alone; its defining tail equations;
bad input named."""

import numpy as np
import pytest
from scipy import special, stats

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson

LEVELS = (0.95, 0.90, 0.99)  # 0.95 everywhere, 0.90 the rare-event bound at k = 0


def grid():
    """k at both ends, next to them, in the middle and at random, for n from 1 to 10^7."""
    rng = np.random.default_rng(25)
    for n in (1, 2, 3, 7, 10, 50, 100, 300, 1000, 2000, 4000, 20_000, 10**5, 10**6, 10**7):
        ks = {0, 1, 2, n // 2, n - 2, n - 1, n, *rng.integers(0, n + 1, 4).tolist()}
        yield from ((k, n) for k in sorted(ks) if 0 <= k <= n)


@pytest.mark.parametrize("level", LEVELS)
def test_the_same_doubles_as_binomtest(level):
    cases = list(grid())
    assert len(cases) > 100
    for k, n in cases:
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
        # exact equality: the doubles are what reports print in full
        assert clopper_pearson(k, n, level) == (ci.low, ci.high), (k, n, level)


def test_the_bounds_solve_the_tail_equations():
    """Each bound is where its binomial tail equals (1 - level) / 2: the beta quantile in closed
    form, met to brentq's tolerance (2e-12 in p); at k = 0 and k = n, 1 - alpha ** (1 / n)."""
    for k, n in [(1, 10), (72, 1000), (89, 1000), (999, 1000), (12_345, 10**6)]:
        low, high = clopper_pearson(k, n)
        assert low == pytest.approx(special.betaincinv(k, n - k + 1, 0.025), abs=4e-12)
        assert high == pytest.approx(special.betaincinv(k + 1, n - k, 0.975), abs=4e-12)
    assert clopper_pearson(0, 10) == (0.0, pytest.approx(1 - 0.025 ** 0.1, abs=4e-12))
    assert clopper_pearson(10, 10) == (pytest.approx(0.025 ** 0.1, abs=4e-12), 1.0)


@pytest.mark.parametrize("k, n, level, field", [(3, 0, 0.95, "n"), (-1, 10, 0.95, "k"),
                                                (11, 10, 0.95, "k"), (3, 10, 1.5, "level")])
def test_bad_input_is_named(k, n, level, field):
    with pytest.raises(ParameterError) as exc:
        clopper_pearson(k, n, level)
    assert exc.value.field == field
