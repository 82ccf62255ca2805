"""One model at one LOD level as the tiles store it: a "pack".

A pack is the model's visuals at that level baked into the model frame (each visual's
node transform applied to its vertices, the default morph weights applied) and merged
into one primitive per material, so a tile draws a placed model with one instanced
node and as few draw calls as it has materials. Its vertex data is one binary file
that every tile showing the model at that level references (glTF external buffers),
so a tileset stores each mesh once however many tiles place it.

Layout: `Pack.binary` holds, per merged primitive, its indices then its attributes,
each at a 4-byte boundary; `views` and `accessors` index into it (the tile gives the
views their buffer), `primitives` reference those accessors and the pack's own
`materials`, textures, images and samplers. An image is a file of its own named by
its content (`image_file`), which every level and every model that samples it
references: the tiles store each image once.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import numpy as np

from .. import glb

_KEPT = ("POSITION", "NORMAL", "TEXCOORD_0", "TEXCOORD_1")  # attributes a tile keeps
_TRIANGLES = 4
IMAGES = "images"  # the folder of the image files, beside the packs' meshes/
_SUFFIX = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp"}


def image_file(data: bytes, mime: str) -> str:
    """Where an image is kept, relative to tiles/: named by its content."""
    return f"{IMAGES}/{hashlib.sha256(data).hexdigest()[:24]}{_SUFFIX.get(mime, '.bin')}"


@dataclass
class Pack:
    """One model at one level, baked and merged (see the module docstring).

    hull: (h, 3) float64 points of the merged mesh in the model's Z-up frame whose
    convex hull is the mesh's (the bounding volumes transform these). binary: None
    for a pack recalled from the memo (its file is linked into place instead)."""

    asset: str
    level: int
    binary: bytes | None
    views: list[dict]
    accessors: list[dict]
    primitives: list[dict]
    materials: list[dict]
    textures: list[dict] = field(default_factory=list)
    images: list[dict] = field(default_factory=list)
    samplers: list[dict] = field(default_factory=list)
    variants: list[str] = field(default_factory=list)
    hull: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    triangles: int = 0
    stored_length: int = 0  # the binary's length where it is kept elsewhere (binary None)
    image_data: dict[str, bytes] = field(default_factory=dict)  # image_file -> bytes; empty when recalled

    @property
    def byte_length(self) -> int:
        return len(self.binary) if self.binary is not None else self.stored_length

    _META = ("asset", "level", "views", "accessors", "primitives", "materials", "textures", "images", "samplers",
             "variants", "triangles")

    @property
    def image_files(self) -> list[str]:
        """The image files (relative to tiles/) the pack's images name."""
        return sorted({im["uri"] for im in self.images if "uri" in im and not im["uri"].startswith("data:")})

    def arrays(self) -> dict[str, np.ndarray]:
        """The pack but its binary, as plain arrays (a builder ArrayMemo entry)."""
        meta = {k: getattr(self, k) for k in self._META}
        meta["stored_length"] = self.byte_length
        return {"meta": np.array(json.dumps(meta, sort_keys=True)), "hull": np.asarray(self.hull, dtype=np.float64)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "Pack":
        """The pack `arrays` made, without its binary (kept as a file of its own)."""
        meta = json.loads(np.asarray(arrays["meta"]).reshape(-1)[0])
        return cls(binary=None, hull=np.array(arrays["hull"], dtype=np.float64).reshape(-1, 3), **meta)


def _baked(doc: dict, binary: bytes, mesh_index: int, matrix: np.ndarray) -> list[dict]:
    """The triangle primitives of a mesh with `matrix` (Y-up, the visual's global
    transform) applied: [{"key", "attributes": {name: array}, "indices"}]."""
    mesh = doc["meshes"][mesh_index]
    weights = mesh.get("weights") or []
    m3 = matrix[:3, :3]
    normal_m = m3 if np.allclose(m3.T @ m3, np.eye(3), atol=1e-9) else np.linalg.inv(m3).T
    flip = np.linalg.det(m3) < 0
    out = []
    for p in mesh["primitives"]:
        if p.get("mode", _TRIANGLES) != _TRIANGLES:
            continue
        attrs = {name: glb.accessor(doc, binary, i).astype(np.float64) for name, i in sorted(p["attributes"].items())
                 if name in _KEPT and doc["accessors"][i]["componentType"] == glb.FLOAT}
        for w, target in zip(weights, p.get("targets", [])):
            for name in ("POSITION", "NORMAL"):
                if w and name in target and name in attrs:
                    attrs[name] = attrs[name] + w * glb.accessor(doc, binary, target[name])
        attrs["POSITION"] = attrs["POSITION"] @ m3.T + matrix[:3, 3]
        if "NORMAL" in attrs:
            n = attrs["NORMAL"] @ normal_m.T
            length = np.linalg.norm(n, axis=1, keepdims=True)
            attrs["NORMAL"] = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        count = len(attrs["POSITION"])
        faces = (glb.accessor(doc, binary, p["indices"]) if "indices" in p else np.arange(count)).astype(np.int64)
        faces = faces[: len(faces) // 3 * 3].reshape(-1, 3)
        if flip:
            faces = faces[:, ::-1]
        mappings = p.get("extensions", {}).get("KHR_materials_variants", {}).get("mappings", [])
        key = (p.get("material", -1), tuple(sorted(attrs)), json.dumps(mappings, sort_keys=True))
        out.append({"key": key, "attributes": attrs, "faces": faces, "mappings": mappings})
    return out


def _merged(parts: list[dict]) -> list[dict]:
    """Primitives of one key concatenated, in the order of first appearance."""
    groups: dict[tuple, list[dict]] = {}
    for part in parts:
        groups.setdefault(part["key"], []).append(part)
    merged = []
    for key, members in groups.items():
        offsets = np.cumsum([0] + [len(m["attributes"]["POSITION"]) for m in members])
        merged.append({
            "material": key[0], "mappings": members[0]["mappings"],
            "attributes": {name: np.concatenate([m["attributes"][name] for m in members]) for name in key[1]},
            "faces": np.concatenate([m["faces"] + o for m, o in zip(members, offsets)])})
    return merged


def _copy_materials(pack: Pack, writer: glb.Buffer, doc: dict, binary: bytes, used: list[int]) -> dict[int, int]:
    """The source materials `used` (indices) into the pack, with the textures, images
    and samplers they reference (images into the pack's binary); returns source ->
    pack material index."""
    textures: dict[int, int] = {}
    for src in used:
        mat = json.loads(json.dumps(doc["materials"][src]))
        refs: list[dict] = []
        glb.texture_refs(mat, refs)
        for ref in refs:
            t = ref["index"]
            if t not in textures:
                tex = dict(doc["textures"][t])
                if "sampler" in tex:
                    pack.samplers.append(dict(doc["samplers"][tex["sampler"]]))
                    tex["sampler"] = len(pack.samplers) - 1
                if "source" in tex:
                    image = dict(doc["images"][tex["source"]])
                    if "bufferView" in image:
                        view = doc["bufferViews"][image.pop("bufferView")]
                        start = view.get("byteOffset", 0)
                        data = binary[start: start + view["byteLength"]]
                        name = image_file(data, image.get("mimeType", ""))
                        pack.image_data[name] = data
                        image["uri"] = name  # relative to tiles/: a tile prefixes its own way there
                    pack.images.append(image)
                    tex["source"] = len(pack.images) - 1
                pack.textures.append(tex)
                textures[t] = len(pack.textures) - 1
            ref["index"] = textures[t]
        pack.materials.append(mat)
    return {src: i for i, src in enumerate(used)}


def _hull_points(points: np.ndarray) -> np.ndarray:
    """The points whose convex hull is that of `points` (n, 3): the hull's vertices,
    or every point where the hull is flat."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 5:
        return points
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return np.unique(points, axis=0)


def make_pack(asset: str, level: int, doc: dict, binary: bytes) -> Pack:
    """The model glb (`doc`, `binary`: export.gltf's layout, MSFT_lod chains on its
    visual nodes) at `level` (a visual with a shorter chain shows its coarsest)."""
    parts = []
    for ni, matrix in glb.visual_nodes(doc):
        chain = glb.lod_meshes(doc, ni)
        parts += _baked(doc, binary, chain[min(level, len(chain) - 1)], matrix)
    merged = _merged(parts)
    writer = glb.Buffer(buffer=None)  # a tile names the buffer the pack's views are in
    pack = Pack(asset, level, b"", [], [], [], [])
    src_materials = sorted({m["material"] for m in merged if m["material"] >= 0}
                           | {mp["material"] for m in merged for mp in m["mappings"]})
    material_index = _copy_materials(pack, writer, doc, binary, src_materials)
    names = [v["name"] for v in doc.get("extensions", {}).get("KHR_materials_variants", {}).get("variants", [])]
    points = []
    for m in merged:
        pos = m["attributes"]["POSITION"]
        faces = m["faces"]
        index_type = "<u2" if len(pos) < 65536 else "<u4"
        indices = writer.add_accessor(faces.reshape(-1).astype(index_type), "SCALAR", glb.ELEMENT_ARRAY_BUFFER)
        prim = {"indices": indices, "mode": _TRIANGLES, "attributes": {}}
        for name in sorted(m["attributes"]):
            arr = m["attributes"][name].astype("<f4")
            prim["attributes"][name] = writer.add_accessor(arr, "VEC3" if arr.shape[1] == 3 else "VEC2",
                                                           glb.ARRAY_BUFFER, bounds=name == "POSITION")
            if name == "POSITION":
                points.append(arr.astype(np.float64))  # as stored: the bounds enclose what is drawn
        if m["material"] >= 0:
            prim["material"] = material_index[m["material"]]
        if m["mappings"]:
            prim["mappings"] = [{"material": material_index[mp["material"]],
                                 "variants": [names[v] for v in mp["variants"]]} for mp in m["mappings"]]
            pack.variants += [names[v] for mp in m["mappings"] for v in mp["variants"] if names[v] not in pack.variants]
        pack.primitives.append(prim)
        pack.triangles += len(faces)
    pack.hull = _hull_points(glb.points_to_z_up(np.concatenate(points))) if points else np.zeros((0, 3))
    pack.binary, pack.views, pack.accessors = bytes(writer.binary), writer.views, writer.accessors
    return pack
