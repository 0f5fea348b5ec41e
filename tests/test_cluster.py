"""Studies on a Dask cluster: a LocalCluster of two worker processes against a local run.

Same seed, same bytes (chunks draw from rng.spawn children, whatever worker runs them); a worker
killed mid-study loses nothing but time; an interrupted study resumes from its saved chunks;
numba's kernels compile on both workers at once into one fresh cache and agree; each worker
runs numba with the threads it is given. Kept small: four to eight chunks of a few machines.
"""

import logging
import os
import signal
import time

import numpy as np
import pytest

from sewtol.cli import main
from sewtol.studies import parallel
from sewtol.studies.checkpoint import ChunkStore
from sewtol.studies.montecarlo import _file_model, sample_machines
from sewtol.tables.needle_208 import as_mechanism, montecarlo, needle_sobol
from sewtol.tolerances import NEEDLE_208_SETS

distributed = pytest.importorskip("distributed")

REC = NEEDLE_208_SETS["recommended"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    # a fresh numba cache: both workers compile the kernels at once and write into it
    cache = tmp_path_factory.mktemp("numba_cache")
    env = {"NUMBA_NUM_THREADS": "1", "NUMBA_CACHE_DIR": str(cache)}
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=None, silence_logs=logging.ERROR,
                                  env=env) as lc:
        lc.numba_cache = cache
        yield lc


@pytest.fixture
def client(cluster):
    with distributed.Client(cluster, set_as_default=False) as c:
        c.wait_for_workers(2, timeout=120)
        yield c


def test_needle_montecarlo_on_the_cluster_is_the_local_run(client, cluster, nominal):
    seen = []
    remote = montecarlo(nominal, REC, 60, seed=7, chunk_size=15, scheduler=client,
                        progress=lambda done, total: seen.append((done, total)))
    local = montecarlo(nominal, REC, 60, seed=7, chunk_size=15)
    assert remote.machines.to_csv() == local.machines.to_csv()
    assert remote.machines["total_adjusted_um"].notna().all()
    # the callback: once before the first chunk, then once per chunk as each one completes
    assert seen == [(k, 4) for k in range(5)]
    # numba: every worker runs one thread, as its environment says, and both workers compiled
    # the kernels (concurrently, into one fresh cache) and agree on the same chunk bit for bit
    threads = client.run(lambda: __import__("numba").config.NUMBA_NUM_THREADS)
    assert set(threads.values()) == {1}
    assert list(cluster.numba_cache.rglob("*.nbi"))
    rng = np.random.default_rng(11)
    dev = REC.active().sample(rng, 9)
    mech = as_mechanism(nominal)
    kw = {"mech": mech, "outputs": ["SumDelta_um"], "compensator": {"beta": (10.0, 35.0)},
          "target": "SumDelta_um", "fast": True}
    want = _file_model(None, dev, **kw)
    for address in client.scheduler_info()["workers"]:
        got = client.submit(_file_model, None, dev, **kw, workers=[address],
                            pure=False).result()
        for k, v in want.items():
            assert np.array_equal(got[k], v, equal_nan=k not in ("status", "status_adjusted",
                                                                  "failed_group",
                                                                  "failed_group_adjusted")), \
                (address, k)


def test_numba_threads_per_task_are_the_workers_share(client):
    def probe(_):
        import numba

        return parallel.numba_threads_on_worker(), numba.get_num_threads()

    out = parallel.run_chunks(probe, [(k,) for k in range(4)], scheduler=client)
    assert out == [(1, 1)] * 4  # NUMBA_NUM_THREADS = 1 over one task at a time
    assert parallel.numba_threads_on_worker() is None  # not on a worker here


def _slow_model(nominal, dev):
    time.sleep(0.3)
    return {"sum_mm": sum(dev.values())}


def test_a_killed_worker_loses_nothing(client, nominal):
    pids = client.run(os.getpid)
    killed = []

    def kill_one(done, total):
        if done == 1 and not killed:  # mid-study: a worker dies with work in hand
            victim = sorted(pids.values())[0]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    remote = sample_machines(_slow_model, nominal, REC, 64, seed=5, chunk_size=8,
                             scheduler=client, progress=kill_one)
    local = sample_machines(_slow_model, nominal, REC, 64, seed=5, chunk_size=8)
    assert killed
    assert remote.to_csv() == local.to_csv()
    client.wait_for_workers(2, timeout=120)  # the nanny brings the worker back


class Stop(Exception):
    pass


@pytest.mark.filterwarnings("ignore:.*tasks which were still being processed:UserWarning")
def test_an_interrupted_cluster_study_resumes_from_its_chunks(client, nominal, tmp_path):
    manifest = {"study": "test", "seed": 5}

    def stop_after_three(done, total):
        if done == 3:
            raise Stop

    with pytest.raises(Stop):
        sample_machines(_slow_model, nominal, REC, 64, seed=5, chunk_size=8, scheduler=client,
                        progress=stop_after_three,
                        store=ChunkStore(tmp_path, manifest, resume=False))
    saved = ChunkStore(tmp_path, manifest, resume=True).done()
    assert len(saved) >= 3
    seen = []
    resumed = sample_machines(_slow_model, nominal, REC, 64, seed=5, chunk_size=8,
                              scheduler=client, progress=lambda d, t: seen.append(d),
                              store=ChunkStore(tmp_path, manifest, resume=True))
    assert seen[0] == len(saved) and seen[-1] == 8  # only the rest was computed
    local = sample_machines(_slow_model, nominal, REC, 64, seed=5, chunk_size=8)
    assert resumed.to_csv() == local.to_csv()


def test_cli_scheduler_writes_the_local_bytes(cluster, tmp_path, nominal, capsys):
    address = cluster.scheduler_address
    args = ["needle", "montecarlo", "--n", "40", "--seed", "3", "--tolerances", "recommended",
            "--format", "json"]
    assert main([*args, "--out", str(tmp_path / "local")]) == 0
    assert main([*args, "--out", str(tmp_path / "remote"), "--scheduler", address]) == 0
    for name in ("machines.csv", "summary.csv", "montecarlo.json"):
        assert (tmp_path / "local" / name).read_bytes() == \
            (tmp_path / "remote" / name).read_bytes(), name
    capsys.readouterr()
    # the environment variable is the same switch, and --n-jobs stays the local path
    os.environ["SEWTOL_SCHEDULER"] = address
    try:
        assert main(["needle", "montecarlo", "--n", "10", "--n-jobs", "2"]) == 2
        assert "--n-jobs: is the single-machine path; with SEWTOL_SCHEDULER" in \
            capsys.readouterr().err
    finally:
        del os.environ["SEWTOL_SCHEDULER"]
    # and Sobol through the API on the cluster gives the local indices
    a = needle_sobol(nominal, REC, 16, seed=2, chunk_size=80, scheduler=address)
    b = needle_sobol(nominal, REC, 16, seed=2, chunk_size=80)
    assert a.to_dataframe().equals(b.to_dataframe())


def test_bad_scheduler_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["needle", "montecarlo", "--n", "10", "--scheduler", "tcp://a b",
                 "--out", str(out)]) == 2
    assert capsys.readouterr().err == ("sewtol: error: --scheduler: must be a Dask scheduler "
                                       "address such as tcp://host:8786 (got 'tcp://a b')\n")
    assert not out.exists()
    with pytest.raises(ValueError, match="n_jobs: is the single-machine path"):
        parallel.run_chunks(abs, [(1,)], n_jobs=2, scheduler="tcp://127.0.0.1:1")


def test_progress_callback_on_this_machine():
    seen = []
    out = parallel.run_chunks(abs, [(-1,), (-2,), (-3,)],
                              progress=lambda d, t: seen.append((d, t)))
    assert out == [1, 2, 3] and seen == [(0, 3), (1, 3), (2, 3), (3, 3)]
    seen.clear()
    out = parallel.run_chunks(abs, [(-1,), (-2,), (-3,)], n_jobs=2, backend="threading",
                              progress=lambda d, t: seen.append((d, t)))
    assert out == [1, 2, 3] and seen == [(0, 3), (1, 3), (2, 3), (3, 3)]


def test_an_error_in_a_worker_thread_is_raised_in_the_caller():
    """The threads' pool (backend "threading") raises a chunk's error where run_chunks was
    called, as the serial path does."""
    with pytest.raises(ValueError, match="invalid literal for int"):
        parallel.run_chunks(int, [("1",), ("x",), ("2",)], n_jobs=2, backend="threading")
