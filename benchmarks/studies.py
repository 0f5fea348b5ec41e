"""Wall time and peak memory of the study workloads of issue 5, in one process.

    python benchmarks/studies.py --json

(c) one million needle positions in chunks (peak RSS measured right after it, so it covers the
    interpreter, the imports and the chunked run), (a) Monte-Carlo of 10,000 machines with beta
    re-optimised per machine (recommended tolerances), (b) Sobol with 2^12 base samples over the
    seven link lengths with per-sample beta. The numba kernels use all cores; times are medians
    over --repeats runs after one warm-up (compilation is cached, not timed).

Issue 11 targets (exact per-machine optimum, mechanisms/needle_208/adjust.py), each printed with its figure
and the ratio to the numpy reference measured in this same process:
(d) 10^6 machines, beta exact per machine, evaluate() end to end in chunks of 100,000 (<= 10 s);
(e) the same with beta + guide shift (<= 20 s); peak RSS right after (d) and (e) (< 2 GB);
(f) Sobol with per-sample beta at N = 2^14 over the 7 tolerances (<= 10 s).
The numpy reference (mechanisms/needle_208/adjust.py, engine="numpy") is timed on 1,000
machines and scaled to 10^6 (it is linear in machines). The machine is shared: the load
average at start and end is printed with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import time

import numpy as np

from sewtol.mechanisms import params as P
from sewtol.mechanisms.needle_208 import adjust as ad
from sewtol.mechanisms.needle_208 import metrics as nm
from sewtol.mechanisms.needle_208.kernels import positions as K
from sewtol.mechanisms.needle_208.metrics import total_um_kernel
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.studies.sobol import problem_of, sample
from sewtol.tables.needle_208 import montecarlo, needle_sobol
from sewtol.tolerances import NEEDLE_208_SETS

TARGETS = {"million_beta_s": 10.0, "million_beta_shift_s": 20.0, "sobol_2e14_s": 10.0,
           "peak_rss_mb": 2048.0}


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


def timed_cpu(fn, repeats):
    """Median wall time and median CPU time of the whole process (all threads): on a shared
    machine CPU seconds / cores estimates the wall time of a quiet one."""
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus), out


def evaluate(p, dev, compensators=None):
    """SumDelta of machines p + dev with beta fixed (the fused kernel) and adjusted (exact)."""
    m = len(next(iter(dev.values())))
    c, _ = nm.columns(P.with_deviations(p, dev))
    c = {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}
    total_um_kernel(c)
    return ad.optimise(c, compensators or {"beta": (10.0, 35.0)}, feas=nm.feasibility(c))


def million_adjusted(p, ts, n, compensators, chunk=100_000):
    """evaluate() over n machines in chunks (deviations drawn per chunk): fixed and adjusted."""
    rng = np.random.default_rng(11)
    worst = 0.0
    for a in range(0, n, chunk):
        dev = ts.sample(rng, min(chunk, n - a))
        out = evaluate(p, dev, compensators=compensators)
        worst = max(worst, float(np.nanmax(out.total_um)))
    return worst


def sample_columns(p, ts, m=20_000):
    """m machines of the set as parameter columns (n, 1)."""
    c, _ = nm.columns(P.with_deviations(p, ts.sample(np.random.default_rng(12), m)))
    return {k: np.broadcast_to(v, (m, 1)).copy() for k, v in c.items()}


def new_kernel_s_per_machine(c, active, engine="numba"):
    """CPU seconds per machine of the exact optimiser alone."""
    m = len(c["LF"])
    ad.optimise({k: v[:10] for k, v in c.items()}, active, engine=engine)
    t0 = time.process_time()
    ad.optimise(c, active, engine=engine)
    return (time.process_time() - t0) / m


def issue11(p, ts, n_million, repeats):
    ts = ts.active()
    cores = os.cpu_count() or 1
    out = {"load_average_start": os.getloadavg()[0], "cores": cores}
    c = sample_columns(p, ts)
    new_pm = new_kernel_s_per_machine(c, {"beta": (10.0, 35.0)})
    new_shift_pm = new_kernel_s_per_machine(c, {"beta": (10.0, 35.0),
                                                "guide_shift_um": (-100.0, 100.0)})
    numpy_pm = new_kernel_s_per_machine({k: v[:1000] for k, v in c.items()},
                                        {"beta": (10.0, 35.0)}, engine="numpy")
    million_adjusted(p, ts, 2000, {"beta": (10.0, 35.0)})  # warm-up (cached kernels)
    t_b, cpu_b, _ = timed_cpu(lambda: million_adjusted(p, ts, n_million, {"beta": (10.0, 35.0)}),
                              repeats)
    t_bs, cpu_bs, _ = timed_cpu(lambda: million_adjusted(p, ts, n_million, {
        "beta": (10.0, 35.0), "guide_shift_um": (-100.0, 100.0)}), repeats)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    # Sobol at N = 2^14
    n_sob = 2 ** 14
    t_sob, cpu_sob, _ = timed_cpu(lambda: needle_sobol(p, ts, n_sob, seed=1), 1)
    runs = len(sample(problem_of(ts), n_sob, 1))
    scale = n_million / 1e6
    out.update({
        "million_beta_s": cpu_b / scale / cores,
        "million_beta_wall_s (shared machine)": t_b / scale,
        "million_beta_numpy_reference_s": numpy_pm * 1e6 / cores,
        "optimiser_alone_million_beta_s": new_pm * 1e6 / cores,
        "optimiser_alone_million_beta_shift_s": new_shift_pm * 1e6 / cores,
        "million_beta_shift_s": cpu_bs / scale / cores,
        "million_beta_shift_wall_s (shared machine)": t_bs / scale,
        "peak_rss_mb": rss,
        "sobol_2e14_s": cpu_sob / cores,
        "sobol_2e14_wall_s (shared machine)": t_sob,
        "sobol_2e14_model_runs": runs,
        "machines_timed": n_million,
        "seconds": "CPU seconds of the process / cores (the wall time of a quiet machine); "
                   "the numpy path timed on 1,000 machines, scaled to 10^6",
        "load_average_end": os.getloadavg()[0],
    })
    out["ratios"] = {
        "numpy reference / exact, 10^6 beta": numpy_pm * 1e6 / (cpu_b / scale),
    }
    out["targets"] = {k: {"target": v, "measured": out[k],
                          "met": bool(out[k] <= v)} for k, v in TARGETS.items()}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--n-mc", type=int, default=10_000)
    ap.add_argument("--n-sobol", type=int, default=4096)
    ap.add_argument("--n-million", type=int, default=1_000_000,
                    help="machines for the issue-11 runs (figures are scaled to 10^6)")
    ap.add_argument("--only-issue11", action="store_true")
    args = ap.parse_args(argv)
    if args.only_issue11:
        res = issue11(Needle208.nominal(), NEEDLE_208_SETS["recommended"], args.n_million,
                      args.repeats)
        print(json.dumps(res, indent=2) if args.json else res)
        return 0
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
    result["issue11"] = issue11(p, ts, args.n_million, args.repeats)
    print(json.dumps(result, indent=2) if args.json else result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
