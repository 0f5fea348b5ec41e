"""Scaling of `needle montecarlo` on a real Dask cluster on this machine: a `dask scheduler` and
k `dask worker` processes (one thread each, NUMBA_NUM_THREADS=1) for k in --workers, against
the same command run locally with --n-jobs 1, in the same minutes.

    python benchmarks/cluster_scaling.py --n 100000 --workers 1 2 4 --json

Each configuration runs --repeats times after one warm-up (the workers' numba cache on disk);
the figures are medians of the command's wall time (start-up, connecting, computing, writing),
with the machine's core count and load average, and every run's JSON is checked equal to the
local run's (same seed, same numbers).
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
DASK = Path(sys.executable).with_name("dask")


def load() -> list[float]:
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


def env() -> dict:
    e = dict(os.environ, PYTHONPATH=str(ROOT / "src"), NUMBA_NUM_THREADS="1")
    e.pop("SEWTOL_SCHEDULER", None)
    return e


def timed(cmd: list[str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env(), capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {p.stderr[-500:]}")
    return time.perf_counter() - t0, p.stdout


class Cluster:
    """A scheduler and k worker processes, started here and stopped on exit."""

    def __init__(self, k: int, folder: Path):
        self.k, self.folder, self.procs, self.logs = k, folder, [], []

    def _start(self, *args, name):
        log = open(self.folder / f"{name}.log", "w")
        self.logs.append(log)
        self.procs.append(subprocess.Popen([str(DASK), *args], env=env(), cwd=self.folder,
                                           stdout=log, stderr=subprocess.STDOUT))

    def __enter__(self) -> str:
        from distributed import Client

        info = self.folder / "scheduler.json"
        self._start("scheduler", "--scheduler-file", str(info), "--host", "127.0.0.1",
                    "--port", "0", "--no-dashboard", name="scheduler")
        while not info.exists():
            time.sleep(0.2)
        for i in range(self.k):
            self._start("worker", "--scheduler-file", str(info), "--nthreads", "1",
                        "--nworkers", "1", "--no-dashboard", "--host", "127.0.0.1",
                        name=f"worker{i}")
        with Client(scheduler_file=str(info), set_as_default=False) as c:
            c.wait_for_workers(self.k, timeout=300)
            return c.scheduler.address

    def __exit__(self, *exc):
        for p in self.procs[::-1]:
            p.terminate()
        for p in self.procs[::-1]:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for log in self.logs:
            log.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    cmd = [sys.executable, "-m", "sewtol", "needle", "montecarlo", "--n", str(args.n),
           "--seed", str(args.seed), "--format", "json"]
    res = {"n": args.n, "cores": os.cpu_count(), "load_start": load(), "runs": {}}
    timed(cmd)  # warm-up
    local = [timed([*cmd, "--n-jobs", "1"]) for _ in range(args.repeats)]
    want = local[0][1]
    res["runs"]["local n-jobs 1"] = {"wall_s": statistics.median(t for t, _ in local),
                                     "load": load()}
    for k in args.workers:
        with tempfile.TemporaryDirectory() as d, Cluster(k, Path(d)) as address:
            timed([*cmd, "--scheduler", address])  # warm-up: the workers load the kernels
            runs = [timed([*cmd, "--scheduler", address]) for _ in range(args.repeats)]
        assert all(out == want for _, out in runs), f"{k} workers: not the local numbers"
        res["runs"][f"{k} workers"] = {"wall_s": statistics.median(t for t, _ in runs),
                                       "load": load()}
    base = res["runs"]["local n-jobs 1"]["wall_s"]
    for r in res["runs"].values():
        r["speed_up"] = base / r["wall_s"]
    res["load_end"] = load()
    print(json.dumps(res, indent=2) if args.json else res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
