"""Checkpoints of a chunked study: each finished chunk is saved at once, atomically, so an
interrupted study keeps its finished part and `--resume` continues without recomputing it.

The folder holds manifest.json (what the study is: everything that decides its numbers) and
chunk_NNNNN.pkl files. Resuming into a folder whose manifest differs is refused, so chunks of
two different studies are never mixed.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

from ..errors import ParameterError
from ..io import write_bytes_atomic, write_text_atomic


class ChunkStore:
    def __init__(self, folder: str | Path, manifest: dict, resume: bool, label: str | None = None):
        self.folder = Path(folder)
        label = label or str(self.folder)
        self.manifest = json.loads(json.dumps(manifest, sort_keys=True, default=str))
        path = self.folder / "manifest.json"
        if path.exists():
            old = json.loads(path.read_text())
            if not resume:
                raise ParameterError("--out", "holds a study already; add --resume to continue "
                                     "it or choose an empty folder", label)
            if old != self.manifest:
                diff = sorted(k for k in set(old) | set(self.manifest)
                              if old.get(k) != self.manifest.get(k))
                raise ParameterError("--resume", "the folder holds a different study (differs "
                                     f"in {', '.join(diff)})", label)
        else:
            write_text_atomic(path, json.dumps(self.manifest, indent=2, sort_keys=True) + "\n")

    def _path(self, i: int) -> Path:
        return self.folder / f"chunk_{i:05d}.pkl"

    def load(self, i: int):
        p = self._path(i)
        if not p.exists():
            return None
        return pickle.loads(p.read_bytes())

    def save(self, i: int, result) -> None:
        write_bytes_atomic(self._path(i), pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))

    def done(self) -> list[int]:
        return sorted(int(p.stem.split("_")[1]) for p in self.folder.glob("chunk_*.pkl"))
