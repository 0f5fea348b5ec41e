"""A real Dask cluster: `dask scheduler` and two `dask worker` processes started by the test
(command-line programs, as on a cluster's hosts; tests/test_cluster.py uses an in-process
LocalCluster). The same seed gives the local run's numbers: the API's machines bit for bit, and
the command line's machines.csv, summary.csv and montecarlo.json byte for byte.
"""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).with_name("dask")
START_TIMEOUT_S = 120


def _env() -> dict:
    # the workers import this checkout's sewtol and its numba cache (tests/test_cluster.py has
    # two workers compile into a fresh one at once), one numba thread each
    return dict(os.environ, PYTHONPATH=str(ROOT / "src"), NUMBA_NUM_THREADS="1")


@pytest.fixture(scope="module")
def address(tmp_path_factory):
    if not DASK.exists() and shutil.which("dask") is None:
        pytest.skip("the dask command is not installed")
    dask = str(DASK) if DASK.exists() else shutil.which("dask")
    tmp = tmp_path_factory.mktemp("dask")
    env = _env()
    info = tmp / "scheduler.json"
    procs = []
    logs = []

    def start(*args, name):
        log = open(tmp / f"{name}.log", "w")
        logs.append(log)
        procs.append(subprocess.Popen([dask, *args], env=env, cwd=tmp, stdout=log,
                                      stderr=subprocess.STDOUT))

    try:
        start("scheduler", "--scheduler-file", str(info), "--host", "127.0.0.1", "--port", "0",
              "--no-dashboard", name="scheduler")
        deadline = time.monotonic() + START_TIMEOUT_S
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert info.exists(), (tmp / "scheduler.log").read_text()[-2000:]
        for k in range(2):
            start("worker", "--scheduler-file", str(info), "--nthreads", "1", "--nworkers", "1",
                  "--no-dashboard", "--host", "127.0.0.1", name=f"worker{k}")
        with distributed.Client(scheduler_file=str(info), set_as_default=False) as c:
            c.wait_for_workers(2, timeout=START_TIMEOUT_S)
            yield c.scheduler.address
    finally:
        for p in procs[::-1]:  # the workers first, then the scheduler
            p.terminate()
        for p in procs[::-1]:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for log in logs:
            log.close()


def test_two_worker_processes_give_the_local_numbers(address, nominal):
    from sewtol.tables.needle_208 import montecarlo
    from sewtol.tolerances import NEEDLE_208_SETS

    rec = NEEDLE_208_SETS["recommended"]
    with distributed.Client(address, set_as_default=False) as client:
        workers = client.scheduler_info()["workers"]
        assert len(workers) == 2
        # two separate processes, neither of them this one
        pids = client.run(os.getpid)
        assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
        remote = montecarlo(nominal, rec, 120, seed=7, chunk_size=15, scheduler=client)
        # the eight chunks ran on both workers (the scheduler spreads them)
        ran = client.run(lambda dask_worker: len(dask_worker.state.log) > 0)
        assert all(ran.values())
    local = montecarlo(nominal, rec, 120, seed=7, chunk_size=15)
    assert remote.machines.to_csv() == local.machines.to_csv()
    a = remote.machines["total_adjusted_um"].to_numpy()
    assert np.array_equal(a, local.machines["total_adjusted_um"].to_numpy())
    assert np.isfinite(a).all()
    assert remote.summary_frame().equals(local.summary_frame())


def test_the_command_line_on_the_cluster_writes_the_local_bytes(address, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    env.pop("SEWTOL_SCHEDULER", None)
    common = ["needle", "montecarlo", "--n", "1100", "--seed", "3", "--tolerances",
              "recommended", "--format", "json"]  # three chunks of the sampler's 500
    runs = {}
    for name, extra in (("cluster", ["--scheduler", address]), ("local", [])):
        p = subprocess.run([sys.executable, "-m", "sewtol", *common, "--out", name, *extra],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-2000:]
        runs[name] = p.stdout
    assert runs["cluster"] == runs["local"]
    for f in ("machines.csv", "summary.csv", "montecarlo.json"):
        assert (tmp_path / "cluster" / f).read_bytes() == (tmp_path / "local" / f).read_bytes(), f
