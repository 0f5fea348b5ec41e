"""Hostile inputs (issue 26, sections 4 and 5): each is refused in one line naming the field,
rule and value, with exit 2, within a subprocess timeout (no hang, no traceback)."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cli_helpers import run

ROOT = Path(__file__).resolve().parents[1]
NEEDLE = (ROOT / "examples" / "needle_208.toml").read_text()
TIMEOUT_S = 60  # generous for an overloaded machine; the old header regex took hours on 1 MiB


def sewtol(*argv, cwd=None, timeout=TIMEOUT_S):
    """`sewtol ARGV` in a fresh process, killed after `timeout` s: (exit code, stdout, stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    p = subprocess.run([sys.executable, "-m", "sewtol", *map(str, argv)], capture_output=True,
                       text=True, timeout=timeout, env=env, cwd=cwd)
    return p.returncode, p.stdout, p.stderr


def in_process(*argv, cwd=None):
    """`sewtol ARGV` in this process, in the current folder (a test that needs no process
    boundary chdirs into `cwd` first): (exit code, stdout, stderr)."""
    return run(*map(str, argv))


def refused(*argv, cwd=None, runner=sewtol) -> str:
    """The one-line refusal of `sewtol ARGV` (exit 2, nothing on stdout, no traceback)."""
    code, out, err = runner(*argv, cwd=cwd)
    assert code == 2 and out == "" and err.count("\n") == 1, (code, out, err[-2000:])
    assert err.startswith("sewtol: error: ")
    return err


MEGA_LINE = "[" + " " * ((1 << 20) - 10_000)  # under the 1 MiB file cap with the needle


@pytest.mark.parametrize("text, expected", [
    # not TOML: refused by the TOML parser before any line is located
    (MEGA_LINE + "\n", "m.toml:1: is not valid TOML"),
    # valid TOML (the line sits in a string), refused later: the line locator scans it
    (NEEDLE.replace("[mechanism]", f'x = """\n{MEGA_LINE}\n"""\n[mechanism]'),
     "m.toml:6: x: unknown key"),
    ("x = " + "[" * 100_000 + "]" * 100_000 + "\n",
     "m.toml:1: nests arrays or inline tables too deeply to parse"),
    ("\ufeff" + NEEDLE, "m.toml:1: starts with a UTF-8 byte-order mark (BOM)"),
    (NEEDLE.replace("nominal = 6.75", "nominal = 1" + "0" * 399),
     "m.toml:21: [parameters] LF.nominal: must be a finite number (got 1000"),
    (NEEDLE.replace("nominal = 6.75", "nominal = 1" + "0" * 5000),
     "m.toml:1: is not valid TOML (got 'Exceeds the limit (4300 digits)"),
])
def test_hostile_file_is_refused_by_name_in_one_line(tmp_path, text, expected):
    (tmp_path / "m.toml").write_text(text)
    assert refused("run", "m.toml", "nominal", cwd=tmp_path).startswith(
        f"sewtol: error: {expected}")


@pytest.mark.parametrize("expr, rule", [
    ("9**9**9", "it is inf at the nominal values"),
    ("10.0**400", "it is inf at the nominal values"),
    ("1/0", "it is inf at the nominal values"),
    ("0**-1", "it is inf at the nominal values"),
    ("(-8)**(1/3)", "it is nan at the nominal values"),
    ("sqrt(-1)", "it is nan at the nominal values"),
    ("acos(2)", "it is nan at the nominal values"),
    ("Ax + sqrt(Ax)", "it is nan at the nominal values"),  # Ax < 0
    ("Ax ** Ax", "it is nan at the nominal values"),  # Python floats would give a complex
    ("Ax / (Ax - Ax)", "it is -inf at the nominal values"),
    ("1" + "0" * 399, "a 400-digit number is not a finite 64-bit float"),
    ("Ax + 1e400", "the number inf is not a finite 64-bit float"),
])
def test_numeric_errors_of_an_expression_name_the_field_and_value(tmp_path, expr, rule):
    (tmp_path / "m.toml").write_text(NEEDLE.replace('x = "Ax"', f'x = "{expr}"'))
    err = refused("run", "m.toml", "nominal", cwd=tmp_path)
    assert err.startswith("sewtol: error: m.toml:51: [[groups]] A.x: ")
    assert rule in err and err.endswith(f"(got '{expr}')\n")


@pytest.mark.parametrize("literal", ["nan", "inf", "1" + "0" * 400])
def test_non_finite_literal_field_is_refused_at_load(tmp_path, literal):
    (tmp_path / "m.toml").write_text(NEEDLE.replace('x = "Ax"', f"x = {literal}"))
    err = refused("run", "m.toml", "nominal", cwd=tmp_path)
    assert err.startswith("sewtol: error: m.toml:51: [[groups]] A.x: ")
    assert "is not a finite 64-bit float" in err and "cannot close" not in err


# --- command-line inputs ----------------------------------------------------------------------

TWO_SETS = "[sets.tight]\nLF = 0.01\nLM = 0.02\n\n[sets.loose]\nLF = 0.05\n"


def test_tolerance_set_spec_is_split_at_the_last_colon(tmp_path):
    (tmp_path / "good.toml").write_text(TWO_SETS)
    (tmp_path / "x.toml.d").mkdir()
    (tmp_path / "x.toml.d" / "good.toml").write_text(TWO_SETS)
    for spec in ("good.tomlx", "good.tomlx:tight"):  # once ran set x / tight of good.toml
        assert refused("needle", "scan", "--tolerances", spec, cwd=tmp_path) == \
            "sewtol: error: good.tomlx: cannot be read (got 'No such file or directory')\n"
    code, out, err = sewtol("needle", "scan", "--tolerances", "x.toml.d/good.toml:tight",
                            "--format", "csv", cwd=tmp_path)
    assert code == 0 and err == ""
    rows = [r.split(",") for r in out.splitlines()]
    assert sorted({r[0] for r in rows[1:]}) == ["LF", "LM"]  # the two of set tight
    assert {r[2] for r in rows[1:] if r[0] == "LF"} == {"0.01", "-0.01"}


@pytest.mark.parametrize("argv, expected", [
    (("needle", "montecarlo", "--n", "50", "--out", ""), "--out: must name a folder (got '')"),
    (("run", "needle_208", "sobol", "--out", ""), "--out: must name a folder (got '')"),
    (("needle", "nominal", "--set", "LF=6.8", "--set", "LF=6.9"),
     "LF: is given twice; give each name once (got 'LF=6.9')"),
    (("needle", "nominal", "--set", "guide_shift_um=1e308"),
     "guide_shift_um: must be a finite number in [-1e+06, 1e+06] (got '1e308')"),
    (("needle", "nominal", "--set", "beta=nan"),
     "beta: must be a finite number in [-1e+06, 1e+06] (got 'nan')"),
    (("run", "needle_208", "nominal", "--set", "guide_shift_um=-inf"),
     "guide_shift_um: must be a finite number in [-1e+06, 1e+06] (got '-inf')"),
])
def test_cli_value_is_refused_by_name(tmp_path, argv, expected):
    assert refused(*argv, cwd=tmp_path) == f"sewtol: error: {expected}\n"
    assert list(tmp_path.iterdir()) == []


def test_a_folder_of_another_study_is_refused_and_kept(tmp_path, monkeypatch):
    """`run FILE montecarlo|sobol --out D` over another study's results: refused before
    computing (as the needle path's manifest check does), D left as it was. In this process:
    nothing here can hang, and the folder is the point, not the process boundary."""
    monkeypatch.chdir(tmp_path)
    base = ("run", "needle_208")
    flags = ("--path", "generic", "--out", "D")
    assert in_process(*base, "montecarlo", "--n", "20", *flags)[0] == 0
    before = {p.name: p.read_bytes() for p in (tmp_path / "D").iterdir()}
    assert in_process(*base, "montecarlo", "--n", "20", *flags)[0] == 0  # same study
    err = refused(*base, "sobol", "--n", "16", *flags, runner=in_process)
    # montecarlo adjusts beta (the file's [defaults] adjust), sobol nothing
    assert err == ("sewtol: error: --out: holds the results of a different study (differs in "
                   "adjust, n, study); choose an empty folder (got 'D')\n")
    assert refused(*base, "montecarlo", "--n", "20", "--seed", "1", *flags,
                   runner=in_process).startswith("sewtol: error: --out: holds the results of a "
                                                 "different study (differs in seed)")
    after = {p.name: p.read_bytes() for p in (tmp_path / "D").iterdir()}
    assert after.keys() == before.keys() and after["machines.csv"] == before["machines.csv"]
    # the same study rerun by another revision of the code (as `make report` reruns every
    # report into its own folder) replaces its results: the code's identity is not an input
    record = json.loads((tmp_path / "D" / "run.json").read_text())
    record["inputs"].update(git_revision="0" * 40, sewtol_version="0.0.0")
    (tmp_path / "D" / "run.json").write_text(json.dumps(record))
    assert in_process(*base, "montecarlo", "--n", "20", *flags)[0] == 0
    assert (tmp_path / "D" / "machines.csv").read_bytes() == before["machines.csv"]
    # an unfinished chunked study (manifest, no run.json) is not mixed with a generic one
    (tmp_path / "E" / "chunks").mkdir(parents=True)
    (tmp_path / "E" / "chunks" / "manifest.json").write_text("{}")
    assert "holds the chunks of another study" in refused(
        *base, "sobol", "--n", "16", "--path", "generic", "--out", "E", runner=in_process)
    # the needle path refuses a generic study's folder the same way
    assert "holds the results of a different study" in refused(
        "needle", "montecarlo", "--n", "50", "--out", "D", runner=in_process)


# --- study folders ----------------------------------------------------------------------------

@pytest.mark.parametrize("make", ["fifo", "deep"])
def test_a_hostile_manifest_is_refused_in_one_line_and_the_chunks_kept(tmp_path, make,
                                                                     monkeypatch):
    argv = ("needle", "montecarlo", "--n", "400", "--out", "D")
    monkeypatch.chdir(tmp_path)  # the study in this process; the refusals (a FIFO) in their own
    assert in_process(*argv)[0] == 0
    manifest = tmp_path / "D" / "chunks" / "manifest.json"
    chunks = {p.name: p.read_bytes() for p in manifest.parent.glob("chunk_*.npz")}
    assert chunks
    manifest.unlink()
    if make == "fifo":
        os.mkfifo(manifest)  # a read would block forever
    else:
        manifest.write_text("[" * 200_000)  # json.loads: RecursionError
    assert refused(*argv, "--resume", cwd=tmp_path) == (
        "sewtol: error: --resume: the folder's manifest.json is not a sewtol manifest "
        "(got 'D')\n")
    assert refused(*argv, cwd=tmp_path).startswith("sewtol: error: --out: holds a study already")
    assert {p.name: p.read_bytes() for p in manifest.parent.glob("chunk_*.npz")} == chunks


def test_a_write_failure_names_the_file_not_its_temp_file(tmp_path):
    (tmp_path / "D" / "machines.csv" / "x").mkdir(parents=True)  # the target is a folder
    err = refused("needle", "montecarlo", "--n", "50", "--out", "D", cwd=tmp_path)
    assert err == ("sewtol: error: --out: cannot be written (Is a directory); the finished "
                   "chunks are kept: fix it and rerun with --resume (got 'D/machines.csv')\n")
    assert sorted(p.name for p in (tmp_path / "D" / "chunks").glob("chunk_*.npz")) == \
        ["chunk_00000.npz"]


def test_a_chunk_that_unpacks_beyond_the_cap_is_rejected_unread(tmp_path, monkeypatch):
    """The size cap bounds the unpacked size too (a deflated chunk, a zip bomb in small)."""
    import numpy as np

    from sewtol.studies import checkpoint

    with checkpoint.ChunkStore(tmp_path, {"study": "bomb"}, False) as store:
        store.save(0, np.zeros(100_000))  # 800 kB unpacked
        path = tmp_path / "chunk_00000.npz"
        with np.load(path) as z:
            members = {k: z[k] for k in z.files}
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **members)
        assert path.stat().st_size < 10_000 and store.load(0)[1] is None  # still a good chunk
        monkeypatch.setattr(checkpoint, "MAX_CHUNK_BYTES", 100_000)
        assert store.load(0) == (None, "unpacks to more than 100000 bytes")


@pytest.mark.parametrize("text, rule", [
    ("\ufeff" + TWO_SETS, "starts with a UTF-8 byte-order mark (BOM)"),
    ("x = " + "[" * 100_000 + "]" * 100_000 + "\n", "nests arrays or inline tables too deeply"),
])
def test_a_hostile_tolerance_file_is_refused_by_name(tmp_path, text, rule):
    (tmp_path / "t.toml").write_text(text)
    assert refused("needle", "scan", "--tolerances", "t.toml:tight", cwd=tmp_path).startswith(
        f"sewtol: error: t.toml: {rule}")


def test_a_write_failure_names_the_target_for_every_cause(tmp_path, monkeypatch):
    """write_bytes_atomic's OSError names the file asked for, never its temporary file, and
    leaves no temporary file: a folder in the way, a refused rename, a full disk."""
    from sewtol import io

    (tmp_path / "a.csv").mkdir()
    with pytest.raises(IsADirectoryError) as info:
        io.write_text_atomic(tmp_path / "a.csv", "x\n")
    assert info.value.filename == str(tmp_path / "a.csv") and info.value.strerror
    for exc in (PermissionError(13, "Permission denied"), OSError(28, "No space left on device")):
        def refuse(src, dst, exc=exc):
            raise type(exc)(exc.errno, exc.strerror, src, None, dst)
        monkeypatch.setattr(io.os, "replace", refuse)
        with pytest.raises(OSError) as info:
            io.write_text_atomic(tmp_path / "b.csv", "x\n")
        assert (info.value.errno, info.value.filename) == (exc.errno, str(tmp_path / "b.csv"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]  # no .b.csv.*.tmp left


# --- Dask scheduler addresses -----------------------------------------------------------------

SCHEDULER_TIMEOUT_S = 180  # a subprocess's imports take ~30 s on this loaded machine; a hang is
# caught either way (the HTTP case used to wait forever)


@contextlib.contextmanager
def _server(kind, drop_after_s=None):
    """A local server on a free port that is not a Dask scheduler: an HTTP server (it waits
    for a request line that never comes) or one that answers every connection with random
    bytes (they once decoded to a 3 EiB frame). Yields its tcp:// address."""
    import http.server
    import socket
    import threading

    import numpy as np

    class Handler(http.server.BaseHTTPRequestHandler):
        # drop_after_s: a connection that never sends its request line is dropped then; the
        # server handles one connection at a time, so shutdown() would wait for ever on a
        # client that stalled after the probe and is never closed
        timeout = drop_after_s

    if kind == "http":
        server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        try:
            yield f"tcp://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()
            server.server_close()
        return
    garbage = np.random.default_rng(26).bytes(1 << 16)
    listener = socket.create_server(("127.0.0.1", 0))

    def serve():
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:  # closed at the end of the test
                return
            with conn, contextlib.suppress(OSError):
                conn.sendall(garbage)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        listener.close()


@pytest.mark.parametrize("kind, rule", [
    ("http", "no Dask scheduler answers there within 10 s (got"),
    ("garbage", "something answers there, but not as a Dask scheduler ("),
])
def test_a_server_that_is_not_a_scheduler_is_refused_in_one_line(tmp_path, kind, rule):
    with _server(kind) as address:
        code, out, err = sewtol("needle", "montecarlo", "--n", "50", "--out", "D",
                                "--scheduler", address, cwd=tmp_path,
                                timeout=SCHEDULER_TIMEOUT_S)
    assert code == 2 and out == "" and err.count("\n") == 1, (code, out, err[-2000:])
    assert err.startswith(f"sewtol: error: --scheduler: {rule}")
    assert err.endswith(f"(got '{address}')\n")
    assert not list(tmp_path.rglob("chunk_*.npz"))  # refused before any chunk was computed


@pytest.mark.parametrize("address, why", [
    ("tcp://[::1", "invalid address '[::1'"),
    ("tcp://127.0.0.1:99999", "port 99999 is not in 1..65535"),
    ("tcp://host", "missing port number in address 'host'"),
    ("foo://host:1", "unknown address scheme 'foo'"),
])
def test_a_malformed_scheduler_address_is_one_line_and_nothing_after_it(tmp_path, address, why):
    """Refused before a client is made, so no half-made client prints "Exception ignored"
    at exit."""
    code, out, err = sewtol("needle", "montecarlo", "--n", "50", "--scheduler", address,
                            cwd=tmp_path, timeout=SCHEDULER_TIMEOUT_S)
    assert code == 2 and out == "" and err.count("\n") == 1, (code, out, err[-2000:])
    assert err.startswith("sewtol: error: --scheduler: must be a Dask scheduler address such "
                          f"as tcp://host:8786 ({why}")


@pytest.mark.parametrize("kind", ["http", "garbage", "closed"])
def test_the_stated_scheduler_timeout_is_the_real_one(kind):
    """connect() gives up within its timeout (plus the probe thread's one second to wind
    down): the message's "within N s" is what happens."""
    import time

    import distributed.comm  # noqa: F401  (imports are not the connection's time)

    from sewtol.errors import ParameterError
    from sewtol.studies.parallel import connect

    timeout = 3.0
    with contextlib.ExitStack() as stack:
        address = ("tcp://127.0.0.1:1" if kind == "closed" else
                   stack.enter_context(_server(kind)))
        start = time.monotonic()
        with pytest.raises(ParameterError) as info:
            connect(address, timeout=timeout)
        elapsed = time.monotonic() - start
    assert elapsed < timeout + 1.5, elapsed
    if kind != "garbage":
        assert elapsed >= timeout - 0.1, elapsed  # it did wait as long as it says
        assert f"within {timeout:g} s" in info.value.rule


# --- memory limits ----------------------------------------------------------------------------

def test_the_memory_estimate_honours_the_address_space_limit(tmp_path):
    """Under `ulimit -v` 1.5 GB the 2e7-machine study (2.3 GiB of machines held compactly; its
    table --out writes in chunks) is refused up front in one line, instead of computed and then
    lost to a MemoryError traceback."""
    import resource

    from sewtol.studies.montecarlo import montecarlo_bytes

    # each machine's SumDelta fixed and adjusted, beta*, its plateau and bound flag, the
    # failure figures of both cases (8 bytes each), its statuses (1 byte each), the summary's
    # working copies
    per = montecarlo_bytes(1, 1)
    assert per == 8 * (2 + 4 + 2 * 3) + 4 + 24

    limit = 1_500_000_000
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    p = subprocess.run([sys.executable, "-m", "sewtol", "needle", "montecarlo", "--n", "20000000",
                        "--out", "D"], capture_output=True, text=True, env=env, cwd=tmp_path,
                       timeout=SCHEDULER_TIMEOUT_S,
                       preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit, limit)))
    assert p.returncode == 2 and p.stdout == "" and p.stderr.count("\n") == 1, p.stderr[-2000:]
    assert p.stderr.startswith(f"sewtol: error: --n: needs about {2e7 * per / 2**30:.3g} GiB "
                               f"for 20000000 machines of {per} bytes each, more than the memory "
                               "this process may still use (")
    # the n that fits: the largest whose estimate (per bytes a machine) is within what is left
    left = float(p.stderr.split("may still use (")[1].split(" GiB")[0]) * 2**30
    fits = int(p.stderr.split("at most n = ")[1].split(" fits")[0])
    assert 0 < fits < 20_000_000 and abs(fits * per - left) <= 0.005 * left + per
    assert p.stderr.endswith(f" GiB, address-space limit (ulimit -v)): at most n = {fits} fits "
                             "(got 20000000)\n")
    assert not (tmp_path / "D").exists()


@pytest.mark.parametrize("version", ["v2", "v1"])
def test_the_memory_estimate_honours_a_container_limit(tmp_path, monkeypatch, version):
    from sewtol.errors import ParameterError
    from sewtol.studies import montecarlo

    limit, usage = tmp_path / "limit", tmp_path / "usage"
    limit.write_text(f"{2**30}\n")  # 1 GiB, of which 256 MiB in use: 0.75 GiB left
    usage.write_text(f"{2**28}\n")
    files = [("/nonexistent/memory.max", "/nonexistent/memory.current"), (limit, usage)]
    monkeypatch.setattr(montecarlo, "CGROUP_MEMORY_FILES",
                        files if version == "v1" else files[::-1])
    assert montecarlo.memory_limits_bytes()["container memory limit (cgroup)"] == 3 * 2**28
    montecarlo.check_memory(100_000, 28)  # 0.09 GB fits
    # 0.75 GiB / (28 columns x 32 bytes) = 898,779.4 rows: n = 898,779 fits, one more does not
    with pytest.raises(ParameterError, match=r"needs about 0\.834 GiB for 28 columns of 1000000 "
                       r"rows, more than the memory this process may still use \(0\.75 GiB, "
                       r"container memory limit \(cgroup\)\): at most n = 898779 fits"):
        montecarlo.check_memory(1_000_000, 28)
    montecarlo.check_memory(898_779, 28)
    with pytest.raises(ParameterError, match="at most n = 898779 fits"):
        montecarlo.check_memory(898_780, 28)
    # Sobol: n base samples of 10 rows each, n a power of two: 251,658 samples of 10 columns fit
    # in 0.75 GiB, so 2**17 = 131,072 is the largest n (2**18 = 262,144 does not)
    with pytest.raises(ParameterError, match="at most n = 131072 fits"):
        montecarlo.check_memory(2**20 * 10, 10, value=2**20, rows_per_unit=10, power_of_two=True)
    limit.write_text("max\n")  # v2's "no limit", and v1's page-rounded 2**63 - 1
    assert "container memory limit (cgroup)" not in montecarlo.memory_limits_bytes()
    limit.write_text("9223372036854771712\n")
    assert "container memory limit (cgroup)" not in montecarlo.memory_limits_bytes()


def test_the_sobol_memory_estimate_counts_the_bootstrap(nominal, monkeypatch):
    """check_sobol's estimate: the design, outputs and words, and the bootstrap's resamples and
    working arrays (docs/cli.md; measured peaks in docs/studies.md), first and second order."""
    # the Sobol study itself when some row fails: per row of the base set's needle design
    # (D = 6; 8 rows a base sample, 14 with S2) the 6 inputs, 2 outputs, the output analysed
    # and 5 columns of words, 8 bytes each (112), and the bootstrap's 200 int32 resamples a
    # base sample and BOOTSTRAP_ARRAYS arrays of BOOTSTRAP_CELLS doubles shared out over the
    # rows at n = 2**17 (124 bytes a row of 2**20, 71 of 14 * 2**17); the run's machinery left
    # out here
    from sewtol.errors import ParameterError
    from sewtol.studies import montecarlo, sobol
    from sewtol.tolerances import needle_set

    boot = 4 * 200 * 2**17 + sobol.BOOTSTRAP_ARRAYS * 8 * sobol.BOOTSTRAP_CELLS
    assert (sobol.BOOTSTRAP_ARRAYS, sobol.BOOTSTRAP_CELLS) == (12, 2**18)
    monkeypatch.setattr(montecarlo, "run_reserve_bytes", lambda source, workers=0: 0)
    base = needle_set("base")
    for second_order, rows, per in ((False, 2**20, 236), (True, 14 * 2**17, 183)):
        assert per == 8 * (6 + 8) + -(-boot // rows)
        monkeypatch.setattr(montecarlo, "memory_limits_bytes",
                            lambda have=per * rows: {"available memory": have})
        sobol.check_sobol(nominal, base, 2**17, 0, second_order)
        monkeypatch.setattr(montecarlo, "memory_limits_bytes",
                            lambda have=per * rows - 1: {"available memory": have})
        with pytest.raises(ParameterError, match=rf"needs about {per * rows / 2**30:.3g} GiB "
                           rf"for {rows} machines of {per} bytes each, .*: at most n = 65536 "
                           "fits"):
            sobol.check_sobol(nominal, base, 2**17, 0, second_order)


def test_a_second_order_sobol_that_cannot_fit_is_refused_before_it_starts(nominal, monkeypatch,
                                                                           capsys, tmp_path):
    """`needle sobol --second-order` counts its 14 rows a base sample: with memory for the
    first-order run of --n 131072 and not for the second-order one, the first is let through
    and the second refused in one line (exit 2) naming --n and the n that fits."""
    from sewtol.cli import main
    from sewtol.studies import montecarlo, sobol
    from sewtol.tolerances import needle_set

    rows, per = 14 * 2**17, 183  # the estimate above
    monkeypatch.setattr(montecarlo, "run_reserve_bytes", lambda source, workers=0: 0)
    monkeypatch.setattr(montecarlo, "memory_limits_bytes",
                        lambda: {"available memory": per * rows - 1})
    sobol.check_sobol(nominal, needle_set("base"), 2**17, 0, False)
    out = tmp_path / "study"
    code = main(["needle", "sobol", "--n", "131072", "--second-order", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 2 and captured.out == "" and not out.exists()
    assert captured.err.strip().splitlines() == [
        f"sewtol: error: --n: needs about {per * rows / 2**30:.3g} GiB for {rows} machines of "
        f"{per} bytes each, more than the memory this process may still use "
        f"({(per * rows - 1) / 2**30:.3g} GiB, available memory): at most n = 65536 fits "
        "(got 131072)"]


@pytest.mark.parametrize("kind", ["http", "garbage"])
def test_a_scheduler_that_stops_answering_after_the_probe_is_one_error(kind, monkeypatch):
    """The client after a passed probe is bounded by the same timeout, and a failed one is
    closed: a ParameterError naming the address, not a hang or a traceback."""
    import time

    import distributed.comm  # noqa: F401  (imports are not the connection's time)

    from sewtol.errors import ParameterError
    from sewtol.studies import parallel

    monkeypatch.setattr(parallel, "probe", lambda address, timeout: None)  # it answered
    timeout = 3.0
    with _server(kind, drop_after_s=timeout + 2.0) as address:
        start = time.monotonic()
        with pytest.raises(ParameterError, match="the Dask scheduler there stopped answering"):
            parallel.connect(address, timeout=timeout)
        assert time.monotonic() - start < timeout + 1.0
