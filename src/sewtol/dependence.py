"""Dependence between toleranced parameters: a Gaussian copula over a tolerance set's marginals.

Each parameter keeps its own distribution (its Tolerance: limits, dist, mean shift); the
dependence only ties their ranks. The machines' ranks u are Phi(L z) where z are independent
standard normals and L L^T = R, the correlation matrix of the copula (the normal scores'
correlation, not the deviations' own Pearson correlation; for uniform marginals the two differ
by at most 0.018). A tolerance set declares R in three ways, combined into one matrix (a pair
given twice is refused):

    correlation = [["AB", "BE", 0.9]]                         # pairs
    correlation = { params = ["AB", "BE"], matrix = [[1, 0.9], [0.9, 1]] }   # a full matrix
    setup = [{ params = ["AB", "BE"], share = 0.8 }]          # one setup (below)

A "one setup" group is parts (or features) made in one machine setting or fixture: each
member's normal score is a systematic error the group shares, carrying `share` of its variance,
plus an error of its own carrying 1 - share, so every pair of the group is correlated `share`.
share = 1 (the default) means the setup error is all there is: the members draw the same rank
(each at the same quantile of its own tolerance).

L is the Cholesky factor of R, computed here for positive semi-definite R: a singular R
(share = 1, rho = +/-1) has zero pivots that OpenTURNS' NormalCopula regularises (1e-7 off for
rho = 1) where this one is exact. For a positive definite R it equals OpenTURNS'
NormalCopula(R) inverse isoprobabilistic transformation to 1e-12 (tests/test_dependence.py).
Lower-triangular L keeps the first parameter's rank as drawn, so a correlated law draws the
same ranks as the independent one for every parameter not tied to an earlier one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sewtol.errors import ParameterError

KEYS = ("correlation", "setup")
# eigenvalues down to -PSD_TOL count as zero (rounding of a singular matrix typed in decimals)
PSD_TOL = 1e-10


@dataclass(frozen=True)
class Dependence:
    """A Gaussian copula over some of a set's parameters (the others stay independent).

    Validated at construction: a square, symmetric matrix with a unit diagonal, entries in
    [-1, 1], positive semi-definite.

    Parameters
    ----------
    params : tuple of str
        The parameters the matrix ties, in its order.
    matrix : tuple of tuple of float
        The copula's correlation matrix R (normal scores).
    where : str
        The field errors name (e.g. ``"base.correlation"``).
    """

    params: tuple[str, ...]
    matrix: tuple[tuple[float, ...], ...]
    where: str = field(default="correlation", compare=False)

    def __post_init__(self):
        r = np.asarray(self.matrix, float)
        d = len(self.params)
        if len(set(self.params)) != d:
            raise ParameterError(self.where, "names a parameter twice", list(self.params))
        if r.shape != (d, d):
            raise ParameterError(self.where, f"must be a {d} x {d} matrix, one row and column per "
                         f"parameter ({', '.join(self.params)})", np.asarray(self.matrix).tolist())
        if not np.all(np.isfinite(r)) or np.any(np.abs(r) > 1):
            raise ParameterError(self.where, "must hold correlations within [-1, 1]", r.tolist())
        if not np.allclose(np.diag(r), 1.0, rtol=0, atol=1e-12):
            raise ParameterError(self.where, "must have 1 on its diagonal", np.diag(r).tolist())
        if not np.allclose(r, r.T, rtol=0, atol=1e-12):
            raise ParameterError(self.where, "must be symmetric", r.tolist())
        low = float(np.linalg.eigvalsh(r)[0])
        if low < -PSD_TOL:
            raise ParameterError(self.where, f"must be positive semi-definite (no set of parameters "
                         f"{', '.join(self.params)} has these correlations); its smallest "
                         f"eigenvalue is {low:.4g}", r.tolist())

    @property
    def array(self) -> np.ndarray:
        return np.asarray(self.matrix, float)

    def restrict(self, params) -> Dependence | None:
        """The copula of those of `params` it ties (None when it ties no two of them)."""
        keep = [i for i, p in enumerate(self.params) if p in set(params)]
        off = self.array[np.ix_(keep, keep)] - np.eye(len(keep))
        keep = [i for i, row in zip(keep, off, strict=True) if row.any()]
        if not keep:
            return None
        sub = self.array[np.ix_(keep, keep)]
        return Dependence(tuple(self.params[i] for i in keep), tuple(map(tuple, sub.tolist())),
                          self.where)

    def factor(self) -> np.ndarray:
        """Lower-triangular L with L L^T = R, zero columns at R's zero pivots."""
        r = self.array
        d = len(r)
        low = np.zeros_like(r)
        for j in range(d):
            pivot = r[j, j] - low[j, :j] @ low[j, :j]
            if pivot > PSD_TOL:
                low[j, j] = np.sqrt(pivot)
                low[j + 1:, j] = (r[j + 1:, j] - low[j + 1:, :j] @ low[j, :j]) / low[j, j]
        return low

    def ranks(self, u: np.ndarray) -> np.ndarray:
        """The copula's ranks (n, k) of independent standard uniforms u (n, k), columns in
        `params` order: Phi(L Phi^-1(u))."""
        from scipy import special  # only a dependent law needs it: not on an independent start-up

        return special.ndtr(special.ndtri(np.asarray(u, float)) @ self.factor().T)


def _params_list(where, v, known):
    if not isinstance(v, list) or not all(isinstance(p, str) for p in v) or len(v) < 2:
        raise ParameterError(where, "must be a list of two or more parameter names", v)
    for p in v:
        if p not in known:
            raise ParameterError(where, f"names {p!r}, not a parameter of the set ({', '.join(known)})", p)
    return v


def _rho(where, v):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not -1 <= v <= 1:
        raise ParameterError(where, "must be a correlation within [-1, 1]", v)
    return float(v)


def parse(set_name: str, body: dict, known: list[str]) -> Dependence | None:
    """The dependence a tolerance set's table declares (keys `correlation`, `setup`; the
    module docstring), over the set's parameters `known`; None when it declares none."""
    entries: dict[frozenset, tuple[str, float]] = {}

    def put(a, b, rho, where):
        if a == b:
            raise ParameterError(where, "must pair two different parameters", [a, b])
        key = frozenset((a, b))
        if key in entries:
            raise ParameterError(where, f"gives the pair {a}, {b} a second time (first in "
                         f"{entries[key][0]})", rho)
        entries[key] = (where, rho)

    corr = body.get("correlation")
    where = f"{set_name}.correlation"
    if isinstance(corr, dict):
        if set(corr) != {"params", "matrix"}:
            raise ParameterError(where, "a full matrix is a table of params and matrix", sorted(corr))
        names = _params_list(f"{where}.params", corr["params"], known)
        m = corr["matrix"]
        if not isinstance(m, list) or len(m) != len(names) or \
                not all(isinstance(row, list) and len(row) == len(names) for row in m):
            raise ParameterError(f"{where}.matrix", f"must be {len(names)} rows of {len(names)} numbers", m)
        Dependence(tuple(names), tuple(tuple(_rho(f"{where}.matrix", x) for x in row)
                                       for row in m), where)
        for i, a in enumerate(names):
            for j in range(i + 1, len(names)):
                put(a, names[j], float(m[i][j]), where)
    elif corr is not None:
        if not isinstance(corr, list):
            raise ParameterError(where, 'must be a list of ["A", "B", rho] or a table of params and '
                         "matrix", corr)
        for k, pair in enumerate(corr):
            at = f"{where}[{k}]"
            if not isinstance(pair, list) or len(pair) != 3:
                raise ParameterError(at, 'must be ["A", "B", rho]', pair)
            a, b = _params_list(at, pair[:2], known)
            put(a, b, _rho(f"{where}[{a}, {b}]", pair[2]), at)
    groups = body.get("setup", [])
    if not isinstance(groups, list):
        raise ParameterError(f"{set_name}.setup", "must be a list of { params = [...], share = s }", groups)
    for k, g in enumerate(groups):
        at = f"{set_name}.setup[{k}]"
        if not isinstance(g, dict) or not set(g) <= {"params", "share"} or "params" not in g:
            raise ParameterError(at, "must be a table { params = [...], share = s }", g)
        share = g.get("share", 1.0)
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 < share <= 1:
            raise ParameterError(f"{at}.share", "must be the setup error's share of the variance, in "
                         "(0, 1]", share)
        names = _params_list(f"{at}.params", g["params"], known)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                put(a, b, float(share), at)
    if not entries:
        return None
    tied = [p for p in known if any(p in key for key in entries)]
    r = np.eye(len(tied))
    for key, (_, rho) in entries.items():
        i, j = sorted(tied.index(p) for p in key)
        r[i, j] = r[j, i] = rho
    return Dependence(tuple(tied), tuple(map(tuple, r.tolist())), f"{set_name}.correlation")
