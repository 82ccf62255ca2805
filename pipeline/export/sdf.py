"""SDF 1.9 writer: model.config and model.sdf of one asset package (or a LOD variant).

Frames follow SDF 1.9 defaults, so no pose needs a `relative_to` attribute:
a link pose is in the model frame (__model__), a visual/collision/inertial pose in its
link's frame, a joint pose in its child link's frame, a joint axis in the joint frame.
Meshes are the package's COLLADA files, referenced as model://<asset id>/meshes/...,
which lets a LOD variant folder reuse them without copies; a variant's links draw each
material once, and a collision mesh that is a box or a cylinder is written as that
shape (export/variants.py): physics engines test those in closed form.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from lxml import etree

from pipeline import ir
from pipeline.errors import UserError
from pipeline.export import names
from pipeline.export.textures import texture_file
from pipeline.export.variants import VariantVisual, variant_collisions, variant_visuals
from pipeline.geometry.primitives import Primitive
from pipeline.geometry.transform import matrix_to_xyz_rpy

SDF_VERSION = "1.9"
_AUTHOR = "substation-twin"
# A link with no geometry still needs a positive inertia; 10 cm is a plausible part.
_DEFAULT_EXTENT = 0.1
# Below this extent a box inertia degenerates; physics engines reject zero moments.
_MIN_EXTENT = 1e-3

VisualOverrides = Mapping[str, tuple[np.ndarray | None, str | None]]


def write(
    asset: ir.Asset,
    folder: Path,
    *,
    lod: int = 0,
    model_name: str | None = None,
    visual_overrides: VisualOverrides | None = None,
) -> list[str]:
    """Write folder/model.config and folder/model.sdf; return ["model.config", "model.sdf"].

    lod: which LOD's meshes the visuals reference (a visual with fewer LODs uses its
         coarsest). model_name: the <model name> and config name (default asset.id).
    visual_overrides: visual name -> (pose (4, 4) in the link frame or None,
         material name or None), used by the runtime for per-state model variants;
         the package's own model (lod 0) only: a coarse variant draws a visual apart
         only where the package has its file (collada.write).
    """
    folder = Path(folder)
    overrides = dict(visual_overrides or {})
    _check_overrides(asset, overrides)
    if overrides and lod > 0:
        raise ValueError(f"asset {asset.id!r}: visual_overrides apply to LOD 0 only, not to LOD {lod}")
    name = model_name or asset.id
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.config").write_bytes(_serialize(_config(asset, name)))
    (folder / "model.sdf").write_bytes(_serialize(_sdf(asset, name, lod, overrides)))
    return ["model.config", "model.sdf"]


def _check_overrides(asset: ir.Asset, overrides: dict) -> None:
    known = {v.name for _, v in asset.visuals()}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"asset {asset.id!r}: visual_overrides name unknown visuals {unknown}")


def _serialize(root: etree._Element) -> bytes:
    return etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)


def _sub(parent: etree._Element, tag: str, text: str | None = None, **attrib) -> etree._Element:
    el = etree.SubElement(parent, tag, {k: v for k, v in sorted(attrib.items())})
    if text is not None:
        el.text = text
    return el


def _config(asset: ir.Asset, name: str) -> etree._Element:
    root = etree.Element("model")
    _sub(root, "name", name)
    _sub(root, "version", "1.0")
    _sub(root, "sdf", "model.sdf", version=SDF_VERSION)
    author = _sub(root, "author")
    _sub(author, "name", _AUTHOR)
    _sub(author, "email", "")
    _sub(root, "description", asset.description or f"{asset.category} {asset.id}")
    return root


def _sdf(asset: ir.Asset, name: str, lod: int, overrides: dict) -> etree._Element:
    root = etree.Element("sdf", version=SDF_VERSION)
    model = _sub(root, "model", name=name)
    if not asset.joints:
        _sub(model, "static", "true")
    links = {link.name: link for link in asset.links}
    for link in asset.links:
        _link(model, asset, link, lod, overrides)
    for joint in asset.joints:
        _joint(model, asset, joint, links)
    return root


def _link(model, asset: ir.Asset, link: ir.Link, lod: int, overrides: dict) -> None:
    el = _sub(model, "link", name=names.safe_name(link.name))
    _sub(el, "pose", _pose_text(link.pose))  # default frame: __model__
    _inertial(el, link)
    for visual in variant_visuals(asset, link, lod, keep=frozenset(overrides)):
        pose, material = overrides.get(visual.name, (None, None))
        _visual(el, asset, visual, pose, material)
    for col in variant_collisions(link, lod):
        c = _sub(el, "collision", name=names.safe_name(col.name))
        _sub(c, "pose", _pose_text(col.pose))
        if col.shape is None:
            _mesh_geometry(c, asset.id, col.mesh_file)
        else:
            _primitive_geometry(c, col.shape)


def _inertial(link_el, link: ir.Link) -> None:
    """Mass from the IR; a solid box inertia over the link's visual bounds (link frame),
    centred on them: a plausible tensor for simulation, not a measured one."""
    lo, hi = _link_bounds(link)
    size = np.maximum(hi - lo, _MIN_EXTENT)
    centre = (lo + hi) / 2.0
    m = float(link.mass)
    sx, sy, sz = (size**2).tolist()
    inertial = _sub(link_el, "inertial")
    centre_pose = np.eye(4)
    centre_pose[:3, 3] = centre
    _sub(inertial, "pose", _pose_text(centre_pose))
    _sub(inertial, "mass", names.fmt(m))
    inertia = _sub(inertial, "inertia")
    for tag, value in (("ixx", m * (sy + sz) / 12), ("ixy", 0.0), ("ixz", 0.0),
                       ("iyy", m * (sx + sz) / 12), ("iyz", 0.0), ("izz", m * (sx + sy) / 12)):
        _sub(inertia, tag, names.fmt(value))


def _link_bounds(link: ir.Link) -> tuple[np.ndarray, np.ndarray]:
    """(3,), (3,): axis-aligned bounds, in the link frame, of the LOD-0 visual vertices
    (collision vertices when the link has no visual)."""
    parts = [(v.pose, v.mesh) for v in link.visuals] or [(c.pose, c.mesh) for c in link.collisions]
    points = [m.vertices @ p[:3, :3].T + p[:3, 3] for p, m in parts if len(m.vertices)]
    if not points:
        half = np.full(3, _DEFAULT_EXTENT / 2)
        return -half, half
    allp = np.concatenate(points)
    return allp.min(axis=0), allp.max(axis=0)


def _visual(link_el, asset: ir.Asset, visual: VariantVisual, pose: np.ndarray | None, material: str | None) -> None:
    el = _sub(link_el, "visual", name=names.safe_name(visual.name))
    _sub(el, "pose", _pose_text(visual.pose if pose is None else np.asarray(pose, dtype=np.float64)))
    _mesh_geometry(el, asset.id, visual.mesh_file)
    _material(el, asset, visual.name, material or visual.material)


def _mesh_geometry(parent, asset_id: str, rel_path: str) -> None:
    mesh = _sub(_sub(parent, "geometry"), "mesh")
    _sub(mesh, "uri", f"model://{asset_id}/{rel_path}")


def _primitive_geometry(parent, shape: Primitive) -> None:
    geometry = _sub(parent, "geometry")
    if shape.kind == "box":
        _sub(_sub(geometry, "box"), "size", _floats(shape.size))
    else:
        cylinder = _sub(geometry, "cylinder")
        _sub(cylinder, "radius", names.fmt(shape.size[0]))
        _sub(cylinder, "length", names.fmt(shape.size[1]))


def _material(visual_el, asset: ir.Asset, visual_name: str, material_name: str) -> None:
    try:
        mat = asset.material(material_name)
    except KeyError:
        raise UserError(asset.source or asset.id, visual_name,
                        f"material {material_name!r} is not among the asset's materials") from None
    material_element(visual_el, mat, asset.id)


# IR texture slot -> sdformat's <pbr><metal> map. The packed glTF metallic-roughness
# image has no place: gz-rendering samples roughness_map and metalness_map from their
# red channel, where glTF keeps neither.
_PBR_MAPS = {"base_color": "albedo_map", "normal": "normal_map", "occlusion": "ambient_occlusion_map",
             "emissive": "emissive_map"}


def material_element(visual_el, mat: ir.Material, asset_id: str | None = None) -> None:
    """visual_el's <material> (replacing any) and <transparency>, from the Principled
    inputs through ir.Material.sdf_phong (its docstring gives the mapping); with the
    package's asset id, its image maps as model://<asset_id>/textures/... (gz-sim
    replaces a mesh's own materials by this one, textures included)."""
    for old in visual_el.findall("material") + visual_el.findall("transparency"):
        visual_el.remove(old)
    p = mat.sdf_phong()
    el = _sub(visual_el, "material")
    for tag, rgba in (("ambient", p.ambient), ("diffuse", p.diffuse),
                      ("specular", p.specular), ("emissive", p.emissive)):
        _sub(el, tag, _floats(rgba))
    metal = _sub(_sub(el, "pbr"), "metal")
    _sub(metal, "metalness", names.fmt(mat.metallic))
    _sub(metal, "roughness", names.fmt(mat.roughness))
    if asset_id is not None:
        for slot, texture in mat.textures().items():
            if slot in _PBR_MAPS:
                _sub(metal, _PBR_MAPS[slot], f"model://{asset_id}/{texture_file(texture)}")
    if mat.alpha < 1.0:
        # Both generations read the visual's <transparency>, not the colour alpha.
        _sub(visual_el, "transparency", names.fmt(1.0 - mat.alpha))


def _joint(model, asset: ir.Asset, joint: ir.Joint, links: dict[str, ir.Link]) -> None:
    for end in (joint.parent, joint.child):
        if end not in links:
            raise UserError(asset.source or asset.id, joint.name, f"joint names unknown link {end!r}")
    el = _sub(model, "joint", name=names.safe_name(joint.name), type=joint.type)
    _sub(el, "parent", names.safe_name(joint.parent))
    _sub(el, "child", names.safe_name(joint.child))
    # SDF 1.9: a joint pose is in its child link's frame; the IR gives the pivot in the
    # model frame, so write child^-1 * pivot (identity when the pivot is the child frame).
    child = links[joint.child].pose
    _sub(el, "pose", _pose_text(np.linalg.inv(child) @ joint.pose))
    if joint.type == "fixed":
        return
    axis = _sub(el, "axis")
    # No expressed_in: the default frame is the joint frame, where the IR axis lives.
    _sub(axis, "xyz", _floats(_unit(asset, joint)))
    if joint.type in ("revolute", "prismatic"):
        limit = _sub(axis, "limit")
        _sub(limit, "lower", names.fmt(joint.lower if joint.lower is not None else -1e16))
        _sub(limit, "upper", names.fmt(joint.upper if joint.upper is not None else 1e16))
        if joint.effort is not None:
            _sub(limit, "effort", names.fmt(joint.effort))
        if joint.velocity is not None:
            _sub(limit, "velocity", names.fmt(joint.velocity))


def _unit(asset: ir.Asset, joint: ir.Joint) -> np.ndarray:
    n = float(np.linalg.norm(joint.axis))
    if not math.isfinite(n) or n < 1e-9:
        raise UserError(asset.source or asset.id, joint.name, "joint axis has (near) zero length")
    return joint.axis / n


def _floats(values) -> str:
    return " ".join(names.fmt(v) for v in values)


def _pose_text(matrix: np.ndarray) -> str:
    # Matrices everywhere else; roll-pitch-yaw only in the file text (DESIGN.md s.3).
    xyz, rpy = matrix_to_xyz_rpy(matrix)
    return _floats((*xyz.tolist(), *rpy.tolist()))
