"""An object's evaluated geometry as arrays: modifiers applied through the viewport
depsgraph, shape keys each alone and the rest mesh as the package docstring says."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .scene import Scene


def evaluated_arrays(path: Path, ob, depsgraph, scene: Scene):
    """(co (n,3) f64, tris (m,3), loops (m,3), material index (m,), per-loop uv (L,2) or
    None, shape keys ((name, (n,3)), ...)) of the object's evaluated geometry."""
    key_blocks = None
    if ob.type == "MESH" and ob.data.shape_keys is not None and len(ob.data.shape_keys.key_blocks) > 1:
        key_blocks = ob.data.shape_keys.key_blocks
    if key_blocks is None:
        return (*_mesh_arrays(ob.evaluated_get(depsgraph)), ())
    return _shape_key_arrays(path, ob, depsgraph, key_blocks, scene)


def _mesh_arrays(ob_eval, mesh=None):
    """Arrays of `mesh`, or of the evaluated object's to_mesh() (freed afterwards)."""
    owned = mesh is None
    me = ob_eval.to_mesh() if owned else mesh
    try:
        n = len(me.vertices)
        co = np.empty(n * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        lt = me.loop_triangles
        m = len(lt)
        tris = np.empty(m * 3, dtype=np.int32)
        lt.foreach_get("vertices", tris)
        loops = np.empty(m * 3, dtype=np.int32)
        lt.foreach_get("loops", loops)
        mat_index = np.empty(m, dtype=np.int32)
        lt.foreach_get("material_index", mat_index)
        uv = None
        if me.uv_layers.active is not None and len(me.loops):
            uv = np.empty(len(me.loops) * 2, dtype=np.float32)
            me.uv_layers.active.data.foreach_get("uv", uv)
            uv = uv.reshape(-1, 2).astype(np.float64)
    finally:
        if owned:
            ob_eval.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64), tris.reshape(-1, 3), loops.reshape(-1, 3), mat_index, uv


def _enabled_modifiers(ob) -> list:
    return [m for m in ob.modifiers if m.show_viewport]


def _shape_key_arrays(path: Path, ob, depsgraph, key_blocks, scene: Scene):
    """The saved mix as the base arrays, plus each key but the reference alone at full
    weight (the package docstring).

    Without modifiers: both from the key blocks (_shape_key_arrays_raw). With
    modifiers: the object evaluated as saved, and each key evaluated alone through the
    stack (show_only_shape_key); if the stack changes the vertex count between them (it
    merges or welds by distance), the modifiers are left out for this object and a
    warning says so."""
    names = [kb.name for kb in key_blocks]
    mixed = not scene.drives(ob)
    _note_key_values(ob, key_blocks, scene, mixed)
    if not _enabled_modifiers(ob):
        return _shape_key_arrays_raw(ob, key_blocks, names, mixed)

    base = _mesh_arrays(ob.evaluated_get(depsgraph)) if mixed else None
    ob.show_only_shape_key = True
    evaluated = []
    for i in range(0 if base is None else 1, len(key_blocks)):
        ob.active_shape_key_index = i
        depsgraph.update()
        evaluated.append(_mesh_arrays(ob.evaluated_get(depsgraph)))
    ob.show_only_shape_key = False
    ob.active_shape_key_index = 0
    depsgraph.update()
    if base is None:
        base = evaluated.pop(0)
    if all(len(e[0]) == len(base[0]) for e in evaluated):
        return (*base, tuple((name, e[0]) for name, e in zip(names[1:], evaluated)))
    lost = scene.warnings.get("shape_keys", "shape keys read without the modifiers of: ")
    scene.warnings["shape_keys"] = lost + ("" if lost.endswith(": ") else ", ") + \
        f"{ob.name} (its modifiers change the vertex count between keys)"
    return _shape_key_arrays_raw(ob, key_blocks, names, mixed)


def _note_key_values(ob, key_blocks, scene: Scene, mixed: bool) -> None:
    """The saved values, and whether they make the object's rest mesh, in the notes."""
    values = [f"{kb.name}={kb.value:g}" for kb in list(key_blocks)[1:] if kb.value != 0.0 and not kb.mute]
    if values:
        what = "make its rest mesh" if mixed else "left to its shape binding (the rest mesh is the reference key)"
        scene.notes.append(f"{ob.name}: shape key values {', '.join(values)} {what}")


def _shape_key_arrays_raw(ob, key_blocks, names, mixed: bool = True):
    """Mesh data arrays with the mix of the keys' saved values as positions (a key's
    offset is from its reference key, scaled by its vertex group; the reference key
    alone unless `mixed`), and each key alone: reference + key - its own reference."""
    co, tris, loops, mat_index, uv = _mesh_arrays(None, ob.data)
    positions = {}
    for kb in key_blocks:
        buf = np.empty(len(co) * 3, dtype=np.float32)
        kb.data.foreach_get("co", buf)
        positions[kb.name] = buf.reshape(-1, 3).astype(np.float64)
    reference = positions[key_blocks[0].name]
    mix = reference.copy()
    alone = []
    for kb in list(key_blocks)[1:]:
        offset = positions[kb.name] - positions[kb.relative_key.name]
        alone.append((kb.name, reference + offset))
        if mixed and kb.value != 0.0 and not kb.mute:
            mix += kb.value * _group_weights(ob, kb.vertex_group, len(co))[:, None] * offset
    return mix, tris, loops, mat_index, uv, tuple(alone)


def _group_weights(ob, group: str, n: int) -> np.ndarray:
    """(n,) weights of vertex group `group` (ones when the key names none)."""
    if not group or group not in ob.vertex_groups:
        return np.ones(n)
    index = ob.vertex_groups[group].index
    weights = np.zeros(n)
    for v in ob.data.vertices:
        for g in v.groups:
            if g.group == index:
                weights[v.index] = g.weight
    return weights
