"""ir.Asset on disk: what the source task hands to the geometry task, and the geometry
task to the package task.

One file: MAGIC, the header's length (uint64, little-endian), a JSON header, then the
arrays' raw bytes, each at an 8-aligned offset the header gives. The header is the
asset's dataclass tree with every array replaced by {"$array": i}; reading it builds
only the ir classes and dtypes listed below, so a file from a shared cache can hold
data but never code (no pickle). Floats are written as repr, so they come back exact,
and the same asset always gives the same bytes.
"""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import numpy as np

from .. import ir
from ..errors import UserError

MAGIC = b"TWINIR\x00\x01"
_ALIGN = 8
_CLASSES = {c.__name__: c for c in (ir.ShapeKey, ir.Mesh, ir.Texture, ir.Material, ir.Visual, ir.Collision,
                                    ir.Link, ir.Joint, ir.StateBinding, ir.LodInfo, ir.Asset)}
_DTYPES = ("<f8", "<f4", "<i4", "<i8", "|u1", "|b1")


def dumps(asset: ir.Asset, extra: dict | None = None) -> bytes:
    """The file's bytes for `asset`; `extra`: JSON data kept beside it."""
    arrays: list[np.ndarray] = []
    tree = _encode(asset, arrays)
    blobs, table, offset = [], [], 0
    for a in arrays:
        a = np.ascontiguousarray(a)
        if a.dtype.str not in _DTYPES:
            a = a.astype(a.dtype.newbyteorder("<"))
        data = a.tobytes()
        table.append({"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset})
        pad = -len(data) % _ALIGN
        blobs.append(data + b"\0" * pad)
        offset += len(data) + pad
    header = json.dumps({"asset": tree, "arrays": table, "extra": extra or {}}, sort_keys=True,
                        separators=(",", ":")).encode()
    header += b" " * (-(len(MAGIC) + 8 + len(header)) % _ALIGN)
    return MAGIC + struct.pack("<Q", len(header)) + header + b"".join(blobs)


def write(path: Path, asset: ir.Asset, extra: dict | None = None) -> None:
    """The asset's source is kept by its file name: the file is then the same bytes
    wherever the sources sit (a moved sources folder is a cut-off, not a rebuild), and
    a reader puts the path back (`read`'s `source`)."""
    if asset.source:
        asset = dataclasses.replace(asset, source=Path(asset.source).name)
    Path(path).write_bytes(dumps(asset, extra))


def read(path: Path, source: Path | None = None) -> tuple[ir.Asset, dict]:
    """(asset, extra) from a file `write` made; a damaged file is a UserError.
    `source`: the asset's source file as it is now (what its errors name)."""
    path = Path(path)
    data = path.read_bytes()
    try:
        asset, extra = loads(data)
    except (ValueError, KeyError, TypeError, struct.error) as e:
        raise UserError(path, None, f"not a readable asset file ({e})") from None
    if source is not None:
        asset = dataclasses.replace(asset, source=str(source))
    return asset, extra


def loads(data: bytes) -> tuple[ir.Asset, dict]:
    if data[:len(MAGIC)] != MAGIC:
        raise ValueError("bad magic")
    (n,) = struct.unpack_from("<Q", data, len(MAGIC))
    start = len(MAGIC) + 8
    header = json.loads(data[start:start + n])
    body = memoryview(data)[start + n:]
    arrays = []
    for spec in header["arrays"]:
        if spec["dtype"] not in _DTYPES:
            raise ValueError(f"dtype {spec['dtype']!r} not allowed")
        dtype = np.dtype(spec["dtype"])
        shape = tuple(int(s) for s in spec["shape"])
        count = int(np.prod(shape, dtype=np.int64))
        arrays.append(np.frombuffer(body, dtype=dtype, count=count, offset=int(spec["offset"])).reshape(shape))
    asset = _decode(header["asset"], arrays)
    if not isinstance(asset, ir.Asset):
        raise ValueError("no asset at the root")
    return asset, header["extra"]


# Fields added after files were written: left out while empty, so an asset without
# them keeps its file's bytes (and the tasks downstream their cache entries).
_LATER = {("Asset", "terminals")}


def _encode(x, arrays: list):
    if dataclasses.is_dataclass(x):
        out = {"$": type(x).__name__}
        for f in dataclasses.fields(x):
            value = getattr(x, f.name)
            if (type(x).__name__, f.name) in _LATER and not value:
                continue
            out[f.name] = _encode(value, arrays)
        return out
    if isinstance(x, np.ndarray):
        arrays.append(x)
        return {"$array": len(arrays) - 1}
    if isinstance(x, bytes):  # a texture's image: raw bytes beside the arrays
        arrays.append(np.frombuffer(x, dtype=np.uint8))
        return {"$bytes": len(arrays) - 1}
    if isinstance(x, (list, tuple)):
        return [_encode(v, arrays) for v in x]
    if isinstance(x, dict):
        return {"$map": [[str(k), _encode(v, arrays)] for k, v in sorted(x.items())]}
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x)
    if x is None or isinstance(x, str):
        return x
    raise TypeError(f"cannot store {type(x).__name__}")


def _decode(x, arrays: list):
    if isinstance(x, list):
        return tuple(_decode(v, arrays) for v in x)  # the ir keeps sequences as tuples
    if isinstance(x, dict):
        if "$array" in x:
            return arrays[int(x["$array"])]
        if "$bytes" in x:
            return arrays[int(x["$bytes"])].tobytes()
        if "$map" in x:
            return {k: _decode(v, arrays) for k, v in x["$map"]}
        cls = _CLASSES[x["$"]]
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: _decode(v, arrays) for k, v in x.items() if k != "$" and k in names})
    return x
