"""The scene as OGC 3D Tiles 1.1: build/tiles/tileset.json.

Frame: the root's transform takes the scene's ENU frame to ECEF (EPSG:4978, through
pyproj) at the site origin; tile contents are glTF (Y up, as 3D Tiles reads glTF), each
tile's nodes offset from the centre of its content so the float32 instance data stays
small beside it.

Tree: the root (refine ADD, no content) holds the terrain tile and the equipment
tree. The equipment tree's top tile shows every placement at the coarsest LOD level;
each level below replaces it by tiles of the next finer level over smaller cells,
down to level 0 (refine REPLACE). A tile's geometric error is the largest measured
error (the manifests' LOD chain) of the levels it shows, so a viewer refines a tile
once that error would cover more pixels than its tolerance. A level's cells are cut
(quadtree over the placements' positions) no larger than the distance at which the
tiles of the level above refine for the site's reference camera and screen
tolerance ([lod] in site.toml), so only the tiles near the eye load finer levels.

Contents: each placed model at a tile's level is one pack (viewer.packs), drawn
with one EXT_mesh_gpu_instancing node per model per tile; the packs' vertex data are
shared files (tiles/meshes/) that the tiles reference, so the geometry is stored
once per model and level, and each image once (tiles/images/, named by content) for
every level and model that samples it. Bounding volumes are boxes in the ENU frame around what
the tile draws: every placement's pack hull transformed by its pose, and the
children's boxes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import numpy as np

from .. import glb
from ..export.names import gltf_file
from ..files import atomic_write
from ..scene.placements import yaw_matrix
from .packs import IMAGES, Pack, make_pack

TILESET = "tileset.json"
MIN_CELL_M = 8.0  # no cell smaller: below it, a tile holds about one placement
MIN_HALF_M = 0.005  # a box's smallest half size (a flat terrain has none of its own)


@dataclass
class Tile:
    level: int
    name: str
    members: np.ndarray  # indices of the placements it shows
    children: list["Tile"] = field(default_factory=list)
    box: np.ndarray | None = None  # (2, 3) ENU min, max of what it and its children draw
    content_box: np.ndarray | None = None
    error_m: float = 0.0


def ecef_transform(origin_llh) -> np.ndarray:
    """(4, 4) float64: ENU at the origin (lat, lon deg, ellipsoidal height) -> ECEF."""
    from pyproj import Transformer

    from ..georef import enu_rotation

    lat, lon, h = (float(v) for v in origin_llh)
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = to_ecef.transform(lon, lat, h)
    m = np.eye(4)
    m[:3, :3] = enu_rotation(lat, lon).T
    m[:3, 3] = (x, y, z)
    return m


def levels_of(manifest: dict) -> list[float]:
    """Measured error of each LOD level a model package has (the scene's rule: the
    base level and one per LOD model)."""
    count = len(manifest.get("lod_models", [])) + 1
    return [float(lod["error_m"]) for lod in manifest["lods"] if lod["level"] < count]


def refine_distance(error_m: float, lod: dict) -> float:
    """Distance under which `error_m` covers more than the tolerance on the site's
    reference camera (scene.placements.screen_error_px solved for the distance)."""
    return error_m * lod["reference_width_px"] / (2.0 * math.tan(lod["reference_hfov_rad"] / 2.0) * lod["screen_tolerance_px"])


def _cells(x0: float, y0: float, size: float, path: str, members: np.ndarray, en: np.ndarray,
           target: float) -> list[tuple[str, np.ndarray]]:
    """Quadtree cells (path, members) of no more than `target` metres covering the
    members' positions, empty ones left out."""
    if size <= target or len(members) <= 1 or size < 2 * MIN_HALF_M:
        return [(path, members)]
    half = size / 2.0
    right = en[members, 0] >= x0 + half
    top = en[members, 1] >= y0 + half
    out = []
    for q, (dx, dy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        sub = members[(right == bool(dx)) & (top == bool(dy))]
        if len(sub):
            out += _cells(x0 + dx * half, y0 + dy * half, half, path + str(q), sub, en, target)
    return out


def tree(en: np.ndarray, top: int, targets: dict[int, float]) -> Tile:
    """The equipment tree over placements at ENU `en` (n, 2): the top tile at level
    `top`, the tiles of level k over cells of at most targets[k] metres. A tile's
    name is its level and its cell's quadrant path from the whole site's square."""
    lo, hi = en.min(axis=0), en.max(axis=0)
    x0, y0 = float(lo[0]) - MIN_HALF_M, float(lo[1]) - MIN_HALF_M
    size = float(max(hi - lo)) + 2 * MIN_HALF_M

    def grow(tile: Tile, path: str) -> Tile:
        if tile.level == 0:
            return tile
        cx, cy, cell = _cell(x0, y0, size, path)
        for sub, members in _cells(cx, cy, cell, path, tile.members, en, targets[tile.level - 1]):
            tile.children.append(grow(Tile(tile.level - 1, f"{tile.level - 1}_{sub or 'r'}", members), sub))
        return tile

    return grow(Tile(top, f"{top}_r", np.arange(len(en))), "")


def _cell(x0: float, y0: float, size: float, path: str) -> tuple[float, float, float]:
    """(lower corner x, y, size) of the cell that quadrant path `path` names."""
    for d in path:
        size /= 2.0
        q = int(d)
        x0, y0 = x0 + (q % 2) * size, y0 + (q // 2) * size
    return x0, y0, size


# --- contents -------------------------------------------------------------------


def pack_file(pack: Pack) -> str:
    return mesh_file(pack.asset, pack.level)


def mesh_file(asset: str, level: int) -> str:
    """Where a model's pack at a level keeps its binary, relative to tiles/."""
    return f"meshes/{asset}.lod{level}.bin"


def content_glb(path: Path, entries: list[tuple[Pack, np.ndarray, list[str]]], centre: np.ndarray) -> int:
    """A tile's glb: per entry (pack, poses (k, 4, 4) ENU, tags) one node drawing the
    pack at every pose with EXT_mesh_gpu_instancing, under a node at `centre` (ENU);
    the packs' vertex data stay in their shared files (external buffers). Returns
    the bytes written."""
    doc = {"asset": {"version": "2.0", "generator": "substation-twin"}, "scene": 0,
           "buffers": [{}], "bufferViews": [], "accessors": [], "meshes": [], "materials": [], "nodes": [],
           "textures": [], "images": [], "samplers": []}
    instance_data = glb.Buffer(doc["bufferViews"], doc["accessors"])  # buffer 0, the tile's own
    used = {"EXT_mesh_gpu_instancing"}
    variants: list[str] = []
    centre_y = glb.points_to_y_up(centre)
    children = []
    for pack, poses, tags in entries:
        local = np.array(poses, dtype=np.float64)
        local[:, :3, 3] -= centre
        matrices = glb.to_y_up(local)  # (k, 4, 4)
        instances = {name: instance_data.add_accessor(arr, kind) for name, arr, kind in zip(
            ("TRANSLATION", "ROTATION", "SCALE"), glb.instance_transforms(matrices), ("VEC3", "VEC4", "VEC3"))}
        mesh = _add_pack(doc, pack, variants, used)
        doc["nodes"].append({"name": pack.asset, "mesh": mesh, "extras": {"tags": tags},
                             "extensions": {"EXT_mesh_gpu_instancing": {"attributes": instances}}})
        children.append(len(doc["nodes"]) - 1)
    doc["nodes"].append({"name": "tile", "children": children, "translation": [float(v) for v in centre_y]})
    doc["scenes"] = [{"nodes": [len(doc["nodes"]) - 1]}]
    doc["buffers"][0] = {"byteLength": glb.padded_length(instance_data.binary)}
    if variants:
        doc["extensions"] = {"KHR_materials_variants": {"variants": [{"name": n} for n in variants]}}
    doc["extensionsUsed"] = sorted(used)
    for key in ("textures", "images", "samplers", "materials"):
        if not doc[key]:
            del doc[key]
    return glb.write(path, doc, bytes(instance_data.binary))


def _add_pack(doc: dict, pack: Pack, variants: list[str], used: set[str]) -> int:
    """The pack's buffer, views, accessors, materials and one mesh into `doc`."""
    doc["buffers"].append({"uri": "../" + quote(pack_file(pack)), "byteLength": pack.byte_length})
    buffer = len(doc["buffers"]) - 1
    views, accessors = len(doc["bufferViews"]), len(doc["accessors"])
    doc["bufferViews"] += [{**v, "buffer": buffer} for v in pack.views]
    doc["accessors"] += [{**a, "bufferView": a["bufferView"] + views} for a in pack.accessors]
    materials, textures = len(doc["materials"]), len(doc["textures"])
    images, samplers = len(doc["images"]), len(doc["samplers"])
    doc["samplers"] += pack.samplers
    doc["images"] += [{**im, "uri": "../" + quote(im["uri"])} if "uri" in im and not im["uri"].startswith("data:")
                      else im for im in pack.images]  # the shared image files, from content/
    doc["textures"] += [{**t, **({"sampler": t["sampler"] + samplers} if "sampler" in t else {}),
                         **({"source": t["source"] + images} if "source" in t else {})} for t in pack.textures]
    for mat in pack.materials:
        mat = json.loads(json.dumps(mat))
        refs: list[dict] = []
        glb.texture_refs(mat, refs)
        for ref in refs:
            ref["index"] += textures
        used.update(mat.get("extensions", {}))
        doc["materials"].append(mat)
    primitives = []
    for p in pack.primitives:
        q = {"attributes": {k: v + accessors for k, v in p["attributes"].items()}, "indices": p["indices"] + accessors,
             "mode": p["mode"]}
        if "material" in p:
            q["material"] = p["material"] + materials
        if p.get("mappings"):
            for m in p["mappings"]:
                variants += [n for n in m["variants"] if n not in variants]
            q["extensions"] = {"KHR_materials_variants": {"mappings": [
                {"material": m["material"] + materials, "variants": [variants.index(n) for n in m["variants"]]}
                for m in p["mappings"]]}}
            used.add("KHR_materials_variants")
        primitives.append(q)
    doc["meshes"].append({"name": f"{pack.asset}/lod{pack.level}", "primitives": primitives})
    return len(doc["meshes"]) - 1


# --- bounds ---------------------------------------------------------------------


def placed_boxes(pack: Pack, poses: np.ndarray) -> np.ndarray:
    """(k, 2, 3) ENU min and max of the pack drawn at each pose (k, 4, 4): its hull
    points transformed, so each box is as tight as the drawn mesh allows."""
    pts = np.einsum("kij,hj->khi", poses[:, :3, :3], pack.hull) + poses[:, None, :3, 3]
    return np.stack([pts.min(axis=1), pts.max(axis=1)], axis=1)


def union(boxes) -> np.ndarray:
    boxes = [b for b in boxes if b is not None]
    return np.stack([np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)])


def box_volume(box: np.ndarray) -> dict:
    """A 3D Tiles `box` (centre and half axes, in the tileset's ENU frame)."""
    centre = (box[0] + box[1]) / 2.0
    half = np.maximum((box[1] - box[0]) / 2.0, MIN_HALF_M)
    return {"box": [float(v) for v in (*centre, half[0], 0, 0, 0, half[1], 0, 0, 0, half[2])]}


# --- the tileset ------------------------------------------------------------------


def packs_of(out: Path, models: Path, manifests: dict[str, dict], memo=None) -> dict[tuple[str, int], Pack]:
    """Every level of every placed model as a pack, its binary written to out/meshes/.
    `memo`: builder memos (FileMemo, ArrayMemo) keeping packs by the model glb's
    hash in its manifest, so a rerun bakes only the models that changed."""
    packs: dict[tuple[str, int], Pack] = {}
    for a in sorted(manifests):
        model_file = gltf_file(a)
        digest = manifests[a].get("outputs", {}).get(model_file)
        doc = binary = None
        for level in range(len(levels_of(manifests[a]))):
            dest = out / mesh_file(a, level)
            key = f"{a}\0{digest}\0{level}"
            if memo is not None and digest:
                kept = memo[1].get(key)
                if kept is not None:
                    recalled = Pack.from_arrays(kept)
                    if all(_linked(out, name, memo) for name in recalled.image_files) and memo[0].link(key, dest):
                        packs[(a, level)] = recalled
                        continue
            if doc is None:
                doc, binary = glb.read(models / a / model_file)
            pack = packs[(a, level)] = make_pack(a, level, doc, binary)
            dest.write_bytes(pack.binary)
            for name, data in pack.image_data.items():
                if not (out / name).is_file():
                    (out / name).write_bytes(data)
                    if memo is not None:
                        memo[0].keep(f"image\0{name}", out / name)
            if memo is not None and digest:
                memo[0].keep(key, dest)
                memo[1].put(key, pack.arrays())
    return packs


def _linked(out: Path, name: str, memo) -> bool:
    """Whether the image file `name` is in place in `out`, linked from the memo if need be."""
    return (out / name).is_file() or memo[0].link(f"image\0{name}", out / name)


def write(out: Path, *, models: Path, record: dict, manifests: dict[str, dict], lod: dict, memo=None,
          conductors: dict | None = None) -> dict:
    """tiles/ of a built scene into `out` (the folder made): `record` placements.json,
    `manifests` the placed models' manifest.json, `lod` the site's [lod] settings
    (screen_tolerance_px, reference_hfov_rad, reference_width_px), `memo` see
    packs_of, `conductors` conductors.json (its spans one tile). Returns figures."""
    out = Path(out)
    (out / "content").mkdir(parents=True, exist_ok=True)
    (out / "meshes").mkdir(exist_ok=True)
    (out / IMAGES).mkdir(exist_ok=True)
    placements = record["placements"]
    assets = [p["asset"] for p in placements]
    errors = {a: levels_of(manifests[a]) for a in sorted(set(assets))}
    # placements.json records "scale" where insert_scale = "apply" drew one (else 1)
    poses = np.array([yaw_matrix(p["yaw_rad"], p["enu"]) @ np.diag([p.get("scale", 1.0)] * 3 + [1.0])
                      for p in placements]).reshape(-1, 4, 4)
    packs = packs_of(out, models, {a: manifests[a] for a in errors}, memo)

    def shown(a: str, level: int) -> int:
        return min(level, len(errors[a]) - 1)

    top = max(len(e) for e in errors.values()) - 1 if errors else 0
    targets = {k: max(refine_distance(max(errors[a][shown(a, k + 1)] for a in errors), lod), MIN_CELL_M)
               for k in range(top)}
    figures = {"tiles": 0, "content_bytes": 0, "levels": top + 1, "cell_m": {str(k): round(v, 3) for k, v in targets.items()}}
    names = np.array(assets, dtype=object)

    def fill(tile: Tile, parent_error: float) -> None:
        entries, boxes = [], []
        for a in sorted(set(names[tile.members])):
            idx = tile.members[names[tile.members] == a]
            pack = packs[(a, shown(a, tile.level))]
            entries.append((pack, poses[idx], [placements[i]["tag"] for i in idx]))
            boxes.append(placed_boxes(pack, poses[idx]).transpose(1, 0, 2))
        tile.content_box = np.stack([np.min([b[0].min(axis=0) for b in boxes], axis=0),
                                     np.max([b[1].max(axis=0) for b in boxes], axis=0)])
        tile.error_m = min(parent_error, max(errors[a][shown(a, tile.level)] for a in set(names[tile.members])))
        centre = np.round((tile.content_box[0] + tile.content_box[1]) / 2.0, 3)
        figures["content_bytes"] += content_glb(out / "content" / f"{tile.name}.glb", entries, centre)
        figures["tiles"] += 1
        for child in tile.children:
            fill(child, tile.error_m)
        tile.box = union([tile.content_box] + [c.box for c in tile.children])

    children = []
    terrain = _terrain_tile(out, models, record["terrain"])
    if terrain is not None:
        children.append(terrain)
    equipment = None
    if placements:
        equipment = tree(poses[:, :2, 3], top, targets)
        fill(equipment, math.inf)
        children.append(_tile_json(equipment))
    wires = _conductor_tile(out, conductors) if conductors else None
    if wires is not None:
        children.append(wires)
    boxes = [np.array(c["_box"]) for c in children]
    whole = union(boxes) if boxes else np.zeros((2, 3))
    for c in children:
        del c["_box"]
    diagonal = float(np.linalg.norm(whole[1] - whole[0]))
    origin = record["origin"]
    root = {"boundingVolume": box_volume(whole), "geometricError": diagonal, "refine": "ADD",
            "transform": [float(v) for v in ecef_transform(
                (origin["latitude_deg"], origin["longitude_deg"], origin["height_m"])).T.reshape(16)],
            "children": children}
    tileset = {"asset": {"version": "1.1", "generator": "substation-twin"}, "geometricError": diagonal, "root": root,
               "extras": {"site": record["site"], "crs": record["crs"], "origin": origin,
                          "frame": "root transform: scene ENU (x east, y north, z up, metres) -> ECEF (EPSG:4978)"}}
    (out / TILESET).write_text(json.dumps(tileset, indent=1, sort_keys=True) + "\n")
    figures["mesh_bytes"] = sum(p.byte_length for p in packs.values())
    figures["image_bytes"] = sum(p.stat().st_size for p in (out / IMAGES).iterdir())
    figures["packs"] = len(packs)
    return figures


def _tile_json(tile: Tile) -> dict:
    node = {"boundingVolume": box_volume(tile.box), "geometricError": tile.error_m,
            "content": {"uri": f"content/{tile.name}.glb", "boundingVolume": box_volume(tile.content_box)},
            "_box": tile.box.tolist()}
    if tile.children:
        node["refine"] = "REPLACE"
        node["children"] = [_tile_json(c) for c in tile.children]
        for c in node["children"]:
            del c["_box"]
    return node


def _terrain_tile(out: Path, models: Path, name: str) -> dict | None:
    """The terrain package's glb as a tile (its frame is the scene's), or None."""
    path = models / name / gltf_file(name)
    if not path.is_file():
        return None
    doc, binary = glb.read(path)
    points = []
    for ni, m in glb.visual_nodes(doc):
        for p in doc["meshes"][glb.lod_meshes(doc, ni)[0]]["primitives"]:
            pos = glb.accessor(doc, binary, p["attributes"]["POSITION"]).astype(np.float64)
            points.append(glb.points_to_z_up(pos @ m[:3, :3].T + m[:3, 3]))  # ENU
    atomic_write(out / "terrain.glb", path.read_bytes())  # the model's bytes as they are
    if not points:
        return None
    pts = np.concatenate(points)
    box = np.stack([pts.min(axis=0), pts.max(axis=0)])
    return {"boundingVolume": box_volume(box), "geometricError": 0.0, "content": {"uri": "terrain.glb"},
            "_box": box.tolist()}


CONDUCTOR_COLOR = [0.62, 0.63, 0.64, 1.0]


def _conductor_tile(out: Path, record: dict) -> dict | None:
    """conductors.glb: the spans' tubes at their chosen LOD, merged per conductor type
    (a mesh each, vertices relative to the tile's centre), as one leaf tile."""
    from ..geometry.wires import bundle_paths, tube

    per_type: dict[str, list] = {}
    for s in record.get("spans", []):
        t = record["types"][s["type"]]
        pts = np.array(s["lods"][s["lod"]]["points"], dtype=np.float64)
        d = np.subtract(s["to"]["enu"], s["from"]["enu"])[:2]
        horizontal = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.array([1.0, 0.0])
        for path in bundle_paths(pts, horizontal, np.array(t["bundle_offsets_m"])):
            per_type.setdefault(s["type"], []).append(tube(path, t["diameter_m"] / 2.0, 6))
    if not per_type:
        return None
    allv = np.concatenate([v for parts in per_type.values() for v, _, _ in parts])
    box = np.stack([allv.min(axis=0), allv.max(axis=0)])
    centre = np.round((box[0] + box[1]) / 2.0, 3)
    doc = {"asset": {"version": "2.0", "generator": "substation-twin"}, "scene": 0, "buffers": [{}], "bufferViews": [],
           "accessors": [], "meshes": [], "nodes": [],
           "materials": [{"name": "conductor_aluminium", "pbrMetallicRoughness": {
               "baseColorFactor": CONDUCTOR_COLOR, "metallicFactor": 0.9, "roughnessFactor": 0.45}}]}
    buf = glb.Buffer(doc["bufferViews"], doc["accessors"])
    for name, parts in sorted(per_type.items()):
        base, faces = 0, []
        for v, f, _ in parts:
            faces.append(f + base)
            base += len(v)
        pos = glb.points_to_y_up(np.concatenate([v for v, _, _ in parts]) - centre).astype(np.float32)
        nrm = glb.points_to_y_up(np.concatenate([n for _, _, n in parts])).astype(np.float32)
        prim = {"attributes": {"POSITION": buf.add_accessor(pos, "VEC3", 34962, bounds=True),
                               "NORMAL": buf.add_accessor(nrm, "VEC3", 34962)},
                "indices": buf.add_accessor(np.concatenate(faces).reshape(-1).astype(np.uint32), "SCALAR", 34963),
                "material": 0}
        doc["meshes"].append({"name": name, "primitives": [prim]})
        doc["nodes"].append({"name": name, "mesh": len(doc["meshes"]) - 1})
    doc["nodes"].append({"name": "conductors", "children": list(range(len(doc["meshes"]))),
                         "translation": [float(c) for c in glb.points_to_y_up(centre)]})
    doc["scenes"] = [{"nodes": [len(doc["nodes"]) - 1]}]
    doc["buffers"][0] = {"byteLength": glb.padded_length(buf.binary)}
    glb.write(out / "conductors.glb", doc, bytes(buf.binary))
    return {"boundingVolume": box_volume(box), "geometricError": 0.0, "content": {"uri": "conductors.glb"},
            "_box": box.tolist()}
