"""Peer (a), run inside a subprocess with bpy: what a Blender user does to ship the
whole scene as ONE file (the study's rejected monolithic approach), and how long
Blender takes to load each result. Not imported by the pipeline; run as

    python -m pipeline.bench.blender_script assemble BUILT OUTDIR REPEATS
    python -m pipeline.bench.blender_script usd BLEND OUTDIR
    python -m pipeline.bench.blender_script load FILE
    python -m pipeline.bench.blender_script reexport BUILT ASSET OUTDIR STEPS
    python -m pipeline.bench.blender_script nudge BLEND STEP

and prints one line `BENCH_JSON {...}`.

assemble: import each used model's .glb once (LOD0, as authored), then one linked
duplicate of its object tree per placement (objects share mesh data, as Alt+D does)
at the placement's ENU pose from scene/placements.json, plus the terrain; then time
`export_scene.gltf` (GLB) of the whole scene, and save it as a .blend for `usd`.
usd: open that .blend and time `wm.usd_export` of the whole scene (its own process:
Blender's USD export of the sample runs for minutes and takes gigabytes, so the driver caps it
without losing the glTF figures, and without assembling the scene again).
load: a fresh Blender imports FILE (glTF or USD, default options); seconds and this
process's peak RSS (`load none` gives bpy's own baseline).
reexport: the study's runtime: at every state step, change the indicator (the
pointer's rotation and a material colour) and re-export the model with Blender.
nudge: a modeller's edit of a source, for the build bench: open BLEND, move one
vertex of its largest mesh STEP metres along X, save it in place (no .blend1).
"""

from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path


def _emit(data: dict) -> None:
    print("BENCH_JSON " + json.dumps(data), flush=True)


def _reset(bpy) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _import_glb(bpy, path: Path) -> list:
    before = set(bpy.data.objects)
    bpy.ops.import_scene.gltf(filepath=str(path))
    return [o for o in bpy.data.objects if o not in before]


def _duplicate(bpy, objects: list, collection) -> dict:
    """Linked duplicate of an object tree: copies share their mesh data."""
    mapping = {o: o.copy() for o in objects}
    for src, dup in mapping.items():
        collection.objects.link(dup)
        if src.parent in mapping:
            dup.parent = mapping[src.parent]
            dup.matrix_parent_inverse = src.matrix_parent_inverse.copy()
    return mapping


def assemble(built: Path, outdir: Path, repeats: int) -> dict:
    import bpy
    from mathutils import Matrix

    _reset(bpy)
    record = json.loads((built / "scene" / "placements.json").read_text())
    t0 = time.perf_counter()
    templates, roots = {}, {}
    for asset in sorted({p["asset"] for p in record["placements"]}):
        objs = _import_glb(bpy, built / "models" / asset / f"{asset}.glb")
        templates[asset] = objs
        roots[asset] = {o: o.matrix_world.copy() for o in objs if o.parent is None}
    terrain = record.get("terrain")
    if terrain:
        _import_glb(bpy, built / "models" / terrain / f"{terrain}.glb")
    collection = bpy.context.scene.collection
    used = set()
    for p in record["placements"]:
        asset = p["asset"]
        copy = {o: o for o in templates[asset]}  # the first placement keeps the imported objects
        if asset in used:
            copy = _duplicate(bpy, templates[asset], collection)
        used.add(asset)
        pose = Matrix.Translation(p["enu"]) @ Matrix.Rotation(p["yaw_rad"], 4, "Z")
        for root, imported in roots[asset].items():
            copy[root].matrix_world = pose @ imported
    bpy.context.view_layer.update()
    assemble_s = time.perf_counter() - t0
    outdir.mkdir(parents=True, exist_ok=True)
    dst = outdir / "blender_monolithic.glb"
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        bpy.ops.export_scene.gltf(filepath=str(dst), export_format="GLB")
        times.append(time.perf_counter() - t0)
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    blend = outdir / "blender_monolithic.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), compress=False)
    return {"assemble_s": assemble_s, "objects": len(bpy.data.objects), "meshes": len(bpy.data.meshes),
            "placements": len(record["placements"]), "export_s": times, "file": str(dst),
            "bytes": dst.stat().st_size, "maxrss_bytes": maxrss, "blend": str(blend),
            "blender": bpy.app.version_string}


def usd(blend: Path, outdir: Path) -> dict:
    import bpy

    t0 = time.perf_counter()
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False, use_scripts=False)
    open_s = time.perf_counter() - t0
    dst = outdir / "blender_monolithic.usdc"
    t0 = time.perf_counter()
    bpy.ops.wm.usd_export(filepath=str(dst))
    export_s = time.perf_counter() - t0
    return {"open_s": open_s, "export_s": [export_s], "file": str(dst), "bytes": dst.stat().st_size,
            "maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def load(path: str) -> dict:
    import bpy

    _reset(bpy)
    t0 = time.perf_counter()
    if path == "none":
        pass
    elif path.endswith((".glb", ".gltf")):
        bpy.ops.import_scene.gltf(filepath=path)
    else:
        bpy.ops.wm.usd_import(filepath=path)
    bpy.context.view_layer.update()
    seconds = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {"seconds": seconds, "maxrss_bytes": rss, "objects": len(bpy.data.objects),
            "meshes": len(bpy.data.meshes)}


def reexport(built: Path, asset: str, outdir: Path, steps: int) -> dict:
    import bpy

    _reset(bpy)
    objs = _import_glb(bpy, built / "models" / asset / f"{asset}.glb")
    meshes = [o for o in objs if o.type == "MESH"]
    target = meshes[0]
    mat = target.active_material
    outdir.mkdir(parents=True, exist_ok=True)
    dst = outdir / f"{asset}_step.glb"
    times = []
    for k in range(steps):
        t0 = time.perf_counter()
        target.rotation_euler[1] = 0.1 * k  # the pointer moves
        if mat is not None and mat.use_nodes:
            bsdf = mat.node_tree.nodes.get("Principled BSDF")
            if bsdf is not None:
                bsdf.inputs["Base Color"].default_value = (0.5 + 0.05 * (k % 10), 0.1, 0.1, 1.0)
        bpy.ops.export_scene.gltf(filepath=str(dst), export_format="GLB")
        times.append(time.perf_counter() - t0)
    return {"asset": asset, "objects": len(objs), "step_s": times, "bytes": dst.stat().st_size}


def nudge(blend: Path, step: float) -> dict:
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False, use_scripts=False)
    meshes = sorted((o for o in bpy.data.objects if o.type == "MESH" and len(o.data.vertices)), key=lambda o: o.name)
    if not meshes:
        raise SystemExit(f"{blend}: no mesh to edit")
    target = max(meshes, key=lambda o: len(o.data.vertices))
    target.data.vertices[0].co.x += step
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_mainfile(filepath=str(blend))
    return {"object": target.name, "step_m": step}


if __name__ == "__main__":
    mode, *args = sys.argv[1:]
    if mode == "assemble":
        _emit(assemble(Path(args[0]), Path(args[1]), int(args[2])))
    elif mode == "usd":
        _emit(usd(Path(args[0]), Path(args[1])))
    elif mode == "load":
        _emit(load(args[0]))
    elif mode == "reexport":
        _emit(reexport(Path(args[0]), args[1], Path(args[2]), int(args[3])))
    elif mode == "nudge":
        _emit(nudge(Path(args[0]), float(args[1])))
    else:
        sys.exit(f"unknown mode {mode!r}")
