"""Results of steps inside a task, kept between builds by content (the LOD search's
levels, the per-mesh checks' findings, the package's COLLADA files): a task that
reruns finds there the parts of its work whose inputs did not change. A memo only
spares work: what it returns is what the step would compute, so a task's outputs
are the same with an empty memo, a full one or none.

Entries live under the hash of the step's key and the code version the caller names
(its namespace), so new code never reads an old entry. Each is made under a
temporary name beside its place and renamed into it (files.atomic_path): a killed
build leaves whole entries or none, and a temporary it left is a memo file like any
other to the cache's prune.

- ArrayMemo: plain arrays (numbers, booleans, fixed-width text) in a file of their
  own layout (below), read without pickles. An entry that cannot be read is a miss,
  and the step's result, computed again, replaces it.
- FileMemo: files a step wrote, kept as hard links to them (see there).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Callable

import numpy as np

from ..files import atomic_path
from .cache import MEMO_FOLDER, add_usage


class _Memo:
    """Entries under the hash of (namespace, key), counted: what a task reports as
    reused (hits) and computed (puts)."""

    suffix = ""

    def __init__(self, cache_root: Path, namespace: str):
        self.root = Path(cache_root)
        self.namespace = namespace
        self.hits = self.puts = 0

    def path(self, key: str) -> Path:
        name = hashlib.sha256(f"{self.namespace}\0{key}".encode()).hexdigest()
        return self.root / MEMO_FOLDER / name[:2] / f"{name}{self.suffix}"

    def _place(self, final: Path, make: Callable[[Path], None]) -> None:
        """final <- what `make(tmp)` makes at a temporary name beside it; nothing
        when the cache cannot be written (read-only, full, another filesystem, a
        file in its place): the memo only spares work."""
        try:
            with atomic_path(final) as tmp:
                make(tmp)
                size = tmp.stat().st_size
            add_usage(self.root, size)
        except OSError:
            pass


class ArrayMemo(_Memo):
    """Each entry one file: MAGIC, the header's length (8 bytes, little-endian), the
    header (JSON: [name, dtype, shape] per array) and the arrays' bytes in that order.
    An edit's geometry and package tasks read hundreds of entries, so an entry is read
    without parsing (numpy parses an .npz file's headers with ast)."""

    suffix = ".arrays"
    MAGIC = b"TWINARR1"

    def get(self, key: str) -> dict[str, np.ndarray] | None:
        path = self.path(key)
        try:
            arrays = _unpack(bytearray(path.read_bytes()), self.MAGIC)
        except (OSError, ValueError, TypeError, KeyError, IndexError):
            return None
        self.hits += 1
        _used(path)
        return arrays

    def put(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        self.puts += 1
        parts = {name: np.ascontiguousarray(a) for name, a in arrays.items()}
        if any(a.dtype.kind not in _PLAIN for a in parts.values()):
            return  # objects would be pickles: nothing is kept, the step computes again
        header = json.dumps([[name, a.dtype.str, list(a.shape)] for name, a in parts.items()]).encode()
        data = b"".join([self.MAGIC, len(header).to_bytes(8, "little"), header] + [a.tobytes() for a in parts.values()])
        self._place(self.path(key), lambda tmp: tmp.write_bytes(data))


_PLAIN = "biufU"  # dtype kinds an entry holds: numbers, booleans, fixed-width text


def _unpack(data: bytearray, magic: bytes) -> dict[str, np.ndarray]:
    """ArrayMemo's layout read back; ValueError for anything that does not fit it
    (plain arrays only: nothing in an entry becomes an object)."""
    if data[:len(magic)] != magic:
        raise ValueError("not an array memo entry")
    start = len(magic) + 8
    end = start + int.from_bytes(data[len(magic):start], "little")
    offset, arrays = end, {}
    for name, dtype, shape in json.loads(bytes(data[start:end])):
        dtype = np.dtype(dtype)
        if dtype.kind not in _PLAIN or any(not isinstance(n, int) or n < 0 for n in shape):
            raise ValueError(f"array {name!r}: {dtype}, {shape}")
        count = int(np.prod(shape, dtype=np.int64))
        arrays[str(name)] = np.frombuffer(data, dtype, count, offset).reshape(shape)
        offset += count * dtype.itemsize
    if offset != len(data):
        raise ValueError("array memo entry of the wrong length")
    return arrays


class FileMemo(_Memo):
    """Files a step wrote, by content key: a step about to write the same bytes again
    links the kept file into place instead of making it. Entries are hard links to
    the files as written, so they take no room of their own (the cache entry that
    got the written file shares it) and stay whole when that entry goes. Nothing
    writes into a kept file: staged files are moved into the cache, which copies
    them out to the build folder. Where a link cannot be made (a cache on another
    filesystem than the build folder), nothing is kept and every file is written."""

    def link(self, key: str, dest: Path) -> bool:
        """Make `dest` (which must not exist) the file kept under `key`; False when
        none is kept (or it cannot be linked there), and the caller writes it."""
        path = self.path(key)
        try:
            os.link(path, dest)
        except OSError:
            return False
        self.hits += 1
        _used(path)
        return True

    def keep(self, key: str, written: Path) -> None:
        """Keep the complete file `written` under `key`."""
        self.puts += 1
        self._place(self.path(key), lambda tmp: os.link(written, tmp))


def _used(path: Path) -> None:
    """An entry's mtime is its last use: the cache's pruning keeps what is used."""
    try:
        os.utime(path)
    except OSError:
        pass
