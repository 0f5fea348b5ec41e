"""The generic path against a built-in's fused path, end to end through the command line.

    python benchmarks/generic_vs_fused.py [--n 2000] [--repeats 3] [--seed 0] [--json]

For every built-in whose file names a fast path (`fast_path = ...`, sewtol.protocol.plugins)
and every single compensator its exact adjuster takes (the needle: beta), it runs

    sewtol run NAME montecarlo --adjust COMP --n N --seed S --format json [--path generic]

as child processes and reads their CPU time (user + sys, from the children's rusage): one
warm-up run of each path first (numba's caches on disk, the generated generic kernel included,
are not timed), then --repeats runs of each, interleaved. It prints the median CPU seconds of
each path, their ratio (the target: generic <= 3 x fused) and the yields and counts of both
(they must agree to the printed precision), with the load average at start and end: the
machine is shared, so the ratio of two runs made side by side is the figure, not the seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

TARGET_RATIO = 3.0


def cases():
    """(built-in, compensator) pairs with both paths: a fast path whose exact adjuster takes the
    compensator alone."""
    from sewtol.mechanism import load
    from sewtol.mechanisms import mechanism_file, names
    from sewtol.protocol import plugins

    out = []
    for name in names():
        mech = load(mechanism_file(name))
        pl = plugins(mech)
        if pl.name is None or pl.adjuster is None:
            continue
        for comp, c in mech.compensators.items():
            if pl.adjusts({c.parameter: (c.low, c.high)}) and c.mode == "absolute":
                out.append((name, comp))
    return out


def run_once(name, comp, n, seed, generic):
    argv = [sys.executable, "-m", "sewtol", "run", name, "montecarlo", "--adjust", comp,
            "--n", str(n), "--seed", str(seed), "--format", "json"]
    if generic:
        argv += ["--path", "generic"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall, json.loads(done.stdout)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=2000, help="machines per run (2000)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per path (3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    load_start = os.getloadavg()
    rows = []
    for name, comp in cases():
        for generic in (False, True):  # warm-up: compilation and caches, not timed
            run_once(name, comp, args.n, args.seed, generic)
        cpu = {False: [], True: []}
        wall = {False: [], True: []}
        answers = {}
        for _ in range(args.repeats):
            for generic in (False, True):
                c, w, out = run_once(name, comp, args.n, args.seed, generic)
                cpu[generic].append(c)
                wall[generic].append(w)
                answers[generic] = out
        fused, gen = statistics.median(cpu[False]), statistics.median(cpu[True])
        a, b = answers[False], answers[True]
        rows.append({
            "mechanism": name, "adjust": comp, "n": args.n, "seed": args.seed,
            "fused_cpu_s": fused, "generic_cpu_s": gen, "ratio": gen / fused,
            "target_ratio": TARGET_RATIO, "meets_target": gen / fused <= TARGET_RATIO,
            "fused_cpu_runs_s": cpu[False], "generic_cpu_runs_s": cpu[True],
            "fused_wall_median_s": statistics.median(wall[False]),
            "generic_wall_median_s": statistics.median(wall[True]),
            "fused_yields": a["yields"], "generic_yields": b["yields"],
            "yields_equal": a["yields"] == b["yields"], "counts_equal": a["counts"] == b["counts"],
        })
    result = {"rows": rows, "load_average_start": load_start,
              "load_average_end": os.getloadavg(), "cpus": os.cpu_count()}
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"load average at start {load_start}, at end {result['load_average_end']}")
    for r in rows:
        print(f"{r['mechanism']} --adjust {r['adjust']}, {r['n']} machines: fused "
              f"{r['fused_cpu_s']:.2f} CPU-s, generic {r['generic_cpu_s']:.2f} CPU-s, ratio "
              f"{r['ratio']:.2f} (target <= {TARGET_RATIO:g}); yields fused {r['fused_yields']}"
              f" generic {r['generic_yields']} (equal: {r['yields_equal']}, counts equal: "
              f"{r['counts_equal']})")


if __name__ == "__main__":
    main()
