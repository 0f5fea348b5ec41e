"""Where `sewtol needle strategies` spends its CPU time: per strategy row and, inside each, per
kernel and search stage, in one process with one numba thread (so CPU-s add up).

    python benchmarks/strategies_profile.py [--n 2000] [--reference-src OTHER/src] [--json]

Runs `needle strategies --n N --format json` in-process (after one run at n 20, so nothing is
compiled in the timed run) with timers wrapped around: the rows (studies.strategies.
set_in_order), the window kernels (optimise_batch; outer_batch over the guide angle or over
CD; fixed_batch), the `all` row's first-stage CD search (cd_angle_batch, or before it the
golden section of needle_208.adjustment; its plateau), and the exact extremes
(metrics.deviation_figures, feasibility); each row's figures summed over its chunks. A stage's
figure includes the kernels it calls. With --reference-src the same script runs again in a
subprocess on that checkout's sources, the two interleaved run by run (--repeats, medians),
and the ratio this / reference is printed; the load average before and after is printed with
the figures (the machine is shared). `benchmarks/cli.py` times the whole command with workers.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def load() -> list[float]:
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


def profile(n: int) -> dict:
    """{row: {"cpu_s": ..., stage: cpu_s, ...}} of one in-process run (one numba thread)."""
    import numba

    import sewtol.mechanisms.needle_208.adjustment as A
    import sewtol.mechanisms.needle_208.metrics as NM
    import sewtol.studies.strategies as ST
    from sewtol.cli import main
    from sewtol.mechanisms.needle_208.kernels import window as KW

    numba.set_num_threads(1)
    acc: dict[str, float] = {}

    def timed(mod, name, key):
        f = getattr(mod, name, None)
        if f is None:  # a reference checkout from before it
            return

        def g(*a, **k):
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                label = key(a) if callable(key) else key
                acc[label] = acc.get(label, 0.0) + time.process_time() - t

        setattr(mod, name, g)

    timed(KW, "optimise_batch", "optimise_batch")
    timed(KW, "outer_batch", lambda a: "outer_batch guide_angle" if a[1] == 13
          else "outer_batch CD")
    timed(KW, "fixed_batch", "fixed_batch")
    timed(A, "golden_min", "stage 1 CD golden section")
    timed(KW, "cd_angle_batch", "stage 1 cd_angle_batch")
    timed(A, "_plateau", "stage 1 CD plateau")
    timed(NM, "deviation_figures", "deviation_figures")
    timed(NM, "feasibility", "feasibility")
    rows: dict[str, dict] = {}
    row = ST.set_in_order

    def per_row(mech, values, s, *a, **k):
        before, t = dict(acc), time.process_time()
        out = row(mech, values, s, *a, **k)
        got = rows.setdefault(s.name, {})  # summed over the chunks
        for k2, v in {"cpu_s": time.process_time() - t,
                      **{k2: v - before.get(k2, 0.0) for k2, v in acc.items()
                         if v - before.get(k2, 0.0) > 0}}.items():
            got[k2] = got.get(k2, 0.0) + v
        return out

    ST.set_in_order = per_row
    with contextlib.redirect_stdout(io.StringIO()):
        main(["needle", "strategies", "--n", "20", "--format", "json"])
        acc.clear()
        rows.clear()
        t = time.process_time()
        main(["needle", "strategies", "--n", str(n), "--format", "json"])
    return {"total_cpu_s": time.process_time() - t, "rows": rows}


def child(src: Path, n: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, __file__, "--n", str(n), "--json", "--child"],
                         env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--reference-src", type=Path, default=None)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(profile(args.n)))
        return 0
    sides = {"this": Path(__file__).resolve().parents[1] / "src"}
    if args.reference_src is not None:
        sides["reference"] = args.reference_src
    res: dict = {"n": args.n, "load_start": load()}
    runs: dict[str, list] = {k: [] for k in sides}
    for _ in range(args.repeats):
        for k, src in sides.items():
            runs[k].append(child(src, args.n))
    res["load_end"] = load()
    for k, got in runs.items():
        res[k] = {"total_cpu_s": statistics.median(g["total_cpu_s"] for g in got),
                  "rows": {r: {s: statistics.median(g["rows"][r].get(s, 0.0) for g in got)
                               for s in got[0]["rows"][r]} for r in got[0]["rows"]}}
    if "reference" in res:
        res["ratio_total_cpu"] = res["this"]["total_cpu_s"] / res["reference"]["total_cpu_s"]
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"n {args.n}, load {res['load_start']} -> {res['load_end']}")
    for k in sides:
        print(f"{k}: {res[k]['total_cpu_s']:.2f} CPU-s")
        for r, stages in res[k]["rows"].items():
            print(f"  {r:24s} " + ", ".join(f"{s} {v:.2f}" for s, v in stages.items()))
    if "ratio_total_cpu" in res:
        print(f"this / reference, CPU-s: {res['ratio_total_cpu']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
