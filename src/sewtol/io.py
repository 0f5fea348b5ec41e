"""Atomic file output: write to a temporary file in the same folder, then rename.

Files get the permissions of a plain `open()` (0666 less the user's umask), not mkstemp's 0600,
so a study folder shared through group permissions stays readable by the group.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tempfile
from pathlib import Path

import numpy as np


def strict(o):
    """JSON-ready data with every NaN or infinity as None (null): JSON has no NaN or Infinity.

    What null means for each key is listed in docs/cli.md (e.g. a quantile beyond every machine
    that runs, a Cpu without scatter, a window that does not exist).
    """
    if isinstance(o, dict):
        return {str(k): strict(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [strict(v) for v in o]
    if isinstance(o, np.ndarray):
        return strict(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def to_json(data) -> str:
    """Strict JSON text (indent 2, a final newline) of data, as every sewtol output writes it."""
    return json.dumps(strict(data), indent=2, allow_nan=False) + "\n"


def read_json(path, max_bytes: int = 64 << 20):
    """The JSON value of a regular file, else None: missing, a FIFO or device (checked before
    opening, so a read never blocks), unreadable, too large, malformed or nested too deep. A
    study folder is data, never trusted to be well-formed."""
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > max_bytes:
            return None
        return json.loads(Path(path).read_bytes().decode("utf-8"))
    except (OSError, ValueError, RecursionError):
        return None


def umask() -> int:
    """The process umask (read from /proc where it can, so it is never changed even briefly)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def write_text_atomic(path: Path, text: str) -> None:
    """UTF-8 text with the newlines as given."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_pieces_atomic(path: Path, pieces) -> None:
    """UTF-8 text written piece by piece (an iterable of str) into `path` through a temporary
    file beside it, as `write_bytes_atomic`: a long table is never one string in memory."""
    write_bytes_atomic(path, (p.encode("utf-8") for p in pieces))


def write_bytes_atomic(path: Path, data) -> None:
    """`data` into `path` through a temporary file beside it; an OSError names `path` (its
    filename), never the temporary file, which is removed."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            for piece in (data,) if isinstance(data, (bytes, bytearray)) else data:
                fh.write(piece)
            os.fchmod(fh.fileno(), 0o666 & ~umask())
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and tmp is not None and exc.filename in (None, tmp):
            raise type(exc)(exc.errno, exc.strerror, str(path)) from exc
        raise
