"""Shared helpers of the bpy authoring scripts: an empty scene, the sample's material
library, joint Empties and state bindings in the conventions of DESIGN.md s.2, and a
save that writes the same file every time.

The sample asset set (ids, sizes, triangle ranges, conventions) is specified in
sources/authoring/ASSETS.md: every authoring script follows it.

Run an authoring script with the project's Python (bpy installed as a module):
    .venv/bin/python sources/authoring/<script>.py [--out sources/assets]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import bpy

ASSETS = Path(__file__).resolve().parent.parent / "assets"

# Principled BSDF parameters: base colour (linear RGBA), metallic, roughness, emission.
MATERIALS = {
    "porcelain_brown": ((0.23, 0.09, 0.04, 1.0), 0.0, 0.15, (0, 0, 0)),
    "porcelain_grey": ((0.55, 0.56, 0.55, 1.0), 0.0, 0.2, (0, 0, 0)),
    "silicone_grey": ((0.42, 0.44, 0.45, 1.0), 0.0, 0.55, (0, 0, 0)),
    "galvanised_steel": ((0.62, 0.63, 0.64, 1.0), 1.0, 0.45, (0, 0, 0)),
    "aluminium": ((0.91, 0.92, 0.92, 1.0), 1.0, 0.3, (0, 0, 0)),
    "copper": ((0.95, 0.64, 0.54, 1.0), 1.0, 0.35, (0, 0, 0)),
    "painted_tank": ((0.33, 0.38, 0.35, 1.0), 0.0, 0.5, (0, 0, 0)),
    "painted_grey": ((0.45, 0.47, 0.48, 1.0), 0.0, 0.55, (0, 0, 0)),
    "concrete": ((0.5, 0.49, 0.46, 1.0), 0.0, 0.9, (0, 0, 0)),
    "gauge_glass": ((0.9, 0.95, 1.0, 0.25), 0.0, 0.05, (0, 0, 0)),
    "dial_white": ((0.85, 0.85, 0.83, 1.0), 0.0, 0.4, (0, 0, 0)),
    "dial_red": ((0.7, 0.03, 0.02, 1.0), 0.0, 0.4, (0, 0, 0)),
    "pointer_black": ((0.02, 0.02, 0.02, 1.0), 0.0, 0.5, (0, 0, 0)),
    "oil_amber": ((0.6, 0.32, 0.02, 0.9), 0.0, 0.1, (0, 0, 0)),
    "lamp_off": ((0.15, 0.1, 0.02, 1.0), 0.0, 0.3, (0, 0, 0)),
    "lamp_alarm": ((1.0, 0.15, 0.02, 1.0), 0.0, 0.3, (4.0, 0.6, 0.08)),
    "lamp_white": ((0.95, 0.95, 0.9, 1.0), 0.0, 0.3, (6.0, 6.0, 5.5)),
    "black_rubber": ((0.03, 0.03, 0.03, 1.0), 0.0, 0.8, (0, 0, 0)),
    "camera_glass": ((0.02, 0.03, 0.05, 1.0), 0.0, 0.05, (0, 0, 0)),
    "brick": ((0.45, 0.2, 0.12, 1.0), 0.0, 0.85, (0, 0, 0)),
    "roof_metal": ((0.5, 0.52, 0.55, 1.0), 1.0, 0.5, (0, 0, 0)),
}


def parse_out() -> Path:
    p = argparse.ArgumentParser()
    p.add_argument("--out", type=Path, default=ASSETS, help="assets folder to write into")
    return p.parse_args().out


def new_scene() -> None:
    """An empty scene: no default cube, camera or light, nothing left from before."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for coll in (bpy.data.meshes, bpy.data.materials, bpy.data.objects):
        for block in list(coll):
            coll.remove(block)


def material(name: str) -> bpy.types.Material:
    """The library material `name`, created once per file."""
    if name in bpy.data.materials:
        return bpy.data.materials[name]
    color, metallic, roughness, emission = MATERIALS[name]
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = color
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Alpha"].default_value = color[3]
    if any(emission):
        bsdf.inputs["Emission Color"].default_value = (*emission, 1.0)
        bsdf.inputs["Emission Strength"].default_value = 1.0
    mat.diffuse_color = color
    return mat


def mesh_object(name: str, verts, faces, mat: str, parent=None, location=(0, 0, 0)):
    """A mesh object from plain vertex and face lists, linked to the scene."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    me.validate(clean_customdata=False)
    me.materials.append(material(mat))
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    if parent is not None:
        ob.parent = parent
    return ob


def joint_empty(name: str, kind: str, location, parent=None, axis=None, lower=None, upper=None,
                effort=None, velocity=None, rotation=(0.0, 0.0, 0.0)):
    """An Empty that marks a joint (DESIGN.md s.2); its origin is the pivot."""
    ob = bpy.data.objects.new(name, None)
    ob.empty_display_type = "ARROWS"
    ob.empty_display_size = 0.3
    ob.location = location
    ob.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(ob)
    if parent is not None:
        ob.parent = parent
    ob["joint"] = kind
    if axis is not None:
        ob["joint_axis"] = [float(a) for a in axis]
    for key, value in (("joint_lower", lower), ("joint_upper", upper),
                       ("joint_effort", effort), ("joint_velocity", velocity)):
        if value is not None:
            ob[key] = float(value)
    return ob


def bind_state(ob, variable: str, effect: str, domain, out_range=None, materials=None, thresholds=None):
    """Custom properties of a state binding (DESIGN.md s.2) on object `ob`."""
    ob["state"] = variable
    ob["state_effect"] = effect
    ob["state_domain"] = [float(v) for v in domain]
    if out_range is not None:
        ob["state_range"] = [float(v) for v in out_range]
    if materials is not None:
        ob["state_materials"] = list(materials)
    if thresholds is not None:
        ob["state_thresholds"] = [float(v) for v in thresholds]


def set_parent_keep(child, parent) -> None:
    """Parent `child` to `parent` without moving it in the world."""
    bpy.context.view_layer.update()
    world = child.matrix_world.copy()
    child.parent = parent
    child.matrix_parent_inverse = parent.matrix_world.inverted()
    child.matrix_world = world


def save(asset_id: str, out: Path) -> Path:
    """Write <out>/<asset_id>/<asset_id>.blend, compressed. Blender's writer is not
    byte-deterministic (it stores memory addresses), so reproducibility is checked on
    the scene content the pipeline reads, not on the file's bytes."""
    folder = out / asset_id
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{asset_id}.blend"
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, relative_remap=False)
    return path


TAU = 2.0 * math.pi
