"""Yield by adjustment strategy on every other named frame of the 208 needle drive.

The frame of the 208 is not published (docs/needle_208.md); the strategies study
(needle_208_strategies.py) runs on the default frame. This one repeats the same rows (the same
compensators, resolutions and setting errors) on every other named frame, so the report can put
the range over the frames beside every strategy yield. The default frame's rows are
strategies.md's (not repeated here); the other frames use --n machines per set (fewer than the
default frame's, each row with its 95 % interval).

Writes reports/needle_208/strategies_frames.md/.csv and strategies_frames_run.json.

    python studies/needle_208_strategies_frames.py [--out reports] [--seed 2026] [--n 500]
        [--n-jobs 1] [--tolerances FILE.toml[:SET] ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

from sewtol.errors import ParameterError
from sewtol.io import write_text_atomic
from sewtol.mechanisms.needle_208.frames import DEFAULT_FRAME, frame_names
from sewtol.mechanisms.needle_208.model import Needle208
from sewtol.mechanisms.params import field_names
from sewtol.provenance import now, run_record
from sewtol.reports import plots
from sewtol.reports.tables import write_table
from sewtol.tables.needle_208 import strategies_table
from sewtol.tolerances import NEEDLE_208_SETS, resolve_all

SETS = ("base", "recommended")
COLUMNS = ["frame", "tolerances", "strategy", "resolution", "setting_error", "n", "ok",
           "out_of_spec", "cannot_assemble", "dead_point", "yield", "yield_ci_low",
           "yield_ci_high", "p50_um", "p95_um", "at_limit_share"]


def frame_rows(frames: list[str], sets: dict, n: int, seed: int, n_jobs: int = 1,
               progress=None, strategies=None) -> pd.DataFrame:
    """The strategies table of every set on every frame of `frames`, one frame after the other
    (the same seed: the same deviations on every frame); strategies None: the default rows."""
    parts = []
    for frame in frames:
        p = Needle208.nominal(frame)
        for set_name, ts in sets.items():
            ts.check_against(p)
            t = strategies_table(p, ts, n, seed, strategies, n_jobs=n_jobs).to_dataframe()
            parts.append(t.assign(frame=frame, tolerances=set_name))
            if progress:
                progress(f"{frame}, {set_name}: done")
    both = pd.concat(parts, ignore_index=True)
    return both[[c for c in COLUMNS if c in both.columns]]


JOBS_HELP = "adjust the machines in chunks on this many processes (same tables)"


def main(argv=None) -> int:
    ap = plots.study_parser(__doc__, jobs=JOBS_HELP, progress=True)
    ap.add_argument("--n", type=int, default=500, help="machines per set and frame")
    ap.add_argument("--tolerances", action="append", metavar="FILE.toml[:SET]",
                    help="these sets instead of the built-in base and recommended (repeatable)")
    args = ap.parse_args(argv)
    frames = [f for f in frame_names() if f != DEFAULT_FRAME]
    started = now()
    try:
        sets = resolve_all(args.tolerances, {k: NEEDLE_208_SETS[k] for k in SETS},
                           field_names(Needle208))
        for f in frames:
            for ts in sets.values():
                ts.check_against(Needle208.nominal(f))
        # bad --n, --seed or --n-jobs: strategies_table refuses them before any machine is made
        table = frame_rows(frames, sets, args.n, args.seed, args.n_jobs,
                           (lambda m: print(m, flush=True)) if args.progress else None)
    except ParameterError as exc:
        print(f"needle_208_strategies_frames.py: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) / "needle_208"
    out.mkdir(parents=True, exist_ok=True)
    write_table(table, out, "strategies_frames",
                "Yield by adjustment strategy on the other named frames, 208 needle drive",
                {"frames": ", ".join(frames) + f" (the default frame {DEFAULT_FRAME}: "
                 "strategies.md)",
                 "n per set and frame": args.n, "seed": args.seed,
                 "machines": "the same deviations on every frame and in every row of a set",
                 "strategies": "strategies.md's rows: the same compensators, resolutions and "
                 "setting errors",
                 "interval": "95 % Clopper-Pearson (yield_ci_low ... yield_ci_high)",
                 "counts": "ok + out_of_spec + cannot_assemble + dead_point = n"})
    inputs = {"study": "strategies on every other frame", "frames": frames, "n": args.n,
              "seed": args.seed, "sets": list(sets)}
    write_text_atomic(out / "strategies_frames_run.json",
                      json.dumps(run_record(started, inputs), indent=2) + "\n")
    print(f"wrote {out / 'strategies_frames.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
