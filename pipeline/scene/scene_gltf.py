"""The glTF scene: one .glb that reuses each model's meshes through
EXT_mesh_gpu_instancing (a mesh is stored once however often it is placed; meshes with
morph targets get a node per placement instead), MSFT_lod for the coarser levels, a
KHR_lights_punctual sun, Y up, the geodetic origin in extras. A primitive's
KHR_materials_variants mappings come along with their materials, the variants merged
by name across models (a viewer switches a placement's state materials from the
scene alone).

It reads the built model .glb files (the packages are its input, not the IR).
"""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import glb
from ..export.names import gltf_file
from ..geometry.transform import quaternion_from_matrix
from . import placements as placing
from .placements import Placed


class SceneBuilder:
    """Accumulates meshes copied from model .glb files and instanced nodes."""

    def __init__(self):
        self.doc = {"asset": {"version": "2.0", "generator": "substation-twin"}, "scene": 0,
                    "scenes": [{"name": "scene", "nodes": []}], "nodes": [], "meshes": [],
                    "materials": [], "textures": [], "images": [], "samplers": [],
                    "accessors": [], "bufferViews": [], "buffers": []}
        self.buffer = glb.Buffer(self.doc["bufferViews"], self.doc["accessors"])
        self.used_ext: set[str] = set()
        self._mesh_cache: dict[tuple[str, int], int] = {}
        self._material_cache: dict[tuple[str, int], int] = {}
        self._texture_cache: dict[tuple[str, int], int] = {}
        self._image_cache: dict[bytes, int] = {}  # the image's content (and type) -> index: each once
        self._sampler_cache: dict[str, int] = {}
        self.variants: list[str] = []  # KHR_materials_variants names, in order of first use

    def _copy_accessor(self, src: dict, src_bin: bytes, index: int) -> int:
        acc = dict(src["accessors"][index])
        view = src["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0)
        acc["bufferView"] = self.buffer.add_view(src_bin[start: start + view["byteLength"]], view.get("target"))
        if "byteStride" in view:
            self.doc["bufferViews"][-1]["byteStride"] = view["byteStride"]
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def _copy_image(self, src: dict, src_bin: bytes, index: int) -> int:
        image = dict(src["images"][index])
        if "bufferView" in image:
            view = src["bufferViews"][image["bufferView"]]
            start = view.get("byteOffset", 0)
            data = src_bin[start: start + view["byteLength"]]
        else:  # a data: URI (a model .glb has no files beside it)
            data = image.get("uri", "").encode()
        ck = hashlib.sha256(image.get("mimeType", "").encode() + b"\0" + data).digest()
        if ck not in self._image_cache:
            if "bufferView" in image:
                image["bufferView"] = self.buffer.add_view(data)
            self.doc["images"].append(image)
            self._image_cache[ck] = len(self.doc["images"]) - 1
        return self._image_cache[ck]

    def _copy_texture(self, key: str, src: dict, src_bin: bytes, index: int) -> int:
        """A texture of a model into the scene: its sampler (one per distinct setting)
        and its images (each distinct image once, whichever models share it)."""
        ck = (key, index)
        if ck not in self._texture_cache:
            tex = json.loads(json.dumps(src["textures"][index]))
            if "sampler" in tex:
                sampler = json.dumps(src["samplers"][tex["sampler"]], sort_keys=True)
                if sampler not in self._sampler_cache:
                    self.doc["samplers"].append(json.loads(sampler))
                    self._sampler_cache[sampler] = len(self.doc["samplers"]) - 1
                tex["sampler"] = self._sampler_cache[sampler]
            for holder in (tex, *tex.get("extensions", {}).values()):  # EXT_texture_webp & co. name a source too
                if isinstance(holder, dict) and "source" in holder:
                    holder["source"] = self._copy_image(src, src_bin, holder["source"])
            self.used_ext.update(tex.get("extensions", {}))
            self.doc["textures"].append(tex)
            self._texture_cache[ck] = len(self.doc["textures"]) - 1
        return self._texture_cache[ck]

    def _copy_material(self, key: str, src: dict, src_bin: bytes, index: int) -> int:
        ck = (key, index)
        if ck not in self._material_cache:
            mat = json.loads(json.dumps(src["materials"][index]))
            refs: list[dict] = []
            glb.texture_refs(mat, refs)
            for ref in refs:
                ref["index"] = self._copy_texture(key, src, src_bin, ref["index"])
                self.used_ext.update(ref.get("extensions", {}))  # KHR_texture_transform
            for ext in mat.get("extensions", {}):
                self.used_ext.add(ext)
            self.doc["materials"].append(mat)
            self._material_cache[ck] = len(self.doc["materials"]) - 1
        return self._material_cache[ck]

    def copy_mesh(self, key: str, src: dict, src_bin: bytes, mesh_index: int) -> int:
        ck = (key, mesh_index)
        if ck in self._mesh_cache:
            return self._mesh_cache[ck]
        mesh = src["meshes"][mesh_index]
        prims = []
        for p in mesh["primitives"]:
            q = {"attributes": {a: self._copy_accessor(src, src_bin, i) for a, i in sorted(p["attributes"].items())},
                 "mode": p.get("mode", 4)}
            if "indices" in p:
                q["indices"] = self._copy_accessor(src, src_bin, p["indices"])
            if "material" in p:
                q["material"] = self._copy_material(key, src, src_bin, p["material"])
            if "targets" in p:
                q["targets"] = [{a: self._copy_accessor(src, src_bin, i) for a, i in sorted(t.items())}
                                for t in p["targets"]]
            mappings = p.get("extensions", {}).get("KHR_materials_variants", {}).get("mappings")
            if mappings:
                q["extensions"] = {"KHR_materials_variants": {"mappings": self._copy_mappings(key, src, src_bin, mappings)}}
            prims.append(q)
        new = {"name": mesh.get("name", ""), "primitives": prims}
        if "weights" in mesh:
            new["weights"] = mesh["weights"]
        if "extras" in mesh:
            new["extras"] = mesh["extras"]
        self.doc["meshes"].append(new)
        self._mesh_cache[ck] = len(self.doc["meshes"]) - 1
        return self._mesh_cache[ck]

    def _copy_mappings(self, key: str, src: dict, src_bin: bytes, mappings: list[dict]) -> list[dict]:
        """A primitive's variant mappings with the scene's material and variant indices."""
        names = [v["name"] for v in src.get("extensions", {}).get("KHR_materials_variants", {}).get("variants", [])]
        out = []
        for m in mappings:
            variants = []
            for i in m["variants"]:
                if names[i] not in self.variants:
                    self.variants.append(names[i])
                variants.append(self.variants.index(names[i]))
            out.append({"material": self._copy_material(key, src, src_bin, m["material"]), "variants": variants})
        self.used_ext.add("KHR_materials_variants")
        return out

    def instance_accessors(self, transforms: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict[str, int]:
        """TRANSLATION / ROTATION / SCALE accessors of instance transforms (Y-up), from
        (translations (k, 3), rotations (k, 4), scales (k, 3)) float32 (glb.instance_transforms)."""
        return {name: self.buffer.add_accessor(arr, typ, bounds=name == "TRANSLATION")
                for name, arr, typ in zip(("TRANSLATION", "ROTATION", "SCALE"), transforms, ("VEC3", "VEC4", "VEC3"))}

    def add_node(self, node: dict, root: bool = True) -> int:
        self.doc["nodes"].append(node)
        i = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(i)
        return i


class _GroupVisual(NamedTuple):
    """One visual node of an asset's glTF at one LOD, for the placements showing it:
    their matrices (k, 4, 4) and whether its mesh has morph targets (a node per
    placement then, not one instanced node)."""

    asset_id: str
    lod: int
    node: int
    chain: list[int]
    members: list[Placed]
    matrices: np.ndarray
    morphs: bool


def _per_placement(sb: SceneBuilder, asset_id: str, lod: int, doc: dict, binary: bytes, node_index: int,
                   chain: list[int], members: list[Placed], matrices: list[np.ndarray]) -> None:
    """A visual with morph targets gets one node per placement (its meshes shared): each
    placement's shape-key weights are its own state (an oil column's level), and
    Blender's glTF importer fails on instanced meshes with morph targets."""
    meshes = [sb.copy_mesh(asset_id, doc, binary, mesh_index) for mesh_index in chain]
    base = f"{asset_id}/lod{lod}/{doc['nodes'][node_index].get('name', node_index)}"
    for pl, m in zip(members, matrices):
        name = f"{base}/{pl.placement.tag}"
        matrix = [float(v) for v in m.T.reshape(16)]
        coarser = [sb.add_node({"name": f"{name}/lod+{k}", "mesh": mesh, "matrix": matrix}, root=False)
                   for k, mesh in enumerate(meshes[1:], start=1)]
        node = {"name": name, "mesh": meshes[0], "matrix": matrix, "extras": {"tags": [pl.placement.tag]}}
        if coarser:
            node["extensions"] = {"MSFT_lod": {"ids": coarser}}
            node["extras"]["MSFT_screencoverage"] = [0.2 / 4**k for k in range(len(coarser) + 1)]
            sb.used_ext.add("MSFT_lod")
        sb.add_node(node)


def write(path: Path, *, models: Path, placed: list[Placed], terrain_model: str, origin_llh,
          crs: str, site_name: str, sun: dict, extra=None) -> None:
    """`extra(sb)`: adds meshes and nodes of its own (the conductors)."""
    sb = SceneBuilder()
    groups: dict[tuple[str, int], list[Placed]] = defaultdict(list)
    for pl in sorted(placed, key=lambda p: p.placement.tag):
        groups[(pl.placement.asset_id, pl.lod)].append(pl)
    sources = {}
    for asset_id in sorted({a for a, _ in groups} | {terrain_model}):
        sources[asset_id] = glb.read(models / asset_id / gltf_file(asset_id))

    doc, binary = sources[terrain_model]
    for ni, m in glb.visual_nodes(doc):
        mesh = sb.copy_mesh(terrain_model, doc, binary, doc["nodes"][ni]["mesh"])
        sb.add_node({"name": f"terrain/{doc['nodes'][ni].get('name', ni)}", "mesh": mesh,
                     "matrix": [float(v) for v in m.T.reshape(16)]} if not np.allclose(m, np.eye(4))
                    else {"name": f"terrain/{doc['nodes'][ni].get('name', ni)}", "mesh": mesh})

    visuals = []
    for (asset_id, lod), members in sorted(groups.items()):
        doc = sources[asset_id][0]
        poses = glb.to_y_up(np.array([placing.scaled_pose(pl) for pl in members]))  # (k, 4, 4)
        for ni, local in glb.visual_nodes(doc):
            chain = glb.lod_meshes(doc, ni)[lod:] or glb.lod_meshes(doc, ni)[-1:]
            morphs = any("targets" in p for p in doc["meshes"][chain[0]]["primitives"])
            matrices = poses @ local
            visuals.append(_GroupVisual(asset_id, lod, ni, chain, members, matrices, morphs))
    instanced = [v.matrices for v in visuals if not v.morphs]
    transforms = glb.instance_transforms(np.concatenate(instanced)) if instanced else None
    start = 0
    for asset_id, lod, ni, chain, members, matrices, morphs in visuals:
        doc, binary = sources[asset_id]
        if morphs:
            _per_placement(sb, asset_id, lod, doc, binary, ni, chain, members, list(matrices))
            continue
        inst = sb.instance_accessors(tuple(a[start:start + len(matrices)] for a in transforms))
        start += len(matrices)
        ext = {"EXT_mesh_gpu_instancing": {"attributes": inst}}
        name = f"{asset_id}/lod{lod}/{doc['nodes'][ni].get('name', ni)}"
        coarser = []
        for k, mesh_index in enumerate(chain[1:], start=1):
            coarser.append(sb.add_node({"name": f"{name}/lod+{k}", "mesh": sb.copy_mesh(asset_id, doc, binary, mesh_index),
                                        "extensions": {"EXT_mesh_gpu_instancing": {"attributes": inst}}}, root=False))
        node = {"name": name, "mesh": sb.copy_mesh(asset_id, doc, binary, chain[0]), "extensions": ext,
                "extras": {"tags": [pl.placement.tag for pl in members]}}
        if coarser:
            ext["MSFT_lod"] = {"ids": coarser}
            node["extras"]["MSFT_screencoverage"] = [0.2 / 4**k for k in range(len(coarser) + 1)]
            sb.used_ext.add("MSFT_lod")
        sb.used_ext.add("EXT_mesh_gpu_instancing")
        sb.add_node(node)

    if extra is not None:
        extra(sb)
    d = -np.array([np.sin(np.radians(sun["azimuth_deg"])) * np.cos(np.radians(sun["elevation_deg"])),
                   np.cos(np.radians(sun["azimuth_deg"])) * np.cos(np.radians(sun["elevation_deg"])),
                   np.sin(np.radians(sun["elevation_deg"]))])
    d_y = glb.Z_TO_Y[:3, :3] @ d
    # a punctual directional light shines along its local -Z
    z = -d_y / np.linalg.norm(d_y)
    x = np.cross([0.0, 1.0, 0.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    q = glb.to_gltf_rotation(quaternion_from_matrix(np.stack([x, y, z], axis=1)))
    sb.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"name": "sun", "type": "directional", "color": [1.0, 0.96, 0.9], "intensity": float(sun["illuminance_lux"])}]}}
    if sb.variants:
        sb.doc["extensions"]["KHR_materials_variants"] = {"variants": [{"name": n} for n in sb.variants]}
    sb.add_node({"name": "sun", "rotation": [float(v) for v in q], "extensions": {"KHR_lights_punctual": {"light": 0}}})
    sb.used_ext.add("KHR_lights_punctual")

    sb.doc["scenes"][0]["extras"] = {
        "site": site_name, "crs": crs, "up": "+Y (glTF); scene frame ENU: x=east, y=up, z=-north",
        "geodetic_origin": {"latitude_deg": float(origin_llh[0]), "longitude_deg": float(origin_llh[1]),
                            "height_m": float(origin_llh[2])}}
    sb.doc["extensionsUsed"] = sorted(sb.used_ext)
    sb.doc["buffers"] = [{"byteLength": glb.padded_length(sb.buffer.binary)}]
    for key in ("materials", "textures", "images", "samplers", "meshes"):
        if not sb.doc[key]:
            del sb.doc[key]
    glb.write(path, sb.doc, bytes(sb.buffer.binary))
