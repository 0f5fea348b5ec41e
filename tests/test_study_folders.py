"""Study folders cannot be poisoned (issue 10, items 1-5): chunks are data bound to their study,
every bad chunk is recomputed, the folder is locked, workers die with their parent."""

import json
import os
import pickle
import signal
import stat
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run
from sewtol.errors import ParameterError
from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.studies.checkpoint import LOCK_NAME, ChunkStore
from sewtol.tables.needle_208 import montecarlo
from sewtol.tolerances import NEEDLE_208_SETS


class Poison:
    """Unpickling this creates the marker file: the proof that a file was unpickled."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


MANIFEST = {"study": "test", "seed": 3, "n": 300}


def study(tmp_path, store=None, seed=3):
    return montecarlo(Needle208.nominal(), NEEDLE_208_SETS["base"], 300, seed, chunk_size=100,
                      store=store)


@pytest.fixture(scope="module")
def reference():
    """The uninterrupted study without a folder: what every repaired folder must reproduce."""
    return study(None).machines


def store_in(folder, resume=False, manifest=MANIFEST):
    return ChunkStore(folder, manifest, resume, label=str(folder))


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """A complete chunk folder of the study, computed once and copied by each test."""
    folder = tmp_path_factory.mktemp("pristine") / "chunks"
    with store_in(folder) as s:
        study(None, s)
    return folder


def copy_of(pristine, tmp_path):
    import shutil

    return Path(shutil.copytree(pristine, tmp_path / "chunks"))


def test_a_pickle_in_the_folder_is_never_loaded(tmp_path, reference, pristine, capsys):
    marker = tmp_path / "MARKER"
    folder = copy_of(pristine, tmp_path)
    for name in ("chunk_00001.pkl", "chunk_00001.npz.pkl", "manifest.pkl"):
        (folder / name).write_bytes(pickle.dumps(Poison(marker)))
    # an .npz whose array is a pickled object: np.load(allow_pickle=False) refuses it
    np.savez(folder / "chunk_00002.npz", header=np.array([Poison(marker)], dtype=object))
    assert pickle.loads(pickle.dumps(Poison(tmp_path / "probe"))) and (tmp_path / "probe").exists()
    with store_in(folder, resume=True) as s:
        res = study(tmp_path, s)
    assert not marker.exists()
    err = capsys.readouterr().err
    assert "chunk 2 in" in err and "recomputing it" in err
    assert "never opened" in err and "chunk_00001.pkl" in err
    assert res.machines.equals(reference)


def damage(folder, how):
    p1, p2 = folder / "chunk_00001.npz", folder / "chunk_00002.npz"
    if how == "copied":
        p1.write_bytes(p2.read_bytes())
    elif how == "truncated":
        p1.write_bytes(p1.read_bytes()[:500])
    elif how == "empty":
        p1.write_bytes(b"")
    elif how == "value":  # one value changed, the header left as it was
        with np.load(p1) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["a0"] = arrays["a0"].copy()
        arrays["a0"][7] += 1e-3
        np.savez(p1, **arrays)
    elif how in ("rows", "forged"):  # a consistent chunk of 50 rows / of other deviations
        from sewtol.studies.checkpoint import arrays_digest, canonical

        with np.load(p1) as z:
            header = json.loads(bytes(z["header"]))
            arrays = [z[f"a{k}"] for k in range(header["arrays"])]
        arrays = [a[:50] for a in arrays] if how == "rows" else [a[::-1].copy() for a in arrays]
        header["sha256"] = arrays_digest(arrays)
        np.savez(p1, header=np.frombuffer(canonical(header).encode(), np.uint8),
                 **{f"a{k}": a for k, a in enumerate(arrays)})
    elif how == "other_study":
        other = folder.parent / "other"
        with store_in(other, manifest={**MANIFEST, "seed": 4}) as s:
            study(None, s, seed=4)
        p1.write_bytes((other / "chunk_00001.npz").read_bytes())
    else:
        raise AssertionError(how)


@pytest.mark.parametrize("how,why", [
    ("copied", "holds chunk 2, not chunk 1"),
    ("truncated", "unreadable"),
    ("empty", "unreadable"),
    ("value", "checksum mismatch"),
    ("rows", "has shape (50,), not (100,)"),
    ("forged", "are not the ones chunk 1 draws from the seed"),
    ("other_study", "belongs to a different study"),
])
def test_a_bad_chunk_is_named_and_recomputed(tmp_path, reference, pristine, capsys, how, why):
    folder = copy_of(pristine, tmp_path)
    damage(folder, how)
    capsys.readouterr()
    with store_in(folder, resume=True) as s:
        res = study(tmp_path, s)
    err = capsys.readouterr().err
    assert f"chunk 1 in {folder}: " in err and why in err and "recomputing it" in err, err
    assert res.n == 300 and res.machines.equals(reference)
    with store_in(folder, resume=True) as s:  # the folder is whole again
        assert s.load(1)[1] is None


def test_old_chunks_without_manifest_are_never_reused_silently(tmp_path):
    """Issue 10 item 2: seed 1's chunks, manifest and outputs deleted, then seed 0 into it."""
    out = tmp_path / "o"
    assert run("needle", "montecarlo", "--n", "1000", "--seed", "1", "--out", str(out))[0] == 0
    for name in ("chunks/manifest.json", "machines.csv", "summary.csv", "montecarlo.json",
                 "run.json"):
        (out / name).unlink()
    code, stdout, err = run("needle", "montecarlo", "--n", "1000", "--seed", "0", "--out",
                            str(out), "--format", "json")
    assert code == 2 and stdout == "" and "holds chunks of an earlier run" in err
    code, stdout, err = run("needle", "montecarlo", "--n", "1000", "--seed", "0", "--out",
                            str(out), "--format", "json", "--resume")
    assert code == 0 and err.count("belongs to a different study") == 2
    fresh = run("needle", "montecarlo", "--n", "1000", "--seed", "0", "--format", "json")
    assert stdout == fresh[1]


def test_the_folder_is_locked_and_bound_to_the_code_version(tmp_path):
    from filelock import FileLock

    out = tmp_path / "o"
    assert run("needle", "montecarlo", "--n", "600", "--out", str(out))[0] == 0
    with FileLock(str(out / "chunks" / LOCK_NAME)):  # another run holds it
        code, stdout, err = run("needle", "montecarlo", "--n", "600", "--out", str(out),
                                "--resume")
    assert code == 2 and stdout == "" and "holds the lock" in err
    manifest = out / "chunks" / "manifest.json"
    m = json.loads(manifest.read_text())
    assert m["sewtol_version"] and m["git_revision"] and m["chunk_size"] == 500
    write_text_atomic(manifest, json.dumps({**m, "git_revision": "0" * 40}))
    code, _, err = run("needle", "montecarlo", "--n", "600", "--out", str(out), "--resume")
    assert code == 2 and "differs in git_revision" in err


def test_a_lock_held_by_this_process_is_released(tmp_path):
    s = store_in(tmp_path / "c")
    with pytest.raises(ParameterError, match="holds the lock"):
        store_in(tmp_path / "c", resume=True)
    s.close()
    store_in(tmp_path / "c", resume=True).close()


def test_files_get_the_users_umask(tmp_path):
    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
        os.umask(0o002)
        write_text_atomic(tmp_path / "b.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o640
    assert stat.S_IMODE((tmp_path / "b.txt").stat().st_mode) == 0o664


def test_chunk_files_hold_no_pickles(pristine):
    assert len(list(pristine.glob("chunk_*.npz"))) == 3
    for p in pristine.glob("chunk_*.npz"):
        with zipfile.ZipFile(p) as z:
            for name in z.namelist():
                with z.open(name) as fh:
                    head = fh.read(128)
                assert b"'descr': '|O'" not in head and b"'descr': 'O'" not in head


def _children(pid):
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True,
                         text=True).stdout
    return [int(x) for x in out.split()]


def _running(pid):
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


WORKERS = """
import os, sys, time
from sewtol.studies.parallel import run_chunks

def work(folder, i):
    open(os.path.join(folder, f"started_{i}_{os.getpid()}"), "w").close()
    time.sleep(120)

run_chunks(work, [(sys.argv[1], i) for i in range(4)], n_jobs=2)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_workers_die_with_their_parent(tmp_path, sig):
    """The main process killed while its two workers compute: they must not compute on."""
    proc = subprocess.Popen([sys.executable, "-c", WORKERS, str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and len(list(tmp_path.glob("started_*"))) < 2:
        time.sleep(0.05)
    workers = sorted({int(p.name.split("_")[2]) for p in tmp_path.glob("started_*")})
    assert len(workers) == 2 and all(_running(w) for w in workers)
    proc.send_signal(sig)
    proc.communicate(timeout=60)  # stdout closes once every process holding it is gone
    deadline = time.time() + 10
    while time.time() < deadline and any(_running(w) for w in workers):
        time.sleep(0.1)
    assert not any(_running(w) for w in workers)


def test_sigterm_stops_a_study_like_ctrl_c(tmp_path):
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "sewtol", "needle", "montecarlo", "--n", "400000",
           "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not list((out / "chunks").glob("chunk_*.npz")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1].startswith(
        "sewtol: terminated (SIGTERM); finished chunks are saved in")
    assert list((out / "chunks").glob("chunk_*.npz")) and not (out / "run.json").exists()
