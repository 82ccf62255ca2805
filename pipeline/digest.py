"""Content digests: task keys (builder), cache entries, and the output list of a
package manifest all name a file by the same sha256; memo and dedup keys name
arrays and JSON-able data the same way."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

HASH_CHUNK = 1 << 20


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def sha256_arrays(*arrays) -> str:
    """One hash of numpy arrays (dtype, shape and bytes each; None has its own mark)."""
    import numpy as np

    h = hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"none;")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape};".encode())
        h.update(a.data)  # the buffer itself: no copy of a mesh's megabytes
    return h.hexdigest()


def sha256_json(data) -> str:
    """A hash of JSON-able data: sorted keys, compact, repr for what JSON lacks (a
    TOML date), NaN spelled as such."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text.encode()).hexdigest()
