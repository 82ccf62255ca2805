"""manifest.json of a model package (DESIGN.md s.4): what the runtime and the
validators read instead of re-parsing SDF. Schema: schemas/manifest.schema.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import ir
from . import names
from .textures import texture_file

MANIFEST = "manifest.json"
FORMAT_VERSION = 1


def _matrix(m: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(m, dtype=np.float64).reshape(16)]


def _bounds(asset: ir.Asset) -> list[list[float]]:
    corners = []
    for link, visual in asset.visuals():
        b = visual.mesh.bounds()
        cube = np.array([[x, y, z, 1.0] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
        corners.append((cube @ (link.pose @ visual.pose).T)[:, :3])
    if not corners:
        return [[0.0] * 3, [0.0] * 3]
    pts = np.concatenate(corners)
    return [pts.min(axis=0).tolist(), pts.max(axis=0).tolist()]


def _lods(asset: ir.Asset) -> list[dict]:
    """The LOD table; level 0 (the authored meshes) is always first."""
    infos = list(asset.lods)
    if not infos or infos[0].level != 0:
        infos.insert(0, ir.LodInfo(0, 0.0, 0.0, asset.triangle_count(0)))
    return [{"level": i.level, "budget_m": i.budget_m, "error_m": i.error_m, "triangles": i.triangles,
             "within_budget": bool(i.error_m <= i.budget_m)} for i in infos]


def content(asset: ir.Asset, *, source: dict, outputs: dict[str, str], lod_models: list[str]) -> dict:
    """The manifest as plain data. `outputs`: package-relative path -> sha256."""
    visual_of = {v.name: (link.name, v) for link, v in asset.visuals()}
    bindings = []
    for b in asset.bindings:
        link_name = visual_of[b.target][0] if b.target in visual_of else None
        bindings.append({
            "variable": b.variable,
            "effect": b.effect,
            "target": b.target,
            "link": link_name,
            "domain": list(b.domain),
            "range": list(b.range),
            "axis": list(b.axis),
            "shape_key": b.shape_key,
            "materials": list(b.materials),
            "thresholds": list(b.thresholds),
            "rest_pose": _matrix(visual_of[b.target][1].pose) if b.target in visual_of else None,
            "usd_path": names.usd_visual_path(asset.id, link_name, b.target) if link_name else None,
        })
    return {
        "format": FORMAT_VERSION,
        "asset": asset.id,
        "category": asset.category,
        "description": asset.description,
        "source": source,
        "outputs": dict(sorted(outputs.items())),
        "lod_models": lod_models,
        "lods": _lods(asset),
        "bounds": _bounds(asset),
        "links": [
            {"name": link.name, "pose": _matrix(link.pose), "mass": link.mass,
             "visuals": [{"name": v.name, "material": v.material, "pose": _matrix(v.pose),
                          "triangles": [m.triangle_count for m in v.lods],
                          "shape_keys": [k.name for k in v.mesh.shape_keys]} for v in link.visuals],
             "collisions": [c.name for c in link.collisions]}
            for link in asset.links
        ],
        "joints": [
            {"name": j.name, "type": j.type, "parent": j.parent, "child": j.child, "pose": _matrix(j.pose),
             "axis": [float(a) for a in j.axis], "lower": j.lower, "upper": j.upper,
             "effort": j.effort, "velocity": j.velocity}
            for j in asset.joints
        ],
        "materials": [
            {"name": m.name, "base_color": list(m.base_color), "metallic": m.metallic,
             "roughness": m.roughness, "emission": list(m.emission),
             **({"textures": {slot: {"file": texture_file(t), "sha256": t.digest} for slot, t in m.textures().items()}}
                if m.textures() else {})}
            for m in asset.materials
        ],
        "bindings": bindings,
        "metadata": dict(asset.metadata),
    }


def write(data: dict, folder: Path) -> list[str]:
    text = json.dumps(data, sort_keys=True, indent=1, allow_nan=False) + "\n"
    (Path(folder) / MANIFEST).write_text(text)
    return [MANIFEST]


def read(folder: Path) -> dict:
    return json.loads((Path(folder) / MANIFEST).read_text())
