"""Checkpoints of a chunked study: each finished chunk is saved at once, atomically, so
`--resume` continues without recomputing it. A study folder is data, never code: a manifest
(the study hash is the SHA-256 of its canonical JSON), chunk_NNNNN.npz files of numeric arrays
read with allow_pickle=False and a JSON header checked before use, and a file lock against two
runs in one folder. The checksum is not a signature: see docs/study_folders.md.
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
import zipfile
from pathlib import Path

import numpy as np

from sewtol.errors import ParameterError
from sewtol.io import read_json, write_bytes_atomic, write_text_atomic

FORMAT = "sewtol-chunk-1"
MAX_CHUNK_BYTES = 512 * 2**20  # a chunk larger than this is not one of ours
LOCK_NAME = ".sewtol.lock"


def canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False, default=str)


def study_hash(manifest: dict) -> str:
    return hashlib.sha256(canonical(manifest).encode()).hexdigest()


def _encode(obj, arrays: list) -> object:
    """The layout of a result made of tuples, lists, str-keyed dicts and numeric arrays."""
    if isinstance(obj, (tuple, list)):
        return {"seq": [_encode(x, arrays) for x in obj]}
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise TypeError("chunk results may only hold dicts with str keys")
        return {"dict": [[k, _encode(v, arrays)] for k, v in obj.items()]}
    a = np.asarray(obj)
    if a.dtype == object and all(isinstance(x, str) for x in a.flat):
        a = a.astype(str)  # labels (a machine's status): fixed-width text, no pickle needed
    if a.dtype.kind not in "biufU":
        raise TypeError(f"chunk results may only hold numeric or text arrays, not {a.dtype}")
    arrays.append(np.ascontiguousarray(a))
    return {"array": len(arrays) - 1, "scalar": bool(np.ndim(obj) == 0 and not isinstance(
        obj, np.ndarray))}


def _decode(layout, arrays: list):
    if not isinstance(layout, dict) or len(layout) not in (1, 2):
        raise ValueError("malformed layout")
    if "seq" in layout:
        return tuple(_decode(x, arrays) for x in layout["seq"])
    if "dict" in layout:
        return {str(k): _decode(v, arrays) for k, v in layout["dict"]}
    a = arrays[int(layout["array"])]
    return a[()].item() if layout.get("scalar") else a


def arrays_digest(arrays: list[np.ndarray]) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(f"{a.dtype.str}{a.shape};".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


class ChunkStore:
    """The chunk folder of one study (see the module docstring).

    Taking the store takes the folder's lock; `close()` (or the end of a `with` block, or the end
    of the process) releases it.
    """

    def __init__(self, folder: str | Path, manifest: dict, resume: bool, label: str | None = None):
        from filelock import FileLock, Timeout

        self.folder = Path(folder)
        self.label = label or str(self.folder)
        self.manifest = json.loads(canonical(manifest))
        self.hash = study_hash(self.manifest)
        self.resumed = False
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock = FileLock(str(self.folder / LOCK_NAME))
        try:
            self._lock.acquire(timeout=0)
        except Timeout:
            raise ParameterError("--out", "another sewtol run is writing into this folder "
                                 "(it holds the lock); wait for it or choose another folder",
                                 self.label) from None
        try:
            self._open(resume)
        except BaseException:
            self.close()
            raise

    def _open(self, resume: bool) -> None:
        path = self.folder / "manifest.json"
        if path.exists() or path.is_symlink():
            old = read_json(path)  # None for a FIFO, a dangling link or 200 000 "["
            if not resume:
                raise ParameterError("--out", "holds a study already; add --resume to continue "
                                     "it or choose an empty folder", self.label)
            if not isinstance(old, dict):
                raise ParameterError("--resume", "the folder's manifest.json is not a sewtol "
                                     "manifest", self.label)
            if old != self.manifest:
                diff = sorted(k for k in set(old) | set(self.manifest)
                              if old.get(k) != self.manifest.get(k))
                raise ParameterError("--resume", "the folder holds a different study (differs "
                                     f"in {', '.join(diff)})", self.label)
            self.resumed = True
            return
        if not resume and self.done():
            raise ParameterError("--out", "holds chunks of an earlier run; add --resume to "
                                 "check and reuse them, or choose an empty folder", self.label)
        write_text_atomic(path, json.dumps(self.manifest, indent=2, sort_keys=True) + "\n")
        self.resumed = resume and bool(self.done())

    def close(self) -> None:
        if self._lock.is_locked:
            self._lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _path(self, i: int) -> Path:
        return self.folder / f"chunk_{i:05d}.npz"

    def load(self, i: int):
        """(result, None) for a valid chunk i, (None, why) for a missing or rejected one."""
        p = self._path(i)
        try:
            if not p.is_file():
                return None, "missing"
            if p.stat().st_size > MAX_CHUNK_BYTES:
                return None, f"larger than {MAX_CHUNK_BYTES} bytes"
            with zipfile.ZipFile(p) as zf:  # deflated members: small on disk, huge unpacked
                if sum(i.file_size for i in zf.infolist()) > MAX_CHUNK_BYTES:
                    return None, f"unpacks to more than {MAX_CHUNK_BYTES} bytes"
            with np.load(p, allow_pickle=False) as z:
                names = list(z.files)
                if "header" not in names:
                    return None, "no header"
                header = json.loads(bytes(z["header"]).decode("utf-8"))
                count = int(header["arrays"])
                if sorted(names) != sorted(["header"] + [f"a{k}" for k in range(count)]):
                    return None, "unexpected arrays"
                arrays = [z[f"a{k}"] for k in range(count)]
        except Exception as exc:  # any unreadable file is a rejected chunk, never a crash
            return None, f"unreadable ({type(exc).__name__}: {exc})"
        if header.get("format") != FORMAT:
            return None, "not a sewtol chunk of this format"
        if header.get("study") != self.hash:
            return None, "belongs to a different study (study hash differs)"
        if header.get("chunk") != i:
            return None, f"holds chunk {header.get('chunk')!r}, not chunk {i}"
        if header.get("sha256") != arrays_digest(arrays):
            return None, "checksum mismatch (the arrays were changed or damaged)"
        try:
            return _decode(header["layout"], arrays), None
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            return None, f"malformed layout ({exc})"

    def save(self, i: int, result) -> None:
        arrays: list[np.ndarray] = []
        layout = _encode(result, arrays)
        header = {"format": FORMAT, "study": self.hash, "chunk": int(i), "arrays": len(arrays),
                  "layout": layout, "sha256": arrays_digest(arrays)}
        buf = io.BytesIO()
        np.savez(buf, header=np.frombuffer(canonical(header).encode(), np.uint8),
                 **{f"a{k}": a for k, a in enumerate(arrays)})
        write_bytes_atomic(self._path(i), buf.getvalue())

    def done(self) -> list[int]:
        """Indices of the chunk files present (not yet checked)."""
        out = []
        for p in self.folder.glob("chunk_*.npz"):
            digits = p.stem.split("_", 1)[1]
            if digits.isdigit() and p.name == f"chunk_{int(digits):05d}.npz":
                out.append(int(digits))
        return sorted(out)

    def others(self) -> list[str]:
        """Files in the folder that are not ours (never opened)."""
        ours = {"manifest.json", "runs.json", LOCK_NAME} | {self._path(i).name for i in self.done()}
        return sorted(p.name for p in self.folder.iterdir()
                      if p.name not in ours and not p.name.startswith("."))

    def warn(self, i: int, why: str) -> None:
        print(f"sewtol: chunk {i} in {self.label}: {why}; recomputing it", file=sys.stderr)

