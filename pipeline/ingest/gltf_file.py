"""glTF 2.0 files as plain data: the JSON header, the buffers, accessors as arrays.

trimesh reads a glTF's meshes, materials and node tree; this module gives the readers
what it leaves out: morph targets and their default weights, the animations and skins a
file holds (ingest.mesh), and the per-triangle B-rep face indices cascadio writes
(ingest.tessellate). The file is untrusted: a buffer is the GLB's own chunk, a data:
URI, or a file inside the glTF's folder; never another path, never the network.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np

COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942


class GltfError(ValueError):
    """The file is not the glTF it says it is (the message says where)."""


@dataclass(frozen=True)
class Gltf:
    header: dict
    buffers: tuple[bytes, ...]

    def accessor(self, index: int) -> np.ndarray:
        """Accessor `index` as a (count, width) array: float64 for floats and
        normalized integers, int64 for the rest; sparse values applied."""
        try:
            a = self.header["accessors"][index]
            dtype = np.dtype(COMPONENTS[a["componentType"]])
            width, count = WIDTHS[a["type"]], int(a["count"])
        except (KeyError, IndexError, TypeError) as e:
            raise GltfError(f"accessor {index}: malformed ({e!r})") from None
        if "bufferView" in a:
            data = self._view(a["bufferView"], int(a.get("byteOffset", 0)), dtype, width, count)
        else:
            data = np.zeros((count, width), dtype=dtype)
        if "sparse" in a:
            data = self._sparse(a["sparse"], data, dtype, width)
        if dtype.kind == "f":
            return data.astype(np.float64)
        if a.get("normalized"):
            return np.maximum(data.astype(np.float64) / np.iinfo(dtype).max, -1.0)
        return data.astype(np.int64)

    def _view(self, view_index: int, offset: int, dtype: np.dtype, width: int, count: int) -> np.ndarray:
        try:
            view = self.header["bufferViews"][view_index]
            buffer = self.buffers[view["buffer"]]
        except (KeyError, IndexError, TypeError):
            raise GltfError(f"bufferView {view_index}: missing or names a missing buffer") from None
        item = dtype.itemsize * width
        stride = int(view.get("byteStride", item)) or item
        start = int(view.get("byteOffset", 0)) + offset
        end = start + (stride * (count - 1) + item if count else 0)
        if start < 0 or stride < item or end > int(view.get("byteOffset", 0)) + int(view["byteLength"]) \
                or end > len(buffer):
            raise GltfError(f"bufferView {view_index}: an accessor reads past its end")
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        raw = np.frombuffer(buffer, dtype=np.uint8, count=end - start, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def _sparse(self, sparse: dict, data: np.ndarray, dtype: np.dtype, width: int) -> np.ndarray:
        n = int(sparse["count"])
        idx = sparse["indices"]
        indices = self._view(idx["bufferView"], int(idx.get("byteOffset", 0)),
                             np.dtype(COMPONENTS[idx["componentType"]]), 1, n).ravel().astype(np.int64)
        val = sparse["values"]
        values = self._view(val["bufferView"], int(val.get("byteOffset", 0)), dtype, width, n)
        if n and (indices.min() < 0 or indices.max() >= len(data)):
            raise GltfError("a sparse accessor's index is out of range")
        data = data.copy()
        data[indices] = values
        return data


def inside(folder: Path, uri: str) -> Path | None:
    """The file a relative URI names when it stays inside `folder`, else None."""
    if ":" in uri or uri.startswith(("/", "\\")):
        return None
    target = (folder / unquote(uri)).resolve()
    root = folder.resolve()
    return target if target == root or root in target.parents else None


def _data_uri(uri: str) -> bytes:
    head, _, payload = uri.partition(",")
    if not head.endswith(";base64"):
        raise GltfError("a data: URI that is not base64")
    return base64.b64decode(payload, validate=False)


def _glb(data: bytes) -> tuple[dict, bytes | None]:
    if len(data) < 20 or data[:4] != b"glTF":
        raise GltfError("not a GLB file (no glTF header)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise GltfError(f"GLB version {version}: only glTF 2.0 is read")
    header, binary, at = None, None, 12
    while at + 8 <= min(length, len(data)):
        size, kind = struct.unpack_from("<II", data, at)
        chunk = data[at + 8:at + 8 + size]
        if kind == _JSON_CHUNK and header is None:
            header = json.loads(chunk)
        elif kind == _BIN_CHUNK and binary is None:
            binary = bytes(chunk)
        at += 8 + size + (-size % 4)
    if header is None:
        raise GltfError("GLB without a JSON chunk")
    return header, binary


def read(path: Path) -> Gltf:
    """The glTF (.gltf or .glb) at `path` with its buffers loaded."""
    path = Path(path)
    data = path.read_bytes()
    try:
        if data[:4] == b"glTF":
            header, binary = _glb(data)
        else:
            header, binary = json.loads(data), None
    except (ValueError, UnicodeDecodeError) as e:
        raise GltfError(f"not glTF JSON: {e}") from None
    if not isinstance(header, dict):
        raise GltfError("the glTF JSON is not an object")
    buffers = []
    for i, b in enumerate(header.get("buffers", [])):
        uri = b.get("uri") if isinstance(b, dict) else None
        if uri is None:
            if binary is None:
                raise GltfError(f"buffer {i} has no uri and the file no binary chunk")
            buffers.append(binary)
        elif uri.startswith("data:"):
            buffers.append(_data_uri(uri))
        else:
            target = inside(path.parent, uri)
            if target is None:
                raise GltfError(f"buffer {i} uri {uri!r} leaves the file's folder (refused)")
            if not target.is_file():
                raise GltfError(f"buffer {i} file {uri!r} not found beside the file")
            buffers.append(target.read_bytes())
    return Gltf(header, tuple(buffers))
