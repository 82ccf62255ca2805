"""Results of steps inside a task, kept between builds by content (the LOD search's
levels): a task that reruns finds there the parts of its work whose inputs did not
change. A memo only spares work: what it returns is what the step would compute,
so a task's outputs are the same with an empty memo, a full one or none.

Entries are .npz files of plain arrays (read without pickles), under the hash of
the step's key and the code version of the task that keeps them, so new code never
reads an old entry. Each is written to a temporary name in the cache's root (which
`Cache.clean_tmp` sweeps) and renamed into place: a killed build leaves whole
entries or none. An entry that cannot be read is a miss, and the step's result,
computed again, replaces it.
"""

from __future__ import annotations

import hashlib
import io
import os
import uuid
import zipfile
from pathlib import Path

import numpy as np

MEMO_FOLDER = "memo"


class ArrayMemo:
    def __init__(self, cache_root: Path, namespace: str):
        self.root = Path(cache_root)
        self.namespace = namespace
        self.hits = self.puts = 0  # reported by the task: what it reused, what it computed

    def path(self, key: str) -> Path:
        name = hashlib.sha256(f"{self.namespace}\0{key}".encode()).hexdigest()
        return self.root / MEMO_FOLDER / name[:2] / f"{name}.npz"

    def get(self, key: str) -> dict[str, np.ndarray] | None:
        try:
            data = self.path(key).read_bytes()
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
            return None
        self.hits += 1
        return arrays

    def put(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        self.puts += 1
        final = self.path(key)
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        tmp = self.root / f".tmp-{uuid.uuid4().hex}.npz"
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(buffer.getvalue())
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, final)
        except OSError:  # a read-only, full or misplaced cache: the memo only spares work
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
