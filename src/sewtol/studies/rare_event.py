"""Failures per million: plain Monte-Carlo, subset simulation (Au & Beck 2001, adaptive
conditional sampling) and NAIS importance sampling (Morio 2011) in the standard-normal space of
a tolerance set (`StandardNormalMap`, the Nataf transform with a copula); `estimate` chooses
among them from the target and the budget. `limit_state(mech, tolerances, output, ...)` is any
output of a protocol mechanism (as evaluated or adjusted) as a `LimitState`; a machine without
a value fails under a named mode ("cannot_close at G", "dead_point at G", or the mechanism's
words), never dropped. Limits default to the output's [[specs]] entry. Methods, assumptions and
validation: docs/rare_event.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import special, stats

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import refuse_conditioned
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.studies.adjusting import adjusted, evaluated, failures_of
from sewtol.studies.montecarlo import draw_units, stream_window, unit_streams
from sewtol.studies.scan import checked
from sewtol.tolerances import ToleranceSet

METHODS = ("auto", "montecarlo", "subset", "nais")
PASS = "pass"
EXCEEDS = "value > limit"
Z95 = float(stats.norm.ppf(0.975))


# --------------------------------------------------------------------------- the problem


@dataclass(frozen=True)
class StandardNormalMap:
    """Independent standard normals z -> deviations of the tolerances that scatter.

    With a dependence (the set's Gaussian copula, sewtol.dependence) this is the Nataf
    transform: the tied columns become L z (L L^T = R, the copula's Cholesky factor) before
    each marginal's x = F^-1(Phi(.)), so plain Monte-Carlo draws law.draw's machines and
    subset simulation and NAIS search the same independent z space."""

    tolerances: ToleranceSet

    @property
    def params(self) -> list[str]:
        return self.tolerances.params

    @property
    def dim(self) -> int:
        return len(self.tolerances.items)

    def to_physical(self, z: np.ndarray) -> dict[str, np.ndarray]:
        z = np.atleast_2d(np.asarray(z, float))
        if z.shape[1] != self.dim:
            raise ParameterError("z", f"must have {self.dim} columns ({', '.join(self.params)})",
                                 z.shape)
        z = self._nataf(z, lambda f: f.T)
        out = {}
        for i, t in enumerate(self.tolerances.items):
            zi = z[:, i]
            if t.dist == "normal":  # exact, no round trip through Phi in the tails
                out[t.param] = t.mean + t.sigma * zi
            else:
                # Phi(z) for z < 0 and 1 - Phi(-z) for z > 0 keeps tail resolution on both sides
                u = special.ndtr(zi)
                out[t.param] = t.from_unit(np.clip(u, 0.0, 1.0))
        return out

    def to_standard(self, dev: dict[str, np.ndarray]) -> np.ndarray:
        """The inverse map (for tests and for starting points given as deviations)."""
        cols = []
        for t in self.tolerances.items:
            x = np.asarray(dev[t.param], float)
            if t.dist == "normal":
                cols.append((x - t.mean) / t.sigma)
            elif t.dist == "uniform":
                cols.append(special.ndtri((x - t.lower) / (t.upper - t.lower)))
            else:
                cut = ((t.lower - t.mean) / t.sigma, (t.upper - t.mean) / t.sigma)
                cols.append(special.ndtri(stats.truncnorm.cdf((x - t.mean) / t.sigma, *cut)))
        # a singular copula (one setup, share 1) has no inverse: the least-squares z
        return self._nataf(np.column_stack(cols), lambda f: np.linalg.pinv(f).T)

    def _nataf(self, z: np.ndarray, side) -> np.ndarray:
        """z with the copula's columns times side(L) (the identity without a dependence)."""
        dep = self.tolerances.dependence
        if dep is None:
            return z
        cols = [self.params.index(p) for p in dep.params]
        z = np.array(z, float)
        z[:, cols] = z[:, cols] @ side(dep.factor())
        return z


@dataclass(frozen=True)
class LimitState:
    """Failure when response(z) gives value > limit or a failure mode k >= 1 (a union).

    response(z) takes standard normals of shape (n, dim) and returns (value, mode): value (n,)
    floats (NaN allowed where mode != 0), mode (n,) ints, 0 where the value was computed and k
    for failure_modes[k - 1]. to_physical(z), when given, turns z into the named inputs shown for
    the failing samples (e.g. a StandardNormalMap's deviations in mm).
    """

    response: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    dim: int
    limit: float
    failure_modes: tuple[str, ...] = ()
    output: str = "value"
    to_physical: Callable[[np.ndarray], dict] | None = field(default=None, compare=False)

    def __post_init__(self):
        if int(self.dim) != self.dim or self.dim < 1:
            raise ParameterError("dim", "must be a whole number >= 1", self.dim)
        if not np.isfinite(self.limit):
            raise ParameterError("limit", "must be a finite number", self.limit)

    @property
    def mode_names(self) -> tuple[str, ...]:
        """Labels of mode codes as used in results: 0 pass, 1 value > limit, 2.. the others."""
        return (PASS, EXCEEDS) + tuple(self.failure_modes)

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(value, margin, label) per sample: margin = value - limit (+inf for a mode without a
        value, so it fails at every threshold), label an index into mode_names."""
        value, mode = self.response(z)
        value = np.asarray(value, float).reshape(-1)
        mode = np.asarray(mode).astype(int).reshape(-1)
        if value.shape[0] != z.shape[0] or mode.shape[0] != z.shape[0]:
            raise ParameterError("response", "must return one value and one mode per sample",
                                 (value.shape, mode.shape, z.shape))
        if np.any((mode < 0) | (mode > len(self.failure_modes))):
            raise ParameterError("response", f"mode must be 0..{len(self.failure_modes)}",
                                 sorted(set(mode.tolist())))
        if np.any((mode == 0) & ~np.isfinite(value)):
            raise ParameterError("response", "returned a non-finite value with mode 0 (name its "
                                 "failure mode)", int(np.sum((mode == 0) & ~np.isfinite(value))))
        margin = np.where(mode == 0, value - self.limit, np.inf)
        label = np.where(mode == 0, np.where(margin > 0, 1, 0), mode + 1)
        return np.where(mode == 0, value, np.inf), margin, label


# --------------------------------------------------------------------------- the result


def _lognormal_ci(p: float, cov: float) -> tuple[float, float]:
    """95 % interval of a positive estimator with c.o.v. cov, taken as log-normal."""
    if not (p > 0 and np.isfinite(cov)):
        return float("nan"), float("nan")
    s = np.sqrt(np.log1p(cov**2))
    return float(p * np.exp(-Z95 * s)), float(p * np.exp(Z95 * s))


def _fmt_ppm(p: float) -> str:
    ppm = p * 1e6
    if ppm >= 1000:
        return f"{ppm:,.0f} ppm"
    return f"{ppm:.3g} ppm"


@dataclass(frozen=True)
class RareEventResult:
    """A probability of failure with its uncertainty, model calls and failures per mode.

    `failures` counts the failing samples the estimate rests on (the last level of subset
    simulation, the final importance sample, all of plain Monte-Carlo); mode_shares are their
    (weighted) shares of the union. When no failure was found, probability is 0, upper_95 is the
    95 % upper bound and `statement` says "< X at 95 %".
    """

    method: str
    probability: float
    cov: float
    ci_low: float
    ci_high: float
    upper_95: float
    model_calls: int
    failures: int
    mode_counts: dict[str, int]
    mode_shares: dict[str, float]
    limit: float
    output: str
    examples: pd.DataFrame  # most probable failing samples of each mode
    levels: pd.DataFrame  # subset levels / NAIS steps / MC: one row
    curve_values: tuple = field(default=(), repr=False)  # per level: sample values
    curve_weights: tuple = field(default=(), repr=False)  # per level: P(reaching the level)
    curve_cov: tuple = field(default=(), repr=False)  # per level: c.o.v. bound of that weight
    curve_gamma: tuple = field(default=(), repr=False)  # per level: chain correlation factor
    curve_floor: tuple = field(default=(), repr=False)  # per level: threshold it is valid from
    notes: str = ""

    @property
    def resolved(self) -> bool:
        """True when failures were found (otherwise only an upper bound is known)."""
        return self.failures > 0

    @property
    def statement(self) -> str:
        """The result in one line: ppm with c.o.v. and interval, or "< X at 95 %"."""
        if not self.resolved:
            return (f"< {_fmt_ppm(self.upper_95)} at 95 % (no failure in {self.model_calls} "
                    f"model calls, {self.method})")
        return (f"{_fmt_ppm(self.probability)} (c.o.v. {self.cov:.2f}, 95 % interval "
                f"{_fmt_ppm(self.ci_low)} ... {_fmt_ppm(self.ci_high)}; {self.failures} failures "
                f"found, {self.model_calls} model calls, {self.method})")

    def to_dict(self) -> dict:
        """The result as plain data (what ``sewtol needle ppm --format json`` extends)."""
        return {"method": self.method, "probability": self.probability,
                "ppm": self.probability * 1e6, "cov": self.cov,
                "ci95": [self.ci_low, self.ci_high], "upper_95": self.upper_95,
                "resolved": self.resolved, "statement": self.statement,
                "model_calls": self.model_calls, "failures": self.failures,
                "mode_counts": dict(self.mode_counts), "mode_shares": dict(self.mode_shares),
                "limit": self.limit, "output": self.output, "notes": self.notes}

    def to_dataframe(self) -> pd.DataFrame:
        """The result as one row."""
        row = {"method": self.method, "probability": self.probability,
               "ppm": self.probability * 1e6 if self.resolved else np.nan, "cov": self.cov,
               "ci_low_ppm": self.ci_low * 1e6, "ci_high_ppm": self.ci_high * 1e6,
               "upper_95_ppm": self.upper_95 * 1e6, "model_calls": self.model_calls,
               "failures": self.failures, "statement": self.statement}
        for k, v in self.mode_shares.items():
            row[f"share {k}"] = v
        return pd.DataFrame([row])

    def exceedance(self, x) -> pd.DataFrame:
        """P(value > x) with a 95 % band from the samples of every level (subset simulation and
        Monte-Carlo). Between levels the estimate of the highest level whose threshold is below x
        is used, P_j * (fraction of level j above x); its c.o.v. is taken as that of P_j (the sum
        over the levels below) plus the binomial c.o.v. of the fraction inflated by the chain
        correlation factor of level j: the fully correlated bound, as for the probability."""
        if not self.curve_values:
            raise ParameterError("exceedance", "needs a Monte-Carlo or subset-simulation result",
                                 self.method)
        x = np.atleast_1d(np.asarray(x, float))
        rows = []
        for xi in x:
            # the highest level whose samples are conditioned on a threshold at or below x
            j = max(i for i, f in enumerate(self.curve_floor) if f <= xi)
            vals, w = self.curve_values[j], self.curve_weights[j]
            c, g = self.curve_cov[j], self.curve_gamma[j]
            n = vals.size
            k = int(np.sum(vals > xi))
            if k == 0:
                rows.append({"x": xi, "probability": 0.0, "cov": np.nan, "low": 0.0,
                             "high": w * (1 - 0.05 ** (1 / n)), "samples_above": 0, "level": j})
                continue
            f = k / n
            cov = c + np.sqrt((1 - f) / (n * f) * (1 + g))
            p = w * f
            lo, hi = _lognormal_ci(p, cov)
            rows.append({"x": xi, "probability": p, "cov": float(cov), "low": lo,
                         "high": min(hi, 1.0), "samples_above": k, "level": j})
        return pd.DataFrame(rows)

    def plot(self, x, ax=None, label: str | None = None, color=None):
        """The exceedance curve P(value > x) on a log axis with its 95 % band."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        e = self.exceedance(x)
        ok = e["probability"] > 0
        line, = ax.semilogy(e["x"][ok], e["probability"][ok], color=color,
                            label=label or self.method)
        ax.fill_between(e["x"][ok], e["low"][ok], e["high"][ok], color=line.get_color(),
                        alpha=0.25, lw=0)
        return ax


def _shares(labels, weights, names) -> tuple[dict, dict]:
    fail = labels > 0
    counts = {names[k]: int(np.sum(labels == k)) for k in range(1, len(names))}
    tot = float(np.sum(weights[fail]))
    shares = {names[k]: (float(np.sum(weights[labels == k])) / tot if tot > 0 else 0.0)
              for k in range(1, len(names))}
    return counts, shares


def _examples(ls: LimitState, z, value, labels, per_mode: int) -> pd.DataFrame:
    """The most probable failing samples (smallest |z|) of each mode."""
    rows = []
    names = ls.mode_names
    r2 = np.sum(z**2, axis=1)
    for k in range(1, len(names)):
        idx = np.flatnonzero(labels == k)
        if idx.size == 0:
            continue
        # unique samples only: a Markov chain repeats a state whose move was rejected
        _, first = np.unique(z[idx], axis=0, return_index=True)
        idx = idx[first]
        idx = idx[np.argsort(r2[idx], kind="stable")[:per_mode]]
        phys = ls.to_physical(z[idx]) if ls.to_physical is not None else \
            {f"z{i}": z[idx, i] for i in range(z.shape[1])}
        for j, i in enumerate(idx):
            row = {"mode": names[k], "rank": j + 1, "z_norm": float(np.sqrt(r2[i]))}
            row.update({p: float(v[j]) for p, v in phys.items()})
            row[ls.output] = float(value[i]) if np.isfinite(value[i]) else np.nan
            rows.append(row)
    return pd.DataFrame(rows)


def _binomial(k: int, n: int) -> tuple[float, float, float, float, float]:
    """k failures in n plain Monte-Carlo samples: p = k/n, c.o.v. sqrt((1-p)/(n p)), the
    Clopper-Pearson 95 % interval and the 95 % upper bound (one-sided when k = 0)."""
    low, high = clopper_pearson(k, n)
    upper = high if k > 0 else clopper_pearson(k, n, 0.90)[1]
    p = k / n
    return (p, float(np.sqrt((1 - p) / (n * p))) if k > 0 else float("nan"), low, high, upper)


def _check_common(rng, n, name="n", minimum=2):
    if not isinstance(rng, np.random.Generator):
        raise ParameterError("rng", "must be a numpy Generator (np.random.default_rng(seed))",
                             type(rng).__name__)
    if int(n) != n or n < minimum:
        raise ParameterError(name, f"must be a whole number >= {minimum}", n)


# --------------------------------------------------------------------------- plain Monte-Carlo


def _mc_chunk(ls: LimitState, window, keep: int):
    streams, a, b = window
    z = special.ndtri(draw_units(streams, ls.dim, a, b))
    value, _, labels = ls.evaluate(z)
    fail = np.flatnonzero(labels > 0)
    # keep the failing samples only (and at most `keep` of each mode nearest the origin)
    r2 = np.sum(z[fail] ** 2, axis=1)
    kept = []
    for k in np.unique(labels[fail]):
        sel = fail[labels[fail] == k]
        kept.append(sel[np.argsort(r2[labels[fail] == k], kind="stable")[:keep]])
    kept = np.concatenate(kept) if kept else np.zeros(0, int)
    return value, labels.astype(np.int8), z[kept], value[kept], labels[kept]


def monte_carlo(ls: LimitState, n: int, rng: np.random.Generator, chunk_size: int = 20000,
                n_jobs: int = 1, examples_per_mode: int = 3, backend: str | None = None,
                progress: bool = False) -> RareEventResult:
    """Plain Monte-Carlo: p = k/n, Clopper-Pearson 95 % interval, c.o.v. sqrt((1-p)/(n p)).

    The samples are the machines of every study (studies.montecarlo.draw_units: machine k from
    child k // CHUNK of the rng's seed sequence, z = Phi^-1(u)), so any n_jobs or chunk_size
    gives the same numbers, and default_rng(seed) the machines of a Monte-Carlo with that seed."""
    from sewtol.studies.parallel import chunk_bounds, run_chunks

    _check_common(rng, n)
    streams = unit_streams(rng, n)
    parts = run_chunks(_mc_chunk, [(ls, stream_window(streams, a, b), examples_per_mode)
                                   for a, b in chunk_bounds(int(n), int(chunk_size))],
                       n_jobs=n_jobs, backend=backend, progress=progress, desc="Monte-Carlo")
    value, labels, ez, ev, el = (np.concatenate(c) for c in zip(*parts, strict=True))
    labels = labels.astype(int)
    n = value.size
    k = int(np.sum(labels > 0))
    p, cov, lo, hi, upper = _binomial(k, n)
    counts, shares = _shares(labels, np.ones(n), ls.mode_names)
    levels = pd.DataFrame([{"level": 0, "threshold": ls.limit, "samples": n,
                            "conditional_probability": p, "gamma": 0.0, "cov": cov}])
    return RareEventResult("montecarlo", p, cov, lo, hi, upper, n, k,
                           counts, shares, ls.limit, ls.output,
                           _examples(ls, ez, ev, el, examples_per_mode), levels,
                           (value,), (1.0,), (0.0,), (0.0,), (-np.inf,),
                           "Clopper-Pearson interval; upper_95 is the one-sided 95 % bound")


# --------------------------------------------------------------------------- subset simulation


def _chain_gamma(ind: np.ndarray, lengths: np.ndarray) -> float:
    """Au & Beck (2001) correlation factor of an indicator sampled along Markov chains.

    ind has shape (chains, max_length) with the chains left-aligned; lengths the used length of
    each chain."""
    n = int(lengths.sum())
    p = float(ind.sum() / n)
    r0 = p * (1 - p)
    if r0 <= 0:
        return 0.0
    gamma = 0.0
    for lag in range(1, int(lengths.max())):
        ok = lengths > lag
        if not ok.any():
            break
        a = ind[ok, :-lag]
        b = ind[ok, lag:]
        valid = (np.arange(a.shape[1])[None, :] + lag) < lengths[ok, None]
        pairs = int(valid.sum())
        r = float(np.sum(a * b * valid)) / pairs - p * p
        gamma += 2 * (1 - lag * ok.sum() / n) * r / r0
    return max(gamma, 0.0)


def _acs_level(ls: LimitState, seeds_z, seeds_out, b, n, rng, lam, target_accept=0.44):
    """Adaptive conditional sampling (Papaioannou et al. 2015) from the seeds, n samples in all.

    All chains move together; the scale lambda is adapted after each step from that step's
    acceptance rate. Returns the samples chain-major, the chain lengths and the new lambda."""
    ns, d = seeds_z.shape
    lengths = np.full(ns, n // ns)
    lengths[: n % ns] += 1
    L = int(lengths.max())
    sig_hat = np.std(seeds_z, axis=0, ddof=1) if ns > 1 else np.ones(d)
    sig_hat = np.where(np.isfinite(sig_hat) & (sig_hat > 0), sig_hat, 1.0)
    Z = np.empty((ns, L, d))
    V = np.empty((ns, L))
    M = np.empty((ns, L))
    G = np.empty((ns, L), dtype=int)
    u = seeds_z.copy()
    cur = [a.copy() for a in seeds_out]  # value, margin, label
    Z[:, 0], V[:, 0], M[:, 0], G[:, 0] = u, cur[0], cur[1], cur[2]
    calls = 0
    for t in range(1, L):
        act = np.flatnonzero(lengths > t)
        sigma = np.minimum(lam * sig_hat, 1.0)
        rho = np.sqrt(1.0 - sigma**2)
        cand = rho * u[act] + sigma * rng.standard_normal((act.size, d))
        cv, cm, cl = ls.evaluate(cand)
        calls += act.size
        acc = cm > b
        sel = act[acc]
        u[sel] = cand[acc]
        cur[0][sel], cur[1][sel], cur[2][sel] = cv[acc], cm[acc], cl[acc]
        Z[:, t], V[:, t], M[:, t], G[:, t] = u, cur[0], cur[1], cur[2]
        lam = float(np.exp(np.log(lam) + (acc.mean() - target_accept) / np.sqrt(t)))
    mask = np.arange(L)[None, :] < lengths[:, None]
    return Z, V, M, G, mask, lengths, lam, calls


def subset_simulation(ls: LimitState, n_per_level: int, rng: np.random.Generator,
                      p0: float = 0.1, max_levels: int = 25, down_to: float | None = None,
                      p_floor: float = 1e-12, examples_per_mode: int = 3) -> RareEventResult:
    """Subset simulation (Au & Beck 2001) with adaptive conditional sampling: levels at the
    (1 - p0) quantiles of the margin until one reaches the limit, or (down_to) until the
    probability reached falls below down_to, for an exceedance curve; a limit the inputs cannot
    reach stops below p_floor with the 95 % bound "< X". The c.o.v. is the fully correlated
    bound sum_j delta_j (the levels' independent figure is in the notes): docs/rare_event.md."""
    _check_common(rng, n_per_level, "n_per_level", 10)
    if not (0 < p0 <= 0.5):
        raise ParameterError("p0", "must be in (0, 0.5]", p0)
    if down_to is not None and not (0 < down_to < 1):
        raise ParameterError("down_to", "must be a probability in (0, 1)", down_to)
    n = int(n_per_level)
    ns_target = max(int(round(n * p0)), 1)
    z = rng.standard_normal((n, ls.dim))
    value, margin, labels = ls.evaluate(z)
    calls = n
    lengths = np.ones(n, dtype=int)
    chain_mask = None
    weight, sum_delta, sum_d2 = 1.0, 0.0, 0.0
    lam = 0.6
    rows, cv, cw, cc, cg, cf = [], [], [], [], [], []
    floor = -np.inf
    for level in range(max_levels + 1):
        m_sorted = np.sort(margin)[::-1]
        b = 0.5 * (m_sorted[ns_target - 1] + m_sorted[ns_target])
        if not np.isfinite(b):  # more than p0 of the samples fail a mode without a value
            b = 0.0
        stop = (b >= 0 or weight * p0 < p_floor) if down_to is None else weight * p0 < down_to
        final = bool(stop or level == max_levels)
        if final and down_to is None:
            b = 0.0
        ind = margin > b
        p_j = float(ind.mean())
        gamma = 0.0
        if chain_mask is not None:
            full = np.zeros(chain_mask.shape)
            full[chain_mask] = ind
            gamma = _chain_gamma(full, lengths)
        d2 = (1 - p_j) / (n * p_j) * (1 + gamma) if p_j > 0 else np.inf
        for curve, v in zip((cv, cw, cc, cg, cf), (value, weight, sum_delta, gamma, floor),
                            strict=True):
            curve.append(v)
        rows.append({"level": level, "threshold": b + ls.limit, "samples": n,
                     "conditional_probability": p_j, "gamma": gamma,
                     "cov": float(np.sqrt(d2)) if np.isfinite(d2) else np.nan})
        if final or p_j == 0:
            break
        weight *= p_j
        sum_delta += np.sqrt(d2)
        sum_d2 += d2
        floor = b + ls.limit
        seeds = np.flatnonzero(ind)
        Z, V, M, G, chain_mask, lengths, lam, c = _acs_level(
            ls, z[seeds], (value[seeds], margin[seeds], labels[seeds]), b, n, rng, lam)
        calls += c
        z, value, margin, labels = Z[chain_mask], V[chain_mask], M[chain_mask], G[chain_mask]

    k = int(np.sum(labels > 0))
    last = rows[-1]["cov"]
    method = "subset"
    if len(rows) == 1 and down_to is None:
        # the limit lies within the first, plain Monte-Carlo level: report it as that
        method = "subset (level 0 = Monte-Carlo)"
        p, cov, lo, hi, upper = _binomial(k, n)
        cov_ind = cov
    elif k > 0:
        frac = float(np.mean(labels > 0)) if down_to is None else float(np.mean(margin > 0))
        p = weight * frac
        if down_to is not None:  # the last level's threshold is not the limit: its own term
            f = frac
            last = float(np.sqrt((1 - f) / (n * f) * (1 + rows[-1]["gamma"]))) if f < 1 else 0.0
            if rows[-1]["threshold"] > ls.limit:
                p = float("nan")  # the limit lies below this level: read it off exceedance()
        cov = float(sum_delta + last)
        cov_ind = float(np.sqrt(sum_d2 + last**2))
        lo, hi = _lognormal_ci(p, cov)
        upper = hi
    else:
        p, cov, cov_ind = 0.0, float("nan"), float("nan")
        lo, hi = 0.0, float("nan")
        # the level's own probability is uncertain too: its one-sided 95 % log-normal bound
        s = np.sqrt(np.log1p(sum_delta**2))
        upper = weight * float(np.exp(1.645 * s)) * (1 - 0.05 ** (1 / n))
    counts, shares = _shares(labels, np.ones(labels.size), ls.mode_names)
    note = (f"p0 = {p0}, {n} samples per level, {len(rows)} levels; c.o.v. = sum of the levels' "
            f"delta (fully correlated bound; levels taken independent: {cov_ind:.3g}); "
            "log-normal 95 % interval from the c.o.v.")
    if down_to is not None:
        note += f"; run down to P = {down_to:g} for the exceedance curve"
    elif k == 0:
        note += (f"; no failure: the levels stopped at P = {weight:.3g} with the largest "
                 f"{ls.output} found {np.max(value[np.isfinite(value)], initial=-np.inf):.6g}")
    return RareEventResult(method, p, cov, lo, hi, upper, calls, k, counts, shares, ls.limit,
                           ls.output, _examples(ls, z, value, labels, examples_per_mode),
                           pd.DataFrame(rows), tuple(cv), tuple(cw), tuple(cc), tuple(cg),
                           tuple(cf), note)


# --------------------------------------------------------------------------- NAIS


def _kde_logpdf(x, centres, weights, bw):
    """log of sum_i w_i N(x; c_i, diag(bw^2)), weights summing to 1 (chunked over x)."""
    out = np.empty(x.shape[0])
    lw = np.log(weights)
    norm = -0.5 * x.shape[1] * np.log(2 * np.pi) - np.sum(np.log(bw))
    for s in range(0, x.shape[0], 2000):
        d = (x[s:s + 2000, None, :] - centres[None, :, :]) / bw
        out[s:s + 2000] = special.logsumexp(lw - 0.5 * np.sum(d * d, axis=2), axis=1) + norm
    return out


def nais(ls: LimitState, n_per_step: int, rng: np.random.Generator, n_final: int | None = None,
         rho: float = 0.1, defensive: float = 0.1, max_steps: int = 25,
         examples_per_mode: int = 3) -> RareEventResult:
    """Non-parametric adaptive importance sampling (Morio 2011; Morio & Balesdent 2015).

    Each step raises the threshold to the (1 - rho) quantile of the margin (capped at the limit)
    and refits the sampling density as a Gaussian kernel mixture on the weighted samples beyond
    it (weights phi/q, Silverman bandwidth per dimension). A defensive share of the standard
    normal keeps every weight <= 1/defensive, so a lobe the mixture missed cannot blow up the
    variance. The probability comes from a fresh sample of n_final (default n_per_step) drawn
    from the last density: p = mean(1[fail] phi/q), c.o.v. from the sample variance."""
    _check_common(rng, n_per_step, "n_per_step", 10)
    if not (0 < defensive < 1):
        raise ParameterError("defensive", "must be in (0, 1)", defensive)
    n = int(n_per_step)
    n_final = int(n_final or n)
    d = ls.dim
    centres, cweights, bw = None, None, None

    def sample(m):
        if centres is None:
            return rng.standard_normal((m, d))
        from_kde = rng.random(m) >= defensive
        x = rng.standard_normal((m, d))
        pick = rng.choice(centres.shape[0], size=int(from_kde.sum()), p=cweights)
        x[from_kde] = centres[pick] + bw * x[from_kde]
        return x

    def log_ratio(x):
        lphi = -0.5 * np.sum(x * x, axis=1) - 0.5 * d * np.log(2 * np.pi)
        if centres is None:
            return np.zeros(x.shape[0])
        lq = np.logaddexp(np.log(defensive) + lphi,
                          np.log1p(-defensive) + _kde_logpdf(x, centres, cweights, bw))
        return lphi - lq

    calls = 0
    rows = []
    for step in range(max_steps):
        x = sample(n)
        value, margin, labels = ls.evaluate(x)
        calls += n
        # "higher": an actual sample, so modes without a value (margin +inf) never give NaN
        g = min(float(np.quantile(margin, 1 - rho, method="higher")), 0.0)
        w = np.exp(log_ratio(x)) * (margin >= g)
        rows.append({"level": step, "threshold": g + ls.limit, "samples": n,
                     "conditional_probability": float(np.mean(margin >= g)), "gamma": 0.0,
                     "cov": np.nan})
        keep = w > 0
        cweights = w[keep] / w[keep].sum()
        centres = x[keep]
        mean = np.sum(cweights[:, None] * centres, axis=0)
        sd = np.sqrt(np.sum(cweights[:, None] * (centres - mean) ** 2, axis=0))
        n_eff = 1.0 / np.sum(cweights**2)
        bw = np.maximum(sd, 1e-3) * (4.0 / ((d + 2) * n_eff)) ** (1.0 / (d + 4))
        if g >= 0:
            break
    x = sample(n_final)
    value, margin, labels = ls.evaluate(x)
    calls += n_final
    w = np.exp(log_ratio(x))
    fail = labels > 0
    terms = w * fail
    p = float(terms.mean())
    k = int(fail.sum())
    if k > 0:
        cov = float(terms.std(ddof=1) / np.sqrt(n_final) / p)
        lo, hi = _lognormal_ci(p, cov)
        upper = hi
    else:
        cov, lo, hi = float("nan"), 0.0, float("nan")
        upper = float("nan")  # no failure: an IS sample bounds nothing without a model of q
    rows.append({"level": len(rows), "threshold": ls.limit, "samples": n_final,
                 "conditional_probability": p, "gamma": 0.0, "cov": cov})
    counts, shares = _shares(labels, w, ls.mode_names)
    return RareEventResult("nais", p, cov, lo, hi, upper, calls, k, counts, shares, ls.limit,
                           ls.output, _examples(ls, x, value, labels, examples_per_mode),
                           pd.DataFrame(rows), notes=(
                               f"{len(rows) - 1} adaptation steps of {n}, final sample "
                               f"{n_final}, defensive share {defensive}; log-normal 95 % "
                               "interval from the c.o.v."))


# --------------------------------------------------------------------------- choice


def choose_method(target: float, budget: int) -> str:
    """Plain Monte-Carlo when the budget sees about 10 failures at the target probability (its
    c.o.v. is then about 0.3), subset simulation otherwise. Subset simulation, not importance
    sampling, is the default for rare events: it needs no model of the failure domain, so a
    max/min over a stroke or a union of modes with several disjoint lobes does not bias it."""
    if not (0 < target < 1):
        raise ParameterError("target", "must be a probability in (0, 1)", target)
    if int(budget) != budget or budget < 100:
        raise ParameterError("budget", "must be a whole number of model calls >= 100", budget)
    return "montecarlo" if budget * target >= 10 else "subset"


def estimate(ls: LimitState, rng: np.random.Generator, method: str = "auto",
             target: float = 1e-6, budget: int = 20000, n_jobs: int = 1,
             examples_per_mode: int = 3, progress: bool = False) -> RareEventResult:
    """P(failure) with the method chosen by choose_method(target, budget), or the one named.

    budget is the number of model calls (subset simulation and NAIS take about that many; plain
    Monte-Carlo exactly that many).

    Parameters
    ----------
    ls : LimitState
        What fails: e.g. `needle_limit_state` (SumDelta over the limit, or a machine that
        cannot run).
    rng : numpy.random.Generator
        The only source of randomness: ``numpy.random.default_rng(seed)``.
    method : str
        ``"auto"`` (plain Monte-Carlo when the budget sees about 10 failures at the target,
        subset simulation otherwise), ``"montecarlo"``, ``"subset"`` or ``"nais"``.
    target : float
        The smallest probability the study must resolve, in (0, 1); e.g. 1e-6 for 1 ppm.
    budget : int
        Model calls (>= 100).
    n_jobs : int
        Worker processes for plain Monte-Carlo.
    examples_per_mode : int
        Failing samples kept per failure mode, in physical units, for the report.
    progress : bool
        A bar on stderr (plain Monte-Carlo).

    Returns
    -------
    RareEventResult
        The probability, its coefficient of variation and 95 % interval, model calls, the
        method, failures found per mode and example failing machines; when nothing fails, a
        "< X at 95 %" bound instead of a zero.

    Raises
    ------
    ParameterError
        For an unknown method, a target outside (0, 1) or a budget below 100.
    """
    if method not in METHODS:
        raise ParameterError("method", f"must be one of {', '.join(METHODS)}", method)
    chosen = choose_method(target, budget)  # checks target and budget for every method
    chosen = chosen if method == "auto" else method
    if chosen == "montecarlo":
        return monte_carlo(ls, int(budget), rng, n_jobs=n_jobs,
                           examples_per_mode=examples_per_mode, progress=progress)
    levels = max(int(np.ceil(-np.log10(target))), 1)
    if chosen == "subset":
        # each level after the first costs (1 - p0) N new calls
        n = int(budget / (1 + 0.9 * levels)) // 10 * 10
        return subset_simulation(ls, max(n, 100), rng, p_floor=target / 100,
                                 examples_per_mode=examples_per_mode)
    n = int(budget / (levels + 2)) // 10 * 10
    return nais(ls, max(n, 100), rng, n_final=max(n, 100) * 2,
                examples_per_mode=examples_per_mode)


# --------------------------------------------------------------------------- any mechanism


FAILURE_STATUSES = ("cannot_close", "dead_point")


def check_limits(upper: float | None, lower: float | None) -> tuple[float | None, float | None]:
    """At least one finite limit; lower below upper when both are given (mechanism.spec.Spec's
    rules, named by the command line's flags)."""
    if upper is None and lower is None:
        raise ParameterError("limit", "give an upper limit (--limit) and/or a lower limit "
                             "(--lower-limit), or a [[specs]] entry of the output in the file",
                             None)
    try:
        spec = Spec("", upper, lower)
    except ParameterError as exc:
        raise ParameterError({"upper": "limit", "lower": "lower_limit"}[exc.field], exc.rule,
                             exc.value) from None
    return spec.upper, spec.lower


def limits_of(mech, output: str, upper: float | None, lower: float | None):
    """The limits of a study of `output`: those given, else the file's [[specs]] entry of it."""
    spec = mech.spec_of(output) if upper is None and lower is None else None
    if spec is not None:
        return spec.upper, spec.lower
    return check_limits(upper, lower)


def limits_text(output: str, upper: float | None, lower: float | None, unit: str = "") -> str:
    """The pass condition in words, e.g. "4.2 mm <= stroke_mm <= 4.4 mm"."""
    u = f" {unit}" if unit and unit != "1" else ""
    if lower is None:
        return f"{output} <= {upper:g}{u}"
    if upper is None:
        return f"{output} >= {lower:g}{u}"
    return f"{lower:g}{u} <= {output} <= {upper:g}{u}"


def checked_limits(mech, output: str, adjust, upper: float | None, lower: float | None):
    """A yield study's case checked: `output` and a compensator `adjust` given by name must be
    the mechanism's; returns the limits (`limits_of`)."""
    mech.output(output)
    if isinstance(adjust, str) and adjust not in mech.compensators:
        raise ParameterError("adjust", "must name a compensator of the file ("
                             + (", ".join(mech.compensators) or "it has none") + ")", adjust)
    return limits_of(mech, output, upper, lower)


def output_of(mech, values: dict, output: str, adjust=None, fast: bool = True,
              **options) -> np.ndarray:
    """`output` of machines `values`: as evaluated, or minimised over the compensators
    `adjust` (as `adjusting.adjusted` takes them); NaN where a machine gives no value."""
    if adjust is None:
        return evaluated(mech, values, output, fast=fast)
    return adjusted(mech, values, adjust, output, fast=fast, **options).value


def spec_counts(mech, values: dict, output: str, spec: Spec, adjust=None, fast: bool = True,
                failures: Callable | None = None, **options) -> tuple[int, int, int, int]:
    """(ok, out of the spec, cannot_close, dead_point) of machines `values` by `output_of`; a
    machine without a value counts under its status (`failures`, as `failures_of` picks it)."""
    y = output_of(mech, values, output, adjust, fast, **options)
    status = np.full(y.size, "ok", dtype=object)
    bad = ~np.isfinite(y)
    if bad.any():
        status[bad] = failures_of(mech, fast, failures)(
            mech, {p: v[bad] for p, v in values.items()}, output)[0]
    runs = status == "ok"
    inside = runs & spec.passes(y)
    return (int(inside.sum()), int((runs & ~inside).sum()),
            int(np.sum(status == "cannot_close")), int(np.sum(status == "dead_point")))


def group_modes(mech) -> tuple[str, ...]:
    """The failure modes "STATUS at GROUP": every status of FAILURE_STATUSES at every group that
    can fail (it carries a closure), in assembly order."""
    state = mech.state(q_rad=np.zeros(1))
    return tuple(f"{s} at {g.name}" for g in mech.groups if g.name in state.closures
                 for s in FAILURE_STATUSES)


@dataclass(frozen=True)
class _Response:
    """z (n, dim) -> (value, mode) of one output (picklable: joblib workers receive it)."""

    mech: object
    zmap: StandardNormalMap
    output: str
    upper: float | None
    lower: float | None
    adjust: object
    modes: tuple[str, ...]
    words: dict | None  # status -> mode (None: "STATUS at GROUP")
    failures: Callable
    fast: bool
    options: dict = field(default_factory=dict)

    def __call__(self, z):
        values = machines(self.mech, self.zmap.to_physical(z))
        y = output_of(self.mech, values, self.output, self.adjust, self.fast, **self.options)
        mode = np.zeros(y.size, dtype=int)
        bad = ~np.isfinite(y)
        if bad.any():
            status, group = self.failures(self.mech, {k: v[bad] for k, v in values.items()},
                                          self.output)
            code = {m: k for k, m in enumerate(self.modes, start=1)}
            mode[bad] = [code.get(f"{s} at {g}" if self.words is None else self.words.get(s), 0)
                         for s, g in zip(status, group, strict=True)]
        value = y if self.lower is None else Spec(self.output, self.upper, self.lower).excess(y)
        return np.where(mode == 0, value, np.nan), mode


def limit_state(mech, tolerances: ToleranceSet, output: str, upper: float | None = None,
                lower: float | None = None, adjust=None, *, name: str | None = None,
                modes: dict[str, str] | None = None, failures: Callable | None = None,
                fast: bool = True, **options) -> LimitState:
    """One output of a protocol mechanism as a LimitState (see the module docstring).

    With an upper limit only, the LimitState's value is the output itself (named `name`,
    default OUTPUT or OUTPUT_adjusted) and its limit the upper limit; with a lower limit, its
    value is the excess beyond the limits (output units, NAME_excess) and its limit 0.
    adjust: compensators as `adjusting.adjusted` takes them (a name, names, boxes or
    objects); options go to the mechanism's strategy adjuster. failures(mech, values, output)
    -> (status, group) of the machines without a value, as every study takes it (default
    the plug-in, else adjusting.evaluated_failures); the failure mode of a machine is "STATUS at GROUP"
    (`group_modes`), or, with `modes` (status -> the mechanism's word for it), modes[STATUS].
    fast=False: the generic reference path.
    """
    upper, lower = checked_limits(mech, output, adjust, upper, lower)
    tol = checked(mech, tolerances)
    # the relations condition the law (sewtol.relations): P(fail | relations) is a ratio of
    # two estimates that subset simulation and NAIS do not make; refused, not ignored
    refuse_conditioned(tol, "conditions the law on a relation, which the rare-event estimators "
                       "do not take; use the Monte-Carlo (its yield interval) for a set with "
                       "relations", "matches parts within lots, which the rare-event estimators "
                       "do not draw; use the Monte-Carlo for a set with selective assembly")
    zmap = StandardNormalMap(tol)
    name = name or (output if adjust is None else f"{output}_adjusted")
    limit, name = (upper, name) if lower is None else (0.0, f"{name}_excess")
    names = group_modes(mech) if modes is None else tuple(dict.fromkeys(modes.values()))
    return LimitState(_Response(mech, zmap, output, upper, lower, adjust, names, modes,
                                failures_of(mech, fast, failures), fast, dict(options)),
                      zmap.dim, float(limit), names, name, zmap.to_physical)
