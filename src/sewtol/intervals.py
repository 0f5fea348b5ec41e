"""The one interval every yield in sewtol carries: Clopper-Pearson, exact for k successes in n.

Each bound is the p at which a binomial tail equals alpha = (1 - level) / 2: the lower solves
P(X >= k) = alpha, the upper P(X <= k) = alpha, on the Boost binomial sf and cdf that
scipy.stats.binom evaluates (scipy.special's ufuncs, clipped to [0, 1] as binom does), by
Brent's method in scipy.optimize.brentq's steps and tolerances. So the bounds are the doubles of
``scipy.stats.binomtest(k, n).proportion_ci(level, "exact")`` (tests/test_intervals.py holds
them equal), without importing scipy.stats: a second of every command's start-up. The closed
form (betaincinv) lies nearer the root but not on those doubles, which every table prints."""

from __future__ import annotations

from scipy.special import _ufuncs as boost

from sewtol.errors import ParameterError

XTOL, RTOL, MAXITER = 2e-12, 4 * 2.220446049250313e-16, 100  # brentq's defaults


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The two-sided exact (Clopper-Pearson) interval of the proportion k / n at `level`."""
    k, n, level = int(k), int(n), float(level)
    if n < 1:
        raise ParameterError("n", "must be >= 1", n)
    if not 0 <= k <= n:
        raise ParameterError("k", f"must be between 0 and n = {n}", k)
    if not 0 <= level <= 1:
        raise ParameterError("level", "must be between 0 and 1", level)
    alpha = (1 - level) / 2
    low = 0.0 if k == 0 else _root(
        lambda p: min(max(boost._binom_sf(k - 1.0, n, p), 0.0), 1.0) - alpha)
    high = 1.0 if k == n else _root(
        lambda p: min(max(boost._binom_cdf(float(k), n, p), 0.0), 1.0) - alpha)
    return float(low), float(high)


def _root(f) -> float:
    """The p in [0, 1] where f changes sign: inverse quadratic or secant steps while they shrink
    the bracket fast enough, else bisection, as brentq takes them."""
    x_prev, x_now = 0.0, 1.0
    f_prev, f_now = f(x_prev), f(x_now)
    if f_prev * f_now > 0:
        raise ValueError("the binomial tail does not cross alpha on [0, 1]")
    if f_prev == 0 or f_now == 0:
        return x_prev if f_prev == 0 else x_now
    x_far = f_far = step_prev = step = 0.0
    for _ in range(MAXITER):
        if f_prev * f_now < 0:  # the root lies between the last two points
            x_far, f_far = x_prev, f_prev
            step_prev = step = x_now - x_prev
        if abs(f_far) < abs(f_now):  # the better end becomes the current point
            x_prev, x_now, x_far = x_now, x_far, x_now
            f_prev, f_now, f_far = f_now, f_far, f_now
        tol = (XTOL + RTOL * abs(x_now)) / 2
        half = (x_far - x_now) / 2
        if f_now == 0 or abs(half) < tol:
            return x_now
        trial = None
        if abs(step_prev) > tol and abs(f_now) < abs(f_prev):
            if x_prev == x_far:  # secant
                trial = -f_now * (x_now - x_prev) / (f_now - f_prev)
            else:  # inverse quadratic through the three points
                d_prev = (f_prev - f_now) / (x_prev - x_now)
                d_far = (f_far - f_now) / (x_far - x_now)
                trial = (-f_now * (f_far * d_far - f_prev * d_prev)
                         / (d_far * d_prev * (f_far - f_prev)))
        if trial is not None and 2 * abs(trial) < min(abs(step_prev), 3 * abs(half) - tol):
            step_prev, step = step, trial
        else:
            step_prev = step = half
        x_prev, f_prev = x_now, f_now
        x_now += step if abs(step) > tol else (tol if half > 0 else -tol)
        f_now = f(x_now)
    raise RuntimeError(f"Brent's method did not converge in {MAXITER} steps (binomtest neither)")
