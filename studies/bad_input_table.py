"""The bad-input table of docs/cli.md, produced by the real CLI (tests/test_bad_inputs.py checks that
every row still matches what the CLI prints and that nothing is written).

    python studies/bad_input_table.py   # prints the table's markdown rows

Files a case needs are made in a scratch folder shown as /tmp/sewtol-bad in the table.
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

SHOWN = "/tmp/sewtol-bad"

# files the cases refer to as {d}/NAME: name -> bytes
FILES = {
    "bad1.toml": b"[sets.x]\nLF = { lower = -0.05, upper = }\n",
    "bad2.toml": b"[sets.x]\nQQ = 0.1\n",
    "bad3.toml": b"[sets.x]\nLF = { lower = 0.1, upper = -0.1 }\n",
    "pm_text.toml": b'[sets.x]\nLF = { plus_minus = "abc" }\n',
    "pm_list.toml": b"[sets.x]\nLF = { plus_minus = [1, 2] }\n",
    "latin1.toml": b"[sets.x]\ndescription = \"Kurbell\xe4nge\"\nLF = 0.05\n",
    "bool.toml": b"[sets.x]\nLF = true\n",
    "both.toml": b"[sets.x]\nLF = { plus_minus = 0.05, lower = -0.1, upper = 0.1 }\n",
    "string.toml": b'[sets.x]\nLF = "0.05"\n',
    "short.toml": b"[sets.x]\nLF = { lower = -7.0, upper = 0.05 }\n",
    "huge.toml": b"[sets.x]\nAx = 1e300\n",
    "branch.toml": b"[sets.x]\nbranch_M = 0.5\n",
    "zero.toml": b"[sets.x]\nLF = 0.0\n",
    "negative.toml": b"[sets.x]\nAB = -0.005\n",
    "a_file": b"not a folder\n",
}

# the arguments of each case ({d}: the scratch folder)
CASES = [
    "needle nominal --set LF=-2",
    "needle nominal --set QQ=1",
    "needle nominal --set LF",
    "needle nominal --set LF=abc",
    "needle nominal --set beta=nan",
    "needle nominal --set guide_shift_um=1e308",
    "needle nominal --set LF=6.8 --set LF=6.9",
    "needle nominal --set branch_C=0.5",
    "needle nominal --set CD=5",
    "needle nominal --set LM=30",
    "needle nominal --beta-range 30 20",
    "needle nominal --beta-range 0 1e9",
    "needle nominal --limit-um 0",
    "needle deviation --step-deg 0",
    "needle deviation --step-deg 1e-9",
    "needle montecarlo --n 1",
    "needle montecarlo --n abc",
    "needle montecarlo --n 1000000000000",
    "needle sobol --n 1099511627776",
    "needle strategies --n 1000000000000",
    "needle montecarlo --n-jobs 0",
    "needle montecarlo --seed -1",
    "needle montecarlo --resume",
    "needle montecarlo --out {d}/a_file",
    "needle montecarlo --out {d}/a_file/study",
    "needle sobol --n 100",
    "needle sobol --n 2",
    "needle sobol --tolerances {d}/zero.toml",
    "needle scan --tolerances nope",
    "needle montecarlo --tolerances {d}/bad1.toml",
    "needle montecarlo --tolerances {d}/bad2.toml",
    "needle montecarlo --tolerances {d}/bad3.toml",
    "needle montecarlo --tolerances {d}/none.toml",
    "needle montecarlo --tolerances {d}/pm_text.toml",
    "needle montecarlo --tolerances {d}/pm_list.toml",
    "needle montecarlo --tolerances {d}/latin1.toml",
    "needle montecarlo --tolerances {d}/bool.toml",
    "needle montecarlo --tolerances {d}/both.toml",
    "needle montecarlo --tolerances {d}/string.toml",
    "needle montecarlo --tolerances {d}/short.toml",
    "needle montecarlo --tolerances {d}/huge.toml",
    "needle montecarlo --tolerances {d}/branch.toml",
    "needle montecarlo --tolerances {d}/zero.toml",
    "needle montecarlo --tolerances {d}/negative.toml",
    "needle scan --tolerances {d}/branch.toml",
    "needle nominal --plot {d}/figure.txt",
    "needle nominal --set guide_shift_um=20 --guide-shift-um 10",
    "needle montecarlo --adjust guide_shift_um --beta-range 20 30",
    "needle montecarlo --adjust beta --plot {d}/mc.png",
    "needle montecarlo --adjust beta --setting-error beta=0.1",
    "needle strategies --adjust guide_angle --setting-error guide_angle=-0.01",
    "needle strategies --adjust guide_angle --setting-error guide_angle=gauss:0.01",
    "feed sobol --n 100",
    "feed montecarlo --adjust b --objective tgt=2",
    "needle montecarlo --tolerances {d}/fifo.toml",
    "needle montecarlo --tolerances /dev/zero",
    "feed metrics --set EN=50",
    "feed metrics --set b=120",
    "feed trajectory --set O9=1",
    "feed trajectory --step-deg 1e-9",
    "feed metrics --set material_mm=-1",
    "feed regulator --b-range 0 inf 1",
    "feed regulator --b-range 0 60 1e-9",
]

# rows whose message ends with this machine's free memory: compared up to that point
MACHINE_DEPENDENT = ("more than the memory available",
                     "more than the memory this process may still use")


def make_files(folder: Path) -> None:
    for name, data in FILES.items():
        (folder / name).write_bytes(data)
    fifo = folder / "fifo.toml"
    if not fifo.exists():
        os.mkfifo(fifo)


def run_case(args: str, folder: Path) -> tuple[int, str, str]:
    from sewtol.cli import main

    argv = args.format(d=folder).split()
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse usage errors
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def rows(folder: Path) -> list[tuple[str, str]]:
    """(command as shown, message as shown) per case."""
    out = []
    for args in CASES:
        _, _, err = run_case(args, folder)
        out.append((f"sewtol {args.format(d=SHOWN)}", err.strip().replace(str(folder), SHOWN)))
    return out


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        make_files(folder)
        for command, message in rows(folder):
            print(f"| `{command}` | {message.replace('|', '&#124;')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
