"""Results of steps inside a task, kept between builds by content (the LOD search's
levels, the per-mesh checks' findings, the package's COLLADA files): a task that
reruns finds there the parts of its work whose inputs did not change. A memo only
spares work: what it returns is what the step would compute, so a task's outputs
are the same with an empty memo, a full one or none.

Entries live under the hash of the step's key and the code version the caller names
(its namespace), so new code never reads an old entry. Each is made under a
temporary name in the cache's root (which `Cache.clean_tmp` sweeps) and renamed into
place: a killed build leaves whole entries or none.

- ArrayMemo: .npz files of plain arrays, read without pickles. An entry that cannot
  be read is a miss, and the step's result, computed again, replaces it.
- FileMemo: files a step wrote, kept as hard links to them (see there).
"""

from __future__ import annotations

import hashlib
import io
import os
import uuid
import zipfile
from pathlib import Path

import numpy as np

from .cache import MEMO_FOLDER


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
        _used(self.path(key))
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


class FileMemo:
    """Files a step wrote, by content key: a step about to write the same bytes again
    links the kept file into place instead of making it. Entries are hard links to
    the files as written, so they take no room of their own (the cache entry that
    got the written file shares it) and stay whole when that entry goes. Nothing
    writes into a kept file: staged files are moved into the cache, which copies
    them out to the build folder. Where a link cannot be made (a cache on another
    filesystem than the build folder), nothing is kept and every file is written."""

    def __init__(self, cache_root: Path, namespace: str):
        self.root = Path(cache_root)
        self.namespace = namespace
        self.hits = self.puts = 0

    def path(self, key: str) -> Path:
        name = hashlib.sha256(f"{self.namespace}\0{key}".encode()).hexdigest()
        return self.root / MEMO_FOLDER / name[:2] / name

    def link(self, key: str, dest: Path) -> bool:
        """Make `dest` (which must not exist) the file kept under `key`; False when
        none is kept (or it cannot be linked there), and the caller writes it."""
        try:
            os.link(self.path(key), dest)
        except OSError:
            return False
        self.hits += 1
        _used(self.path(key))
        return True

    def keep(self, key: str, written: Path) -> None:
        """Keep the complete file `written` under `key`."""
        self.puts += 1
        final = self.path(key)
        tmp = self.root / f".tmp-{uuid.uuid4().hex}"
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            os.link(written, tmp)
            os.replace(tmp, final)
        except OSError:  # another filesystem, a read-only or full cache: nothing kept
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass


def _used(path: Path) -> None:
    """An entry's mtime is its last use: the cache's pruning keeps what is used."""
    try:
        os.utime(path)
    except OSError:
        pass
