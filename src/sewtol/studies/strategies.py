"""Yield by adjustment strategy, of any mechanism (the protocol): the same machines adjusted
under each named strategy.

Every strategy sees the SAME machines (common random numbers: `law.draw(n, seed)`, the one
sampler, so the machines of `montecarlo` for that seed), so differences between rows are the
strategies', not sampling noise. A strategy is a set of compensators: names of the
mechanism's compensators, a map parameter -> box, or compensator objects (the needle's
Strategy); each machine is adjusted through `sewtol.studies.adjusting.adjusted` (the
mechanism's plug-in where it takes the set, else the generic optimiser), an empty set leaves
the machine as built. Per row: counts ok + out_of_spec + cannot_close + dead_point = n
(against the output's spec), the yield with its Clopper-Pearson interval, p50/p95/p99 of the
adjusted output (a machine that cannot run ranks as infinitely bad), and each compensator's
settings spread over the machines that run with the share at an end of its box.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from sewtol.errors import ParameterError
from sewtol.protocol import input_law, machines, plugins
from sewtol.studies.adjusting import Adjusted, adjusted
from sewtol.studies.montecarlo import WORDS, check_seed, quantiles
from sewtol.studies.parallel import chunk_bounds, run_chunks

# machines per chunk with n_jobs != 1 or a progress bar: the machines are adjusted one by one,
# but a batch optimum need not be bit-identical across batch sizes (the needle's joint optimum
# differs by ~1e-11 um on 2 of 2000 machines between chunks of 250 and 500), so the chunking
# is part of the study's identity: 250, as the needle's strategies report has always used
CHUNK = 250
STATUSES = ("ok", "out_of_spec", "cannot_close", "dead_point")


def default_strategies(mech) -> dict[str, tuple[str, ...]]:
    """none, each compensator of the mechanism alone, and all of them (where there are two or
    more)."""
    names = tuple(mech.compensators)
    rows = {"none": (), **{name: (name,) for name in names}}
    if len(names) > 1:
        rows["all"] = names
    return rows


def parse_strategies(items, mech) -> dict[str, tuple[str, ...]]:
    """`--strategy NAME=C1,C2` items (C: compensators of the mechanism; NAME= alone: none)."""
    out = {}
    for item in items:
        name, eq, comps = item.partition("=")
        names = tuple(c.strip() for c in comps.split(",") if c.strip())
        if not eq or not name.strip() or name.strip() in out:
            raise ParameterError("--strategy", "must be NAME=C1,C2,... with a new NAME", item)
        for c in names:
            if c not in mech.compensators:
                raise ParameterError("--strategy", "must name compensators of the mechanism ("
                                     + (", ".join(mech.compensators) or "it has none") + ")", c)
        out[name.strip()] = names
    return out


def _names(compensators) -> list[str]:
    comps = getattr(compensators, "compensators", compensators)
    if isinstance(comps, Mapping):
        return list(comps)
    return [getattr(c, "name", c) for c in comps]


def _adjust(mech, values, compensators, output, fast, options) -> Adjusted:
    if _names(compensators) or (fast and plugins(mech).adjusts_strategy(())):
        return adjusted(mech, values, compensators, output, fast=fast, **options)
    ev = mech.evaluate(values, [output])  # nothing to set: the machine as built
    return Adjusted(ev.outputs[output], {}, ev.status, {}, {"failed_group": ev.failed_group})


def _chunk(mech, values, strategies, output, fast, options, threads):
    import numba

    before = numba.get_num_threads()
    if threads is not None:  # one numba thread per worker process (2 x 2 threads ran slower)
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        return [_adjust(mech, values, s, output, fast, options) for s in strategies]
    finally:
        numba.set_num_threads(before)


def _cat(values: list):
    """Consecutive chunks' figures as one: arrays joined, dicts of them key by key."""
    if isinstance(values[0], Mapping):
        return {k: _cat([v[k] for v in values]) for k in values[0]}
    if np.ndim(values[0]) == 0:  # a figure of the whole batch (the same in every chunk)
        return values[0]
    return np.concatenate([np.asarray(v, object if isinstance(v[0], str) else None)
                           for v in values])


def _concat(parts: list[Adjusted]) -> Adjusted:
    return Adjusted(*(_cat([getattr(p, k) for p in parts]) for k in
                      ("value", "settings", "status", "at_bound", "extras")), parts[0].path)


@dataclass(frozen=True)
class StrategiesResult:
    """The machines (deviations), each strategy's adjusted batch and the spec they meet."""

    mechanism: str
    output: str
    unit: str
    spec: object  # sewtol.mechanism.Spec or None (every machine that runs is ok)
    tolerances: str
    seed: int
    deviations: dict
    names: tuple[str, ...]
    compensators: tuple[tuple[str, ...], ...]
    adjusted: tuple[Adjusted, ...]

    @property
    def n(self) -> int:
        return len(self.adjusted[0].value)

    def get(self, name: str) -> Adjusted:
        if name not in self.names:
            raise ParameterError("strategy", f"not in this table; rows are "
                                 f"{', '.join(self.names)}", name)
        return self.adjusted[self.names.index(name)]

    def status(self, name: str) -> np.ndarray:
        """Per machine: ok, out_of_spec, cannot_close or dead_point after the strategy."""
        a = self.get(name)
        s = np.array([WORDS.get(w, w) for w in a.status], dtype=object)
        if self.spec is not None:
            s[(s == "ok") & ~self.spec.passes(np.asarray(a.value, float))] = "out_of_spec"
        return s

    def counts(self, name: str) -> dict[str, int]:
        s = self.status(name)
        c = {k: int(np.sum(s == k)) for k in STATUSES}
        c["failed"] = c["cannot_close"] + c["dead_point"]
        c["n"] = int(s.size)
        return c

    def row(self, i: int) -> dict:
        name, a = self.names[i], self.adjusted[i]
        c = self.counts(name)
        ci = stats.binomtest(c["ok"], c["n"]).proportion_ci(0.95, method="exact")
        runs = np.isin(self.status(name), ("ok", "out_of_spec"))
        spread = []
        for k, v in a.settings.items():
            x = np.asarray(v, float)[runs]
            at = float(np.mean(np.asarray(a.at_bound.get(k, np.zeros(self.n)), bool)))
            spread.append(f"{k} {x.min():.6g}..{x.max():.6g} (at bound {at:.1%})" if x.size
                          else f"{k} -")
        return {"strategy": name, "compensators": ",".join(self.compensators[i]) or "-",
                **c, "yield": c["ok"] / c["n"], "yield_ci_low": float(ci.low),
                "yield_ci_high": float(ci.high), **quantiles(a.value),
                "settings": "; ".join(spread)}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per strategy (see the module docstring)."""
        return pd.DataFrame([self.row(i) for i in range(len(self.names))])

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "n": self.n, "seed": self.seed,
                "tolerances": self.tolerances, "output": self.output, "unit": self.unit,
                "spec": None if self.spec is None else self.spec.to_dict(),
                "yield_ci_method": "Clopper-Pearson exact binomial interval of ok / n, 95 %",
                "rows": self.to_dataframe().to_dict("records")}


def strategies(mech, tolerances, n: int, seed: int, strategies: Mapping | None = None,
               output: str | None = None, spec=None, *, fast: bool = True, n_jobs: int = 1,
               progress=False, **options) -> StrategiesResult:
    """The machines 0 .. n-1 of `seed` (`law.draw`) under each strategy (name -> compensators;
    None: `default_strategies`), `output` (default: that of the mechanism's first spec, else its
    first) adjusted and held to `spec` (default: the mechanism's spec of it; none: every machine
    that runs is ok). fast=False: the generic optimiser always; n_jobs, progress: chunks of
    CHUNK machines on worker processes; options go to the mechanism's strategy adjuster (e.g.
    the needle's limit_um)."""
    if isinstance(n, bool) or int(n) != n or n < 2:
        raise ParameterError("n", "must be a whole number >= 2", n)
    check_seed(seed)
    output, file_spec, _ = mech.resolve_spec(output)
    spec = file_spec if spec is None else spec
    strategies = default_strategies(mech) if strategies is None else dict(strategies)
    if not strategies:
        raise ParameterError("strategies", "must name at least one strategy", strategies)
    law = input_law(mech, tolerances)
    if law.dim == 0:
        raise ParameterError("tolerances", "has no tolerance with a non-zero width", law.name)
    dev = law.draw(int(n), seed)
    values = machines(mech, dev)
    rows = list(strategies.values())
    if n_jobs == 1 and not progress:
        adj = [_adjust(mech, values, s, output, fast, options) for s in rows]
    else:
        parts = run_chunks(_chunk, [(mech, {k: v[a:b] for k, v in values.items()}, rows, output,
                                     fast, options, 1 if n_jobs != 1 else None)
                                    for a, b in chunk_bounds(int(n), CHUNK)],
                           n_jobs=n_jobs, progress=progress, desc="strategies")
        adj = [_concat([p[i] for p in parts]) for i in range(len(rows))]
    return StrategiesResult(mech.name, output, mech.output(output).unit, spec, law.name,
                            int(seed), dev, tuple(strategies), tuple(tuple(_names(s))
                                                                     for s in rows), tuple(adj))
