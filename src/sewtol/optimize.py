"""Batched scalar searches: every machine of a batch steps together (no Python loop over machines).

Brackets are arrays of shape (n,); the objective takes an (n,) array and returns an (n,) array.
"""

from __future__ import annotations

import numpy as np

_INVPHI = (np.sqrt(5.0) - 1.0) / 2.0


def golden_min(fun, lo, hi, xtol: float = 1e-10, maxiter: int = 200, value: bool = True,
               cutoff: bool = False):
    """Minimise a unimodal function on [lo, hi] per element by golden-section search.

    Returns (x, f(x)) (value=False: (x, None), two evaluations fewer: of x and of the last
    interior point, never compared). Stops when every bracket is narrower than xtol (same unit
    as x). cutoff=True: fun(x, other) is also given the value of the interior point each new
    one is compared with; where the new one cannot beat it, fun may return any value above it
    instead of its own (it loses either way, and a point that loses is dropped): the same x.
    """
    a = np.array(lo, float, copy=True)
    b = np.array(hi, float, copy=True)
    c = b - _INVPHI * (b - a)
    d = a + _INVPHI * (b - a)
    fc = fun(c, np.full(np.shape(c), np.inf)) if cutoff else fun(c)
    fd = fun(d, fc) if cutoff else fun(d)  # compared with c first
    for _ in range(maxiter):
        if np.all(np.abs(b - a) < xtol):
            break
        left = fc < fd  # the minimum lies in [a, d]
        a, b = np.where(left, a, c), np.where(left, d, b)
        # one interior point is kept from the last step; only the other is evaluated
        c_new = np.where(left, b - _INVPHI * (b - a), d)
        d_new = np.where(left, c, a + _INVPHI * (b - a))
        if not value and np.all(np.abs(b - a) < xtol):
            break
        x_new = np.where(left, c_new, d_new)
        f_new = fun(x_new, np.where(left, fc, fd)) if cutoff else fun(x_new)
        fc, fd = np.where(left, f_new, fd), np.where(left, fc, f_new)
        c, d = c_new, d_new
    x = 0.5 * (a + b)
    return x, (fun(x) if value else None)


def bisect_root(fun, lo, hi, xtol: float = 1e-10, maxiter: int = 200):
    """Root of fun per element in [lo, hi] where fun(lo) and fun(hi) differ in sign."""
    a = np.array(lo, float, copy=True)
    b = np.array(hi, float, copy=True)
    fa = fun(a)
    for _ in range(maxiter):
        if np.all(np.abs(b - a) < xtol):
            break
        m = 0.5 * (a + b)
        fm = fun(m)
        same = np.sign(fm) == np.sign(fa)
        a = np.where(same, m, a)
        fa = np.where(same, fm, fa)
        b = np.where(same, b, m)
    return 0.5 * (a + b)
