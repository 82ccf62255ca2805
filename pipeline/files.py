"""Writing files so that a reader never sees half of one.

Every output is written under a temporary name beside its final one and renamed into
place: a rename within one folder is atomic, so a killed build, a crashed worker or
a reader racing a writer sees the old file or the new one, never a torn one. The
temporary name is unique per call, so two processes writing the same file race only
for which rename lands last.
"""

from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


def _temporary(path: Path) -> Path:
    # the suffix is kept: some writers (USD's) pick the format from the extension
    return path.with_name(f".{path.stem}.tmp-{uuid.uuid4().hex[:8]}{path.suffix}")


@contextmanager
def atomic_path(path: str | Path, *, parents: bool = True) -> Iterator[Path]:
    """A temporary path for a writer that wants a file name (USD's Export, an image
    library); renamed to `path` when the block ends without an exception, removed
    when it raises."""
    path = Path(path)
    if parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write(path: str | Path, data: bytes | str, *, parents: bool = True) -> Path:
    """Write `data` (text is UTF-8) to `path` through a temporary file; returns `path`."""
    path = Path(path)
    payload = data.encode() if isinstance(data, str) else data
    with atomic_path(path, parents=parents) as tmp:
        tmp.write_bytes(payload)
    return path
