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
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from .. import glb


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
            data = glb.accessor(self.header, self.buffers, index)
        except glb.GlbError as e:
            raise GltfError(e.reason) from None
        if data.dtype.kind == "f":
            return data.astype(np.float64)
        if self.header["accessors"][index].get("normalized"):
            return np.maximum(data.astype(np.float64) / np.iinfo(data.dtype).max, -1.0)
        return data.astype(np.int64)


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


def read(path: Path, open_file=None) -> Gltf:
    """The glTF (.gltf or .glb) at `path` with its buffers loaded. `open_file(uri)`:
    how a buffer file beside it is read (ingest.images.SourceFiles.read: capped and
    recorded), else directly."""
    path = Path(path)
    data = path.read_bytes()
    if data[:4] == glb.MAGIC:
        try:
            header, binary = glb.parse(data, path)
        except glb.GlbError as e:
            raise GltfError(e.reason) from None
    else:
        try:
            header, binary = json.loads(data), None
        except (ValueError, UnicodeDecodeError) as e:
            raise GltfError(f"not glTF JSON: {e}") from None
    if not isinstance(header, dict):
        raise GltfError("the glTF JSON is not an object")
    buffers = []
    for i, b in enumerate(header.get("buffers", [])):
        uri = b.get("uri") if isinstance(b, dict) else None
        if uri is None:
            if not binary:
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
            try:
                buffers.append(open_file(uri) if open_file is not None else target.read_bytes())
            except OSError as e:
                raise GltfError(f"buffer {i} file {uri!r}: {e}") from None
    return Gltf(header, tuple(buffers))
