"""Speed and scatter of the rare-event estimators on Phi(-5) (2 dimensions, linear limit state).

    python benchmarks/rare_event.py [--seeds 10] [--n 2000] [--json]

For each method: seconds per run, model calls, mean and scatter of p / p_true over the seeds,
the mean stated c.o.v. and how many stated 95 % intervals hold p_true. When OpenTURNS is
importable (it is not a dependency: docs/rare_event.md says why) its SubsetSampling and NAIS run
on the same event for comparison, with the model given as one vectorised Python function.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from scipy import special

from sewtol.studies import rare_event as R

DIM, BETA = 2, 5.0
P_TRUE = float(special.ndtr(-BETA))


def linear(z):
    return z.sum(axis=1) / math.sqrt(DIM), np.zeros(len(z), int)


def ours(method, n, seeds):
    ls = R.LimitState(linear, DIM, BETA)
    fn = R.subset_simulation if method == "subset" else R.nais
    rows = []
    for s in range(seeds):
        t0 = time.perf_counter()
        r = fn(ls, n, np.random.default_rng(s))
        rows.append((time.perf_counter() - t0, r.probability, r.cov, r.model_calls,
                     r.ci_low <= P_TRUE <= r.ci_high))
    return rows


def with_openturns(method, n, seeds):
    import openturns as ot

    ot.Log.Show(ot.Log.NONE)
    calls = [0]

    def g(x):
        x = np.asarray(x)
        calls[0] += x.shape[0]
        return (x.sum(axis=1) / math.sqrt(DIM)).reshape(-1, 1)

    f = ot.PythonFunction(DIM, 1, func_sample=g)
    event = ot.ThresholdEvent(ot.CompositeRandomVector(f, ot.RandomVector(ot.Normal(DIM))),
                              ot.Greater(), BETA)
    rows = []
    for s in range(seeds):
        ot.RandomGenerator.SetSeed(s)
        calls[0] = 0
        algo = ot.SubsetSampling(event) if method == "subset" else ot.NAIS(event, 0.1)
        algo.setMaximumOuterSampling(n)
        t0 = time.perf_counter()
        algo.run()
        r = algo.getResult()
        p, cov = r.getProbabilityEstimate(), r.getCoefficientOfVariation()
        lo, hi = p * (1 - 1.96 * cov), p * (1 + 1.96 * cov)
        rows.append((time.perf_counter() - t0, p, cov, calls[0], lo <= P_TRUE <= hi))
    return rows


def summary(name, rows):
    t, p, cov, calls, inside = (np.array(c, float) for c in zip(*rows, strict=True))
    ratio = p / P_TRUE
    return {"estimator": name, "seconds_per_run": float(np.median(t)),
            "model_calls": int(np.median(calls)), "mean_ratio": float(ratio.mean()),
            "scatter_ratio": float(ratio.std(ddof=1)), "stated_cov": float(cov.mean()),
            "intervals_holding_p_true": f"{int(inside.sum())}/{len(rows)}"}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--n", type=int, default=2000, help="samples per level / step")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out = [summary(f"sewtol {m}", ours(m, args.n, args.seeds)) for m in ("subset", "nais")]
    try:
        import openturns  # noqa: F401
    except ImportError:
        pass
    else:
        out += [summary(f"openturns {m}", with_openturns(m, args.n, args.seeds))
                for m in ("subset", "nais")]
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for row in out:
            print("  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                            for k, v in row.items()))


if __name__ == "__main__":
    main()
