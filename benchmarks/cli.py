"""The command line end to end: start-up, peak RSS of the whole process tree against n, and the
wall time of 10^6 needle machines, each beside a reference run made in the same minute.

    python benchmarks/cli.py --json
    python benchmarks/cli.py --reference-src /path/to/other/checkout/src --json

Every figure is a median over --repeats runs of a fresh `python -m sewtol ...` process (after
one warm-up run, so numba's cache is on disk and nothing is compiled in a timed run). Wall time,
CPU time (user + sys of the process and its workers, from wait4) and the peak resident memory
of the whole process tree (psutil: the sum over the process and all its descendants, sampled
every 20 ms; /usr/bin/time's %M is the largest single process only) are measured per run, and
the peak of the tree's summed PSS (/proc/PID/smaps_rollup: shared library pages divided among
the processes that map them, so three processes with numba loaded are not counted as three
copies of libLLVM; other processes mapping the same files take their share too, so it reads
lower on a busy machine).

(a) start-up: `needle montecarlo --n 1000` (target <= 1 s wall warm), medians of
    --startup-repeats (default 7) with the load average before and after, against `python -c
    pass`, `python -c "import numpy, numba"`, building the parser (`from sewtol.cli import
    build_parser`) and the same run on numba's kernels (the kernels compiled ahead of time
    hidden: what it costs without `make kernels`; `ahead_of_time_built` says whether the first
    run had them); on a loaded machine the CPU-s (user + sys) of the run is the projection of
    its wall time on an idle one;
(b) peak RSS against n: `needle montecarlo --n N --n-jobs 2` for N in --rss-n (target: flat,
    <= 500 MB at any n);
(c) `needle montecarlo --n 1000000 --n-jobs 2` end to end (target <= 10 s wall idle, or <= 20
    CPU-s with peak RSS <= 500 MB), with the load average before and after;
(d) `needle strategies --n N --n-jobs 2` for N in --strategies-n (default 2000 and 10000; target
    <= 30 s wall idle at 10000; peak RSS and PSS flat in n, <= 500 MB): every default row, the
    all row's nested CD / guide-angle search the bulk of it; its workers run the needle's
    kernels compiled ahead of time where built (numba never loaded in them). Warmed by one run
    at n 20; --strategies-repeats timed runs (default 1).
Every run reports the peak of the tree's summed RSS and PSS and the largest single process's
peak RSS.
With --reference-src every sewtol command runs again, interleaved run by run, with that
checkout's sources first on PYTHONPATH, and the ratio this/reference is printed. The machine
is shared: the load average at start and end is printed with the figures.

Warm means Python's bytecode cache too: when the environment sets PYTHONDONTWRITEBYTECODE (every
run would compile sewtol's sources again), the runs write their bytecode under a temporary
PYTHONPYCACHEPREFIX instead, so neither checkout is written and both start warm.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# where the runs keep their bytecode when the environment forbids writing it beside the sources
PYCACHE = str(Path(tempfile.gettempdir()) / "sewtol-bench-pycache")
TARGETS = {"startup_n1000_wall_s": 1.0, "million_wall_s": 10.0, "million_cpu_s": 20.0,
           "peak_rss_mb": 500.0, "strategies_n10000_wall_s": 30.0}


def load() -> list[float]:
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


def tree_rss(proc) -> tuple[int, int, int]:
    """Resident and proportional (PSS) bytes of proc and all its descendants now (0 for those
    already gone), and the largest single process's resident bytes. The RSS sum counts each
    shared library once per process (numpy's and scipy's .so, and libLLVM where numba is
    loaded); PSS shares those pages out, so its sum is what the tree holds."""
    import psutil

    rss = pss = largest = 0
    try:
        procs = [proc, *proc.children(recursive=True)]
    except psutil.Error:
        return 0, 0, 0
    for p in procs:
        try:
            own = p.memory_info().rss
            rss, largest = rss + own, max(largest, own)
            with open(f"/proc/{p.pid}/smaps_rollup") as fh:
                pss += next(int(line.split()[1]) * 1024 for line in fh
                            if line.startswith("Pss:"))
        except (psutil.Error, OSError, StopIteration):
            pass
    return rss, pss, largest


def run(cmd: list[str], src: Path | None) -> dict:
    """One run of cmd: wall s, CPU s of it and its children, peak tree RSS and PSS and the
    largest process's peak RSS (MB)."""
    import psutil

    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    env.pop("SEWTOL_SCHEDULER", None)
    if env.pop("PYTHONDONTWRITEBYTECODE", None):
        env.setdefault("PYTHONPYCACHEPREFIX", PYCACHE)
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    ps = psutil.Process(p.pid)
    peak = peak_pss = peak_process = 0
    while True:
        try:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
        except ChildProcessError:
            break
        if pid:
            break
        rss, pss, largest = tree_rss(ps)
        peak, peak_pss, peak_process = max(peak, rss), max(peak_pss, pss), max(peak_process, largest)
        time.sleep(0.02)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    err = p.stderr.read().decode(errors="replace")
    p.stderr.close()
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}): {err[-500:]}")
    # wait4's usage covers the process and the children it waited for (joblib's workers)
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_rss_mb": max(peak, usage.ru_maxrss * 1024) / 2**20,
            "peak_pss_mb": peak_pss / 2**20, "peak_process_rss_mb": peak_process / 2**20}


# `needle montecarlo --n N` with the kernels compiled ahead of time hidden: numba's kernels
NUMBA_ONLY = ("import sys\n"
              "from sewtol.mechanisms.needle_208 import kernels\n"
              "kernels.ahead = lambda: None\n"
              "from sewtol.cli import main\n"
              "sys.exit(main(['needle', 'montecarlo', '--n', sys.argv[1]]))\n")


def ahead_built(src: Path) -> bool:
    """Whether src's needle kernels compiled ahead of time are built (make kernels)."""
    probe = "from sewtol.mechanisms.needle_208.kernels import ahead; print(ahead() is not None)"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(src)}, check=True)
    return done.stdout.strip() == "True"


def medians(cmd, src, reference, repeats, warm: bool = True) -> dict:
    """Medians of repeats runs (one warm-up first unless warm is False), this checkout and the
    reference interleaved run by run; ratios this / reference."""
    sides = {"this": src} | ({"reference": reference} if reference is not None else {})
    for s in sides.values() if warm else ():
        run(cmd, s)  # warm-up: numba's cache on disk, the files in the page cache
    got = {k: [] for k in sides}
    for _ in range(repeats):
        for k, s in sides.items():
            got[k].append(run(cmd, s))
    out = {k: {m: statistics.median(r[m] for r in runs) for m in runs[0]}
           for k, runs in got.items()}
    if reference is not None:
        out["ratio"] = {m: out["this"][m] / out["reference"][m] for m in out["this"]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--startup-repeats", type=int, default=7,
                    help="timed runs of each start-up command (default 7; medians)")
    ap.add_argument("--reference-src", type=Path, default=None,
                    help="another checkout's src/ to run beside this one (ratios this/ref)")
    ap.add_argument("--rss-n", type=int, nargs="+", default=[10_000, 100_000, 1_000_000],
                    help="n of the peak-RSS curve (default 1e4 1e5 1e6)")
    ap.add_argument("--n-million", type=int, default=1_000_000,
                    help="machines of the end-to-end run (default 10^6)")
    ap.add_argument("--strategies-n", type=int, nargs="*", default=[2000, 10_000],
                    help="n of the `needle strategies --n-jobs 2` runs (default 2000 10000)")
    ap.add_argument("--strategies-repeats", type=int, default=1,
                    help="timed runs of each strategies n (default 1: 10^4 takes a minute)")
    ap.add_argument("--skip", nargs="*", default=[],
                    choices=["startup", "rss", "million", "strategies"])
    args = ap.parse_args(argv)
    src = ROOT / "src"
    py = [sys.executable]
    mc = [*py, "-m", "sewtol", "needle", "montecarlo"]
    res: dict = {"load_start": load(), "targets": TARGETS, "python": sys.executable,
                 "reference_src": None if args.reference_src is None else str(args.reference_src)}
    if "startup" not in args.skip:
        k = args.startup_repeats
        res["startup"] = {
            "load_before": load(),
            "python_pass": medians([*py, "-c", "pass"], None, None, k),
            "import_numpy_numba": medians([*py, "-c", "import numpy, numba"], None, None, k),
            "build_parser": medians(
                [*py, "-c", "from sewtol.cli import build_parser; build_parser()"], src,
                args.reference_src, k),
            "needle_montecarlo_n1000": medians([*mc, "--n", "1000"], src, args.reference_src, k),
            "ahead_of_time_built": ahead_built(src),
            "needle_montecarlo_n1000_numba": medians([*py, "-c", NUMBA_ONLY, "1000"], src,
                                                     None, k),
            "load_after": load()}
    if "rss" not in args.skip:
        res["peak_rss_vs_n"] = {str(n): medians([*mc, "--n", str(n), "--n-jobs", "2"], src,
                                                args.reference_src, 1, warm=False)
                                for n in args.rss_n}  # the start-up runs warmed the cache
    if "million" not in args.skip:
        before = load()
        res["million"] = medians([*mc, "--n", str(args.n_million), "--n-jobs", "2"], src,
                                 args.reference_src, args.repeats)
        res["million"].update(n=args.n_million, load_before=before, load_after=load())
    if "strategies" not in args.skip and args.strategies_n:
        st = [*py, "-m", "sewtol", "needle", "strategies", "--n-jobs", "2", "--format", "csv"]
        for s in (src, args.reference_src):
            if s is not None:
                run([*st, "--n", "20"], s)  # warm-up: numba's cache on disk
        res["strategies"] = {str(n): medians([*st, "--n", str(n)], src, args.reference_src,
                                             args.strategies_repeats, warm=False)
                             for n in args.strategies_n}
    res["load_end"] = load()
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(f"load average {res['load_start']} -> {res['load_end']}")
        for key in ("startup", "peak_rss_vs_n"):
            for name, r in res.get(key, {}).items():
                print(f"{key} {name}: {r}")
        if "startup" in res:
            st = res["startup"]
            r = st["needle_montecarlo_n1000"]
            line = (f"needle montecarlo --n 1000, medians of {args.startup_repeats}, load "
                    f"{st['load_before'][0]:.2f} -> {st['load_after'][0]:.2f}: "
                    f"{r['this']['wall_s']:.2f} s wall, {r['this']['cpu_s']:.2f} CPU-s")
            if "ratio" in r:
                line += (f"; reference {r['reference']['wall_s']:.2f} s wall, "
                         f"{r['reference']['cpu_s']:.2f} CPU-s; ratio {r['ratio']['wall_s']:.2f} "
                         f"wall, {r['ratio']['cpu_s']:.2f} CPU")
            print(line + f" (target <= {TARGETS['startup_n1000_wall_s']:g} s wall warm, idle)")
            r = st["needle_montecarlo_n1000_numba"]["this"]
            print(f"  kernels compiled ahead of time: "
                  f"{'built' if st['ahead_of_time_built'] else 'NOT built (make kernels)'}; "
                  f"on numba's kernels {r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} CPU-s")
        if "million" in res:
            r = res["million"]
            line = (f"needle montecarlo --n {r['n']} --n-jobs 2, medians of {args.repeats}, load "
                    f"{r['load_before'][0]:.2f} -> {r['load_after'][0]:.2f}: "
                    f"{r['this']['wall_s']:.1f} s wall, {r['this']['cpu_s']:.1f} CPU-s, "
                    f"{r['this']['peak_rss_mb']:.0f} MB")
            if "ratio" in r:
                line += (f"; reference {r['reference']['wall_s']:.1f} s wall, "
                         f"{r['reference']['cpu_s']:.1f} CPU-s, "
                         f"{r['reference']['peak_rss_mb']:.0f} MB; ratio "
                         f"{r['ratio']['wall_s']:.2f} wall, {r['ratio']['cpu_s']:.2f} CPU")
            print(line + f" (target <= {TARGETS['million_wall_s']:g} s wall idle, or <= "
                  f"{TARGETS['million_cpu_s']:g} CPU-s, and <= {TARGETS['peak_rss_mb']:g} MB)")
        for n, r in res.get("strategies", {}).items():
            print(f"strategies n={n}: {r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
