"""glTF 2.0 binary files (GLB): the one module that reads and writes their bytes.

- The container: `parse` / `read` split a file into its JSON document and binary
  chunk and say which file is malformed and how; `pack` / `write` lay out the header
  and the chunks (the JSON padded with spaces, the binary with zeros, each to 4
  bytes) with sorted keys, so the same document always gives the same bytes.
- The binary buffer: `Buffer` appends arrays, each in a 4-byte aligned bufferView
  with its accessor; `accessor` reads one back as an array.
- The frame: the pipeline is Z up, glTF is Y up (+Z forward). `Z_TO_Y` is the one
  change of basis, (x, y, z) -> (x, z, -y); `to_y_up` / `to_z_up` move transforms
  across it, `points_to_y_up` / `points_to_z_up` points and directions. Quaternions
  cross here too: the pipeline's (w, x, y, z) (geometry.transform) become glTF's
  (x, y, z, w) in `to_gltf_rotation` and come back in `from_gltf_rotation`.
- Nodes: `node_matrix`, `visual_nodes` (mesh nodes of the default scene with their
  global matrices), `lod_meshes` (MSFT_lod chains) and `instance_transforms`
  (EXT_mesh_gpu_instancing's TRS).

Plain data in and out: a document is the glTF JSON as a dict, a binary is bytes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from .files import atomic_write
from .geometry.transform import matrices_from_quaternions, quaternions_from_matrices

MAGIC = b"glTF"
VERSION = 2
JSON_CHUNK, BIN_CHUNK = 0x4E4F534A, 0x004E4942
_HEADER, _CHUNK = struct.Struct("<4sII"), struct.Struct("<II")

FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, UNSIGNED_SHORT: np.uint16, UNSIGNED_INT: np.uint32,
              FLOAT: np.float32}
_COMPONENT_OF = {np.dtype(dtype).newbyteorder("<"): code for code, dtype in COMPONENTS.items()}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}

# Z up -> Y up: (x, y, z) -> (x, z, -y). A proper rotation, so winding is unchanged.
Z_TO_Y = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
Z_TO_Y.setflags(write=False)


class GlbError(ValueError):
    """A malformed GLB file or accessor: `reason` says what is wrong, `file` where
    (None when the caller names it); the message is `file: reason`."""

    def __init__(self, reason: str, file: str | Path | None = None):
        self.reason, self.file = reason, file
        super().__init__(reason if file is None else f"{file}: {reason}")


# ---------------------------------------------------------------- the container

def parse(data: bytes, name: str | Path = "<bytes>") -> tuple[dict, bytes]:
    """The JSON document and the binary chunk (b"" when there is none) of GLB `data`;
    `name` (the file) heads every error. Chunks of other types are skipped, as the
    specification asks."""
    data = bytes(data)
    if len(data) < _HEADER.size:
        raise GlbError(f"not a GLB file ({len(data)} bytes, shorter than the 12-byte header)", name)
    magic, version, length = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise GlbError(f"not a GLB file (starts with {magic!r}, not b'glTF')", name)
    if version != VERSION:
        raise GlbError(f"GLB version {version}: only glTF 2.0 is read", name)
    if length > len(data):
        raise GlbError(f"truncated GLB: the header says {length} bytes, the file has {len(data)}", name)
    doc, binary, at = None, None, _HEADER.size
    while at < length:
        if at + _CHUNK.size > length:
            raise GlbError(f"truncated GLB: a chunk header at byte {at} runs past the end ({length})", name)
        size, kind = _CHUNK.unpack_from(data, at)
        start = at + _CHUNK.size
        if start + size > length:
            raise GlbError(f"truncated GLB: a {size}-byte chunk at byte {at} runs past the end ({length})", name)
        if kind == JSON_CHUNK and doc is None:
            doc = _document(data[start:start + size], name)
        elif kind == BIN_CHUNK and binary is None:
            binary = data[start:start + size]
        at = start + size + (-size % 4)
    if doc is None:
        raise GlbError("GLB without a JSON chunk", name)
    return doc, binary if binary is not None else b""


def _document(chunk: bytes, name) -> dict:
    try:
        doc = json.loads(chunk.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise GlbError(f"the GLB's JSON chunk is not JSON ({e})", name) from None
    if not isinstance(doc, dict):
        raise GlbError("the GLB's JSON chunk is not an object", name)
    return doc


def read(path: str | Path) -> tuple[dict, bytes]:
    """The JSON document and binary chunk of the GLB file at `path`."""
    return parse(Path(path).read_bytes(), path)


def pack(doc: dict, binary: bytes = b"") -> bytes:
    """GLB bytes of a document and its binary chunk (padded here; none when empty).
    Sorted keys and compact separators make the bytes reproducible."""
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    body = text.encode("utf-8")
    body += b" " * (-len(body) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    chunks = _CHUNK.pack(len(body), JSON_CHUNK) + body
    if binary:
        chunks += _CHUNK.pack(len(binary), BIN_CHUNK) + binary
    return _HEADER.pack(MAGIC, VERSION, _HEADER.size + len(chunks)) + chunks


def write(path: str | Path, doc: dict, binary: bytes = b"") -> int:
    """Write `pack(doc, binary)` to `path` (atomically); returns the bytes written."""
    data = pack(doc, binary)
    atomic_write(path, data)
    return len(data)


def padded_length(binary: bytes) -> int:
    """The length `pack` gives a binary chunk: a buffer's byteLength."""
    return len(binary) + (-len(binary) % 4)


# ---------------------------------------------------------------- the binary buffer

class Buffer:
    """One binary buffer being filled, with the bufferViews and accessors that index it.

    `views` and `accessors` are glTF's dicts; `buffer` is the index every view names
    (None leaves it out, for a caller that places the views in its own buffer later)."""

    def __init__(self, views: list[dict] | None = None, accessors: list[dict] | None = None,
                 binary: bytearray | None = None, buffer: int | None = 0):
        self.binary = bytearray() if binary is None else binary
        self.views = [] if views is None else views
        self.accessors = [] if accessors is None else accessors
        self.buffer = buffer

    def add_view(self, data: bytes, target: int | None = None) -> int:
        """A bufferView of `data` at the next 4-byte boundary; its index."""
        self.binary += b"\0" * (-len(self.binary) % 4)
        view = {} if self.buffer is None else {"buffer": self.buffer}
        view.update(byteOffset=len(self.binary), byteLength=len(data))
        if target is not None:
            view["target"] = target
        self.binary += data
        self.views.append(view)
        return len(self.views) - 1

    def add_accessor(self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        """An accessor of `array` ((count,) or (count, width); float32, uint16 or uint32,
        stored little-endian) in a view of its own; its index. `bounds`: min and max of
        the values as stored, as validators recompute them."""
        array = np.ascontiguousarray(array)
        stored = array.astype(array.dtype.newbyteorder("<"), copy=False)
        acc = {"bufferView": self.add_view(stored.tobytes(), target), "componentType": _COMPONENT_OF[stored.dtype],
               "count": int(len(array)), "type": kind}
        if bounds:
            acc["min"] = [float(c) for c in np.atleast_1d(array.min(axis=0))]
            acc["max"] = [float(c) for c in np.atleast_1d(array.max(axis=0))]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def accessor(doc: dict, buffers, index: int) -> np.ndarray:
    """Accessor `index` as a (count, width) array of its component type (strided
    views gathered, sparse values applied). `buffers`: the binary chunk, or the
    document's buffers' bytes in order. Raises GlbError when the accessor is
    malformed or reads past its view or buffer."""
    buffers = (buffers,) if isinstance(buffers, (bytes, bytearray, memoryview)) else tuple(buffers)
    try:
        a = doc["accessors"][index]
        dtype = np.dtype(COMPONENTS[a["componentType"]])
        width, count = WIDTHS[a["type"]], int(a["count"])
    except (KeyError, IndexError, TypeError) as e:
        raise GlbError(f"accessor {index}: malformed ({e!r})") from None
    if "bufferView" in a:
        data = _view(doc, buffers, a["bufferView"], int(a.get("byteOffset", 0)), dtype, width, count)
    else:
        data = np.zeros((count, width), dtype=dtype)
    if "sparse" in a:
        data = _sparse(doc, buffers, a["sparse"], data, dtype, width)
    return data


def _view(doc: dict, buffers: tuple, view_index: int, offset: int, dtype: np.dtype, width: int,
          count: int) -> np.ndarray:
    try:
        view = doc["bufferViews"][view_index]
        buffer = buffers[view["buffer"]]
    except (KeyError, IndexError, TypeError):
        raise GlbError(f"bufferView {view_index}: missing or names a missing buffer") from None
    item = dtype.itemsize * width
    stride = int(view.get("byteStride", item)) or item
    start = int(view.get("byteOffset", 0)) + offset
    end = start + (stride * (count - 1) + item if count else 0)
    if start < 0 or stride < item or end > int(view.get("byteOffset", 0)) + int(view["byteLength"]) \
            or end > len(buffer):
        raise GlbError(f"bufferView {view_index}: an accessor reads past its end")
    if count == 0:
        return np.zeros((0, width), dtype=dtype)
    raw = np.frombuffer(buffer, dtype=np.uint8, count=end - start, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1))
    return np.ascontiguousarray(rows).view(dtype.newbyteorder("<")).reshape(count, width)


def _sparse(doc: dict, buffers: tuple, sparse: dict, data: np.ndarray, dtype: np.dtype, width: int) -> np.ndarray:
    try:
        n, idx, val = int(sparse["count"]), sparse["indices"], sparse["values"]
        index_type = np.dtype(COMPONENTS[idx["componentType"]])
        indices = _view(doc, buffers, idx["bufferView"], int(idx.get("byteOffset", 0)), index_type, 1, n)
        values = _view(doc, buffers, val["bufferView"], int(val.get("byteOffset", 0)), dtype, width, n)
    except (KeyError, TypeError) as e:
        raise GlbError(f"a sparse accessor is malformed ({e!r})") from None
    indices = indices.ravel().astype(np.int64)
    if n and (indices.min() < 0 or indices.max() >= len(data)):
        raise GlbError("a sparse accessor's index is out of range")
    data = data.copy()
    data[indices] = values
    return data


# ---------------------------------------------------------------- the frame

def to_y_up(m) -> np.ndarray:
    """(..., 4, 4) Z-up transforms as glTF's Y-up ones: C m C^-1."""
    return Z_TO_Y @ np.asarray(m, dtype=np.float64) @ Z_TO_Y.T


def to_z_up(m) -> np.ndarray:
    """(..., 4, 4) glTF Y-up transforms back in the pipeline's Z-up frame: C^-1 m C."""
    return Z_TO_Y.T @ np.asarray(m, dtype=np.float64) @ Z_TO_Y


def points_to_y_up(points) -> np.ndarray:
    """(n, 3) float64 Z-up points (or directions) in glTF's Y-up frame."""
    return np.asarray(points, dtype=np.float64) @ Z_TO_Y[:3, :3].T


def points_to_z_up(points) -> np.ndarray:
    """(n, 3) float64 glTF Y-up points (or directions) in the pipeline's Z-up frame."""
    return np.asarray(points, dtype=np.float64) @ Z_TO_Y[:3, :3]


def to_gltf_rotation(q) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z) in glTF's order (x, y, z, w)."""
    return np.asarray(q)[..., [1, 2, 3, 0]]


def from_gltf_rotation(q) -> np.ndarray:
    """(..., 4) glTF quaternions (x, y, z, w) in the pipeline's order (w, x, y, z)."""
    return np.asarray(q, dtype=np.float64)[..., [3, 0, 1, 2]]


# ---------------------------------------------------------------- nodes

def texture_refs(node, out: list[dict]) -> None:
    """Every {"index": ...} texture reference inside a material (its textureInfos, those
    of its extensions included), in document order, appended to `out`."""
    if isinstance(node, dict):
        for k in sorted(node):
            v = node[k]
            if k.endswith("Texture") and isinstance(v, dict) and "index" in v:
                out.append(v)
            texture_refs(v, out)
    elif isinstance(node, list):
        for v in node:
            texture_refs(v, out)


def instance_transforms(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(translations (k, 3), rotations (k, 4) glTF's x, y, z, w, scales (k, 3)) float32
    of `matrices: (k, 4, 4)`, for EXT_mesh_gpu_instancing: computed for every
    instanced node of a scene at once, not node by node."""
    m = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    scale = np.linalg.norm(m[:, :3, :3], axis=1)  # (k, 3): the length of each column
    rotation = to_gltf_rotation(quaternions_from_matrices(m[:, :3, :3] / scale[:, None, :]))
    return m[:, :3, 3].astype(np.float32), rotation.astype(np.float32), scale.astype(np.float32)


def node_matrix(node: dict) -> np.ndarray:
    """(4, 4) float64 local transform of a glTF node: its `matrix` (column-major), or
    translation @ rotation @ scale."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    if "scale" in node:
        m = np.diag([*node["scale"], 1.0]) @ m
    if "rotation" in node:
        r = np.eye(4)
        r[:3, :3] = matrices_from_quaternions(from_gltf_rotation(node["rotation"]))[0]
        m = r @ m
    if "translation" in node:
        t = np.eye(4)
        t[:3, 3] = node["translation"]
        m = t @ m
    return m


def visual_nodes(doc: dict) -> list[tuple[int, np.ndarray]]:
    """(node index, global matrix) of every mesh node reachable from the default scene."""
    out = []
    scene = doc["scenes"][doc.get("scene", 0)]

    def walk(i, parent):
        node = doc["nodes"][i]
        m = parent @ node_matrix(node)
        if "mesh" in node:
            out.append((i, m))
        for c in node.get("children", []):
            walk(c, m)

    for root in scene["nodes"]:
        walk(root, np.eye(4))
    return out


def lod_meshes(doc: dict, node_index: int) -> list[int]:
    """Mesh indices of a visual node's LOD chain: its own, then MSFT_lod's nodes."""
    node = doc["nodes"][node_index]
    chain = [node["mesh"]]
    for i in node.get("extensions", {}).get("MSFT_lod", {}).get("ids", []):
        chain.append(doc["nodes"][i]["mesh"])
    return chain


def scene_nodes_only(doc: dict) -> dict:
    """A copy of `doc` with only the nodes its scenes reach, in their order, renumbered:
    MSFT_lod's lower levels (nodes outside every scene) go, and the extension with
    them. Blender's importer makes an object of every node, in a scene or not, and
    building the lower levels' meshes is most of an import. A document whose
    animations or skins name nodes comes back unchanged."""
    if doc.get("animations") or doc.get("skins"):
        return doc
    reached: set[int] = set()
    pending = [r for scene in doc.get("scenes", []) for r in scene.get("nodes", [])]
    while pending:
        i = pending.pop()
        if i not in reached:
            reached.add(i)
            pending.extend(doc["nodes"][i].get("children", []))
    # kept in their order: the importer makes the same objects in the same order
    index = {i: k for k, i in enumerate(sorted(reached))}
    nodes = []
    for i in sorted(reached):
        node = {k: v for k, v in doc["nodes"][i].items() if k != "extensions"}
        extensions = {k: v for k, v in doc["nodes"][i].get("extensions", {}).items() if k != "MSFT_lod"}
        if extensions:
            node["extensions"] = extensions
        if "children" in node:
            node["children"] = [index[c] for c in node["children"]]
        nodes.append(node)
    out = {**doc, "nodes": nodes,
           "scenes": [{**s, "nodes": [index[r] for r in s.get("nodes", [])]} for s in doc.get("scenes", [])]}
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in out:
            kept = [e for e in out[key] if e != "MSFT_lod"]
            if kept:
                out[key] = kept
            else:
                del out[key]
    return out
