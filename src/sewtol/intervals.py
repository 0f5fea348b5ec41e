"""The one interval every yield in sewtol carries: Clopper-Pearson, exact for k successes in n.

SciPy computes it (`binomtest(...).proportion_ci(method="exact")`); this names it once, so every
table, JSON and report line quotes the same doubles for the same k and n."""

from __future__ import annotations

from scipy import stats


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The two-sided exact (Clopper-Pearson) interval of the proportion k / n at `level`."""
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return float(ci.low), float(ci.high)
