"""Selective assembly against tightening: the yield when two parts are matched in k classes
(sewtol.selective; k = 1 is no matching), with its Clopper-Pearson interval, beside the largest
factor f <= 1 on both parts' limits at which the same machines without matching reach that
yield (common random numbers, bisected to FACTOR_STEPS halvings). See docs/mechanism_files.md,
"Selective assembly".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from sewtol.errors import ParameterError
from sewtol.intervals import clopper_pearson
from sewtol.law import STREAM, InputLaw, refuse_conditioned, unit_streams
from sewtol.mechanism.spec import Spec
from sewtol.protocol import machines
from sewtol.selective import BY, Selective
from sewtol.studies.adjusting import evaluated_failures
from sewtol.studies.rare_event import checked_limits, spec_counts
from sewtol.studies.scan import checked
from sewtol.tolerances import ToleranceSet

FACTOR_STEPS = 12


@dataclass(frozen=True)
class SelectiveResult:
    """Per k (`table`): counts of the n machines built (ok + out_of_spec + cannot_close +
    dead_point = n), the yield with its 95 % interval, the parts of each kind the matching left
    unmatched in the first lot of each stream (`lots` lots of `lot_parts` parts; their share),
    and the tightening factor on both parts (with the +/- limits it gives) that reaches the same
    yield unmatched."""

    mechanism: str
    output: str
    tolerances: str
    pair: tuple[str, str]
    by: str
    n: int
    seed: int
    adjust: str | None
    table: pd.DataFrame

    method = ("parts sorted into k classes and matched in lots of the one sampler; tightening "
              "by bisection on a common factor of both parts' limits, same machines unmatched")

    def to_dataframe(self) -> pd.DataFrame:
        return self.table.copy()

    def to_dict(self) -> dict:
        return {"mechanism": self.mechanism, "output": self.output,
                "tolerances": self.tolerances, "pair": list(self.pair), "by": self.by,
                "n": self.n, "seed": self.seed, "adjust": self.adjust, "method": self.method,
                "rows": self.table.to_dict("records")}


def selective_assembly(mech, tolerances: ToleranceSet, output: str, pair: tuple[str, str],
                       groups=(1, 2, 4, 8), by: str = "count", n: int = 2000, seed: int = 0,
                       upper: float | None = None, lower: float | None = None, adjust=None, *,
                       fast: bool = True, **options) -> SelectiveResult:
    """The module docstring's table for each k in `groups`."""
    upper, lower = checked_limits(mech, output, adjust, upper, lower)
    spec = Spec(output, upper, lower)
    if by not in BY:
        raise ParameterError("by", f"must be one of {', '.join(BY)}", by)
    if isinstance(n, bool) or int(n) != n or n < 10:
        raise ParameterError("n", "must be a whole number of machines >= 10", n)
    tol = checked(mech, tolerances)
    refuse_conditioned(tol, "this study compares matching with tightening the pair alone; run "
                       "it on the set without relations")
    pair = tuple(pair)
    for p in pair:
        if p not in tol.params:
            raise ParameterError("pair", f"must name toleranced parameters ({', '.join(tol.params)})",
                                 p)
    for k in groups:
        Selective(pair, k, by, "groups")  # refuses a bad k or pair in one line
    plain = replace(tol, selective=None)

    def score(ts):
        law = InputLaw.of(ts)
        dev = law.draw(int(n), int(seed))
        counts = spec_counts(mech, machines(mech, dev), output, spec, adjust, fast,
                             evaluated_failures, **options)
        return law, dict(zip(("ok", "out_of_spec", "cannot_close", "dead_point"), counts,
                             strict=True))

    def plain_yield(f):
        return score(plain.scaled({p: f for p in pair}))[1]["ok"] / n

    half = {t.param: 0.5 * (t.upper - t.lower) for t in tol.items}
    rows = []
    streams = unit_streams(int(seed), int(n))
    for k in groups:
        law, counts = score(replace(tol, selective=Selective(pair, int(k), by)))
        # the first lot of every stream the n machines draw from: parts the matching leaves
        lots = [law.ranks(np.random.default_rng(ss).random((STREAM, law.dim))) for ss in streams]
        unmatched = sum(STREAM - len(law.matched(lot)) for lot in lots)
        y = counts["ok"] / n
        ci_low, ci_high = clopper_pearson(counts["ok"], n)
        lo, hi = 0.0, 1.0
        if plain_yield(1.0) < y:
            for _ in range(FACTOR_STEPS):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if plain_yield(mid) >= y else (lo, mid)
        else:
            lo = 1.0
        rows.append({"groups": int(k), "by": by, "n": int(n), **counts, "yield": y,
                     "yield_ci_low": ci_low, "yield_ci_high": ci_high,
                     "lots": len(lots), "lot_parts": STREAM, "unmatched_each": unmatched,
                     "unmatched_share": unmatched / (len(lots) * STREAM),
                     "tightening_factor": lo,
                     **{f"{p}_pm_unmatched": lo * half[p] for p in pair}})
    return SelectiveResult(mech.name, output, tolerances.name, pair, by, int(n), int(seed),
                           adjust if isinstance(adjust, str) or adjust is None else "compensators",
                           pd.DataFrame(rows))
