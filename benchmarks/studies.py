"""Wall time and peak memory of the study workloads of issue 5, in one process.

    python benchmarks/studies.py --json

(c) one million needle positions in chunks (peak RSS measured right after it, so it covers the
    interpreter, the imports and the chunked run), (a) Monte-Carlo of 10,000 machines with beta
    re-optimised per machine (recommended tolerances), (b) Sobol with 2^12 base samples over the
    seven link lengths with per-sample beta. The numba kernels use all cores; times are medians
    over --repeats runs after one warm-up (compilation is cached, not timed).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import time

import numpy as np

from sewtol.kernels import needle_positions as K
from sewtol.mechanisms.needle_208 import Needle208
from sewtol.studies.montecarlo import montecarlo
from sewtol.studies.sobol import needle_sobol
from sewtol.tolerances import NEEDLE_208_SETS


def timed(fn, repeats):
    out, times = None, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def million_positions(p):
    phi = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    P = np.repeat(K.pack(p), 278, axis=0)  # 278 x 3600 = 1,000,800 positions
    worst = 0.0
    for _, E in K.positions_chunked(P, phi, chunk_machines=32):
        worst = max(worst, float(np.nanmax(np.abs(E))))
    return P.shape[0] * phi.size, worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--n-mc", type=int, default=10_000)
    ap.add_argument("--n-sobol", type=int, default=4096)
    args = ap.parse_args(argv)
    p = Needle208.nominal()
    ts = NEEDLE_208_SETS["recommended"]

    million_positions(p)  # warm-up: load the cached kernels
    pos_s, (count, _) = timed(lambda: million_positions(p), args.repeats)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    montecarlo(p, ts, 1000, seed=1)  # warm-up
    mc_s, mc = timed(lambda: montecarlo(p, ts, args.n_mc, seed=1), args.repeats)
    sob_s, sob = timed(lambda: needle_sobol(p, ts, args.n_sobol, seed=1), 1)

    result = {
        "montecarlo_s": mc_s, "sobol_s": sob_s, "peak_rss_mb": peak_mb,
        "positions": count, "positions_s": pos_s,
        "montecarlo_machines": args.n_mc, "montecarlo_yield_adjusted": mc.yield_of("adjusted"),
        "sobol_base_samples": args.n_sobol,
        "sobol_model_runs": args.n_sobol * (len(ts.active().items) + 2),
        "repeats": args.repeats,
    }
    print(json.dumps(result, indent=2) if args.json else result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
