"""Reader for mesh files (.stl, .obj, .ply, .glb) through trimesh.

One link "base"; one visual per geometry of the file (a glTF scene's meshes, an OBJ's
material groups), with its material, or a "default" PBR material. Units and up axis
follow asset.toml: mm -> m, and Y-up -> Z-up by +90 deg about X (+Y becomes +Z).
glTF (.glb) is Y-up by its specification, so a .glb is always converted from Y-up.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .. import ir
from ..errors import UserError
from ..geometry.clean import apply_transform

MAX_BYTES = 512 * 1024 * 1024
UNIT_SCALE = {"m": 1.0, "mm": 0.001}
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])  # Rx(+90 deg)
DEFAULT_MATERIAL = ir.Material("default")


def check_size(path: Path) -> None:
    """UserError for a missing file or one over 512 MB (checked by stat, never read)."""
    try:
        size = Path(path).stat().st_size
    except FileNotFoundError:
        raise UserError(path, None, "file not found") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
    if size > MAX_BYTES:
        raise UserError(path, None, f"file is {size / 2**20:.0f} MB, over the {MAX_BYTES // 2**20} MB limit")
    if size == 0:
        raise UserError(path, None, "file is empty")


def source_matrix(units: str, up_axis: str) -> np.ndarray:
    """(4, 4) float64 from file coordinates to model metres, Z up."""
    m = np.diag([UNIT_SCALE[units]] * 3 + [1.0])
    return Y_UP_TO_Z_UP @ m if up_axis == "Y" else m


def _safe_name(name: str, fallback: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name or "")).strip("_")
    return name or fallback


def _material(geom, fallback: str) -> ir.Material:
    """The trimesh visual's PBR or simple material, as an ir.Material."""
    mat = getattr(getattr(geom, "visual", None), "material", None)
    if mat is None:
        return DEFAULT_MATERIAL
    name = _safe_name(getattr(mat, "name", None), fallback)
    try:
        pbr = mat.to_pbr() if hasattr(mat, "to_pbr") else mat
        color = pbr.baseColorFactor
        rgba = tuple(float(c) for c in (np.asarray(color, dtype=np.float64) / (255.0 if np.asarray(color).dtype.kind in "ui" else 1.0))) if color is not None else (0.8, 0.8, 0.8, 1.0)
        emissive = pbr.emissiveFactor
        return ir.Material(
            name,
            base_color=rgba if len(rgba) == 4 else (*rgba[:3], 1.0),
            metallic=float(pbr.metallicFactor if pbr.metallicFactor is not None else 0.0),
            roughness=float(pbr.roughnessFactor if pbr.roughnessFactor is not None else 0.5),
            emission=tuple(float(c) for c in emissive[:3]) if emissive is not None else (0.0, 0.0, 0.0),
        )
    except Exception:  # an exotic material: keep its name, use PBR defaults
        return ir.Material(name)


def _geometries(loaded) -> list[tuple[str, object]]:
    """(name, Trimesh in file coordinates with scene transforms applied) pairs, sorted."""
    import trimesh

    if isinstance(loaded, trimesh.Trimesh):
        return [("mesh", loaded)]
    if isinstance(loaded, trimesh.Scene):
        out = []
        for node in sorted(loaded.graph.nodes_geometry):
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if not isinstance(geom, trimesh.Trimesh):
                continue
            g = geom.copy()
            v, f = apply_transform(g.vertices, g.faces, transform)  # mirrored nodes keep outward faces
            out.append((str(node), trimesh.Trimesh(v, f, visual=g.visual, process=False)))
        return out
    return []


def asset_from_trimesh(loaded, cfg, path: Path, up_axis: str, units: str,
                       metadata: tuple[tuple[str, str], ...] = ()) -> ir.Asset:
    """An ir.Asset from a trimesh Trimesh/Scene (shared with the CAD reader)."""
    matrix = source_matrix(units, up_axis)
    visuals, materials, seen = [], {}, set()
    for name, geom in _geometries(loaded):
        vertices = np.asarray(geom.vertices, dtype=np.float64)
        faces = np.asarray(geom.faces, dtype=np.int64)
        vis_name = _safe_name(name, "mesh")
        if vis_name[0].isdigit():  # OpenCASCADE numbers unnamed STEP solids
            vis_name = f"part_{vis_name}"
        while vis_name in seen:
            vis_name += "_"
        seen.add(vis_name)
        if len(faces) == 0:
            continue
        if not np.isfinite(vertices).all():
            raise UserError(path, vis_name, "non-finite (NaN or infinite) vertex coordinates")
        v, f = apply_transform(vertices, faces, matrix)
        mat = _material(geom, f"{vis_name}_material")
        materials.setdefault(mat.name, mat)
        visuals.append(ir.Visual(vis_name, mat.name, (ir.Mesh(v, f),)))
    if not visuals:
        raise UserError(path, None, "no triangles in the file")
    return ir.Asset(
        id=cfg.id, category=cfg.category, description=getattr(cfg, "description", ""),
        links=(ir.Link("base", visuals=tuple(visuals)),),
        materials=tuple(materials[k] for k in sorted(materials)),
        source=str(path), metadata=metadata,
    )


def _load(path: Path, file_type: str | None = None):
    import trimesh

    try:
        # process=False: no silent merging; cleaning is the geometry step's job
        return trimesh.load(str(path), file_type=file_type, process=False)
    except UserError:
        raise
    except Exception as e:  # trimesh raises many types for corrupt files
        raise UserError(path, None, f"cannot read mesh file: {type(e).__name__}: {e}") from None


def read_mesh(cfg) -> ir.Asset:
    """Read cfg.source (.stl/.obj/.ply/.glb) into an ir.Asset in metres, Z up."""
    path = Path(cfg.source)
    check_size(path)
    suffix = path.suffix.lower()
    if suffix not in (".stl", ".obj", ".ply", ".glb"):
        raise UserError(path, None, f"unsupported mesh format {suffix!r}")
    up = "Y" if suffix == ".glb" else cfg.up_axis
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = _load(path, suffix[1:])
    return asset_from_trimesh(loaded, cfg, path, up, cfg.units)
