"""Walking a .blend's view layer: joint Empties into joints, geometry objects into
visuals and collisions of their links, materials and bindings as they come."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ... import ir
from ...errors import UserError
from .arrays import build_mesh, rigid_inverse
from .bindings import authored_bindings
from .evaluate import evaluated_arrays
from .links import BASE_LINK, assemble_links, check_names, link_of, read_joint
from .materials import DEFAULT_MATERIAL, material, referenced_materials
from .objects import prop_bool, split_world, world_matrix
from .scene import Part, Scene

GEOMETRY_TYPES = ("MESH", "CURVE", "SURFACE", "FONT")


def read_scene(path: Path, scene: Scene) -> None:
    """Fill `scene` with the joints, links, parts, materials and authored bindings of
    the open file's view layer."""
    import bpy

    objects = _asset_objects(bpy)
    if not any(ob.type in GEOMETRY_TYPES for ob in objects):
        raise UserError(path, None, "the scene holds no mesh objects")
    depsgraph = bpy.context.evaluated_depsgraph_get()

    for ob in objects:
        if "joint" in ob.keys() and ob.type != "EMPTY":
            raise UserError(path, ob.name, f"has a `joint` property but is a {ob.type.lower()}, not an Empty")
    empties = [ob for ob in objects if ob.type == "EMPTY" and "joint" in ob.keys()]
    link_pose = {BASE_LINK: ir.pose()}
    parent_of_link: dict[str, str] = {}
    for empty in empties:
        joint = read_joint(path, empty, depsgraph)
        scene.joints.append(joint)
        link_pose[joint.child] = joint.pose
        parent_of_link[joint.child] = joint.parent

    for ob in objects:
        if ob.name.startswith(TERMINAL_PREFIX):
            _read_terminal(path, ob, depsgraph, scene)
            continue
        if ob.type not in GEOMETRY_TYPES:
            if "state" in ob.keys():
                raise UserError(path, ob.name, "state binding on an object without geometry (bind the mesh itself)")
            continue
        link = link_of(ob)
        _read_object(path, ob, depsgraph, link, link_pose[link], scene, bpy)

    check_names(path, scene)
    scene.links = assemble_links(path, scene, link_pose, parent_of_link)
    for material_name in referenced_materials(scene):
        if material_name not in scene.materials:
            scene.materials[material_name] = material(bpy, path, material_name, scene.warnings, scene.opened)


TERMINAL_PREFIX = "terminal."
TERMINAL_NAME = re.compile(r"^[a-z0-9_]+$")  # as asset.toml's (`TAG.terminal` splits at the last dot)


def _read_terminal(path: Path, ob, depsgraph, scene: Scene) -> None:
    """A conductor attachment point: an Empty named `terminal.<name>`, at its world
    location (the model frame before units and up axis), whatever link it hangs on."""
    name = ob.name[len(TERMINAL_PREFIX):]
    if ob.type != "EMPTY":
        raise UserError(path, ob.name, f"a terminal is an Empty; this is a {ob.type.lower()} "
                                       f"(rename it, or make terminal {name!r} an Empty)")
    if not TERMINAL_NAME.match(name):
        raise UserError(path, ob.name, f"terminal name {name!r}: lower-case letters, digits and '_' only "
                                       "(a '.001' suffix is Blender's copy of another terminal)")
    scene.terminals[name] = tuple(float(v) for v in world_matrix(path, ob, depsgraph)[:3, 3])


def _asset_objects(bpy) -> list:
    """The objects of the view layer, sorted by name. Objects only hidden in the
    viewport (a collision box a modeller hid, a disabled collection) are part of the
    asset: they are un-hidden here so the depsgraph evaluates their modifiers too.
    Objects outside the view layer (an excluded collection, an unlinked object) are
    not part of it."""
    for collection in bpy.data.collections:
        collection.hide_viewport = False
    objects = sorted(bpy.context.view_layer.objects, key=lambda o: o.name)
    for ob in objects:
        ob.hide_viewport = False
    return objects


def _read_object(path: Path, ob, depsgraph, link: str, link_pose: np.ndarray, scene: Scene, bpy) -> None:
    """The object's collision, or its visuals (one per material used) with their
    materials and bindings, as parts of `link`."""
    world = world_matrix(path, ob, depsgraph)
    rigid, rest = split_world(path, ob, world)
    pose = rigid_inverse(link_pose) @ rigid
    is_collision = prop_bool(path, ob, "collision")

    co, tris, loops, mat_index, uv, keys = evaluated_arrays(path, ob, depsgraph, scene)
    if len(tris) == 0:
        raise UserError(path, ob.name, "mesh has no faces (empty mesh object)")
    if not np.all(np.isfinite(co)):
        raise UserError(path, ob.name, "mesh has NaN or infinite vertex coordinates")
    for name, k in keys:
        if not np.all(np.isfinite(k)):
            raise UserError(path, ob.name, f"shape key {name!r} has NaN or infinite coordinates")
    corner_uvs = None if uv is None else uv[loops]

    if is_collision:
        if "state" in ob.keys():
            raise UserError(path, ob.name, "a collision mesh cannot carry a state binding")
        mesh = build_mesh(co, tris, None, rest)
        scene.parts.append(Part(link, ob.name, ir.Collision(ob.name, mesh, pose), rest))
        return

    slots = [s.material.name if s.material is not None else DEFAULT_MATERIAL for s in ob.material_slots]
    if not slots:
        slots = [DEFAULT_MATERIAL]
    # Blender clamps out-of-range material indices to the last slot.
    names = np.array(slots, dtype=object)[np.clip(mat_index, 0, len(slots) - 1)]
    used = sorted(set(names.tolist()))
    visual_names = []
    for material_name in used:
        sel = names == material_name
        mesh = build_mesh(co, tris[sel], None if corner_uvs is None else corner_uvs[sel], rest, keys)
        name = ob.name if len(used) == 1 else f"{ob.name}__{material_name}"
        visual_names.append(name)
        scene.parts.append(Part(link, ob.name, ir.Visual(name, material_name, (mesh,), pose), rest))
        if material_name not in scene.materials:
            scene.materials[material_name] = material(bpy, path, material_name, scene.warnings, scene.opened)
    scene.visuals_of[ob.name] = tuple(visual_names)
    if "state" in ob.keys():
        scene.bindings.extend(authored_bindings(path, ob, visual_names, rest, keys, bpy))


def unit_metres() -> float | None:
    """Metres per Blender unit of the scene, None for a unitless scene."""
    import bpy

    units = bpy.context.scene.unit_settings
    # a single-precision property: its 7 digits, so 0.001 stays 0.001
    return None if units.system == "NONE" else float(f"{units.scale_length:.7g}")
