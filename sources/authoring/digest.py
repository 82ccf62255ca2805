"""A content digest of a .blend file, for reproducibility tests.

Blender's writer is not byte-deterministic, so two runs of an authoring script are
compared on what the pipeline reads: objects, hierarchy, world transforms, custom
properties, materials, evaluated meshes and shape keys.

    .venv/bin/python sources/authoring/digest.py FILE.blend [...]   # prints JSON lines
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import bpy
import numpy as np

MATRIX_DECIMALS = 9
VERTEX_DECIMALS = 7
VALUE_DECIMALS = 6


def open_blend(path) -> None:
    """Open `path` without running any Python stored in it."""
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False, use_scripts=False)


def _rounded(values, decimals: int) -> bytes:
    # Adding 0.0 turns -0.0 into 0.0, so a sign of zero cannot change the digest.
    arr = np.round(np.asarray(values, dtype=np.float64), decimals) + 0.0
    return arr.tobytes()


def _plain(value):
    """A custom property value as plain JSON data."""
    if hasattr(value, "to_dict"):
        return {k: _plain(v) for k, v in sorted(value.to_dict().items())}
    if hasattr(value, "to_list"):
        return [_plain(v) for v in value.to_list()]
    if isinstance(value, float):
        return round(value, VALUE_DECIMALS)
    return value


def custom_properties(ob) -> dict:
    return {k: _plain(ob[k]) for k in sorted(ob.keys())}


def _socket_value(socket):
    value = getattr(socket, "default_value", None)
    if value is None:
        return None
    if hasattr(value, "__len__") and not isinstance(value, str):
        return [round(float(v), VALUE_DECIMALS) for v in value]
    if isinstance(value, (int, float)):
        return round(float(value), VALUE_DECIMALS)
    return str(value)


def material_record(mat) -> dict:
    """Name, node types and every Principled BSDF input value of a material."""
    record = {"name": mat.name, "nodes": [], "principled": {}}
    if mat.node_tree is None:
        return record
    record["nodes"] = sorted(node.bl_idname for node in mat.node_tree.nodes)
    for node in sorted(mat.node_tree.nodes, key=lambda n: n.name):
        if node.type == "BSDF_PRINCIPLED":
            record["principled"] = {s.identifier: _socket_value(s) for s in node.inputs}
    return record


def _feed_mesh(h, me) -> None:
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    h.update(_rounded(co, VERTEX_DECIMALS))
    loops = np.empty(len(me.loops), dtype=np.int64)
    me.loops.foreach_get("vertex_index", loops)
    sizes = np.empty(len(me.polygons), dtype=np.int64)
    me.polygons.foreach_get("loop_total", sizes)
    mat_index = np.empty(len(me.polygons), dtype=np.int64)
    me.polygons.foreach_get("material_index", mat_index)
    for arr in (loops, sizes, mat_index):
        h.update(arr.tobytes())


def _feed_shape_keys(h, ob) -> None:
    keys = getattr(ob.data, "shape_keys", None)
    if keys is None:
        return
    for block in keys.key_blocks:
        h.update(f"key:{block.name}:{block.relative_key.name}:{block.value:.6f}".encode())
        co = np.empty(len(block.data) * 3)
        block.data.foreach_get("co", co)
        h.update(_rounded(co, VERTEX_DECIMALS))


def _feed_object(h, ob, depsgraph) -> None:
    header = {
        "name": ob.name,
        "type": ob.type,
        "parent": ob.parent.name if ob.parent else None,
        "props": custom_properties(ob),
        "materials": [slot.material.name if slot.material else None for slot in ob.material_slots],
    }
    h.update(json.dumps(header, sort_keys=True).encode())
    h.update(_rounded([list(row) for row in ob.matrix_world], MATRIX_DECIMALS))
    if ob.type == "MESH":
        evaluated = ob.evaluated_get(depsgraph)
        me = evaluated.to_mesh()
        try:
            _feed_mesh(h, me)
        finally:
            evaluated.to_mesh_clear()
        _feed_shape_keys(h, ob)


def digest_current() -> str:
    """The content digest of the scene loaded now."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    h = hashlib.sha256()
    for ob in sorted(bpy.data.objects, key=lambda o: o.name):
        _feed_object(h, ob, depsgraph)
    for mat in sorted(bpy.data.materials, key=lambda m: m.name):
        h.update(json.dumps(material_record(mat), sort_keys=True).encode())
    return h.hexdigest()


def digest_blend(path) -> str:
    """Open `path` (scripts disabled) and return its content digest (sha256 hex)."""
    open_blend(path)
    return digest_current()


def is_collision(ob) -> bool:
    return bool(ob.get("collision", False))


def evaluated_triangles(collision: bool = False) -> dict[str, int]:
    """Triangles of each evaluated mesh object in the loaded scene: visual meshes, or the
    collision meshes when `collision` is true."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    counts = {}
    for ob in sorted(bpy.data.objects, key=lambda o: o.name):
        if ob.type != "MESH" or is_collision(ob) != collision:
            continue
        evaluated = ob.evaluated_get(depsgraph)
        me = evaluated.to_mesh()
        try:
            me.calc_loop_triangles()
            counts[ob.name] = len(me.loop_triangles)
        finally:
            evaluated.to_mesh_clear()
    return counts


def visual_bounds() -> list[list[float]]:
    """[[xmin, ymin, zmin], [xmax, ymax, zmax]] of the evaluated visual meshes, in the
    model frame (rounded to 1 mm)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for ob in bpy.data.objects:
        if ob.type != "MESH" or is_collision(ob):
            continue
        evaluated = ob.evaluated_get(depsgraph)
        me = evaluated.to_mesh()
        try:
            co = np.empty(len(me.vertices) * 3)
            me.vertices.foreach_get("co", co)
        finally:
            evaluated.to_mesh_clear()
        if co.size == 0:
            continue
        m = np.array(ob.matrix_world)
        world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
    return [np.round(lo, 3).tolist(), np.round(hi, 3).tolist()]


def summary(path) -> dict:
    """Digest, triangle count, joints and bindings of one .blend file."""
    digest = digest_blend(path)
    joints = {ob.name: custom_properties(ob) for ob in bpy.data.objects if "joint" in ob}
    bindings = {ob.name: custom_properties(ob) for ob in bpy.data.objects if "state" in ob}
    return {
        "file": str(path),
        "digest": digest,
        "triangles": sum(evaluated_triangles().values()),
        "bounds": visual_bounds(),
        "collision_objects": sorted(evaluated_triangles(collision=True)),
        "joints": dict(sorted(joints.items())),
        "bindings": dict(sorted(bindings.items())),
    }


def main(argv: list[str]) -> int:
    for arg in argv:
        print(json.dumps(summary(Path(arg)), sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
