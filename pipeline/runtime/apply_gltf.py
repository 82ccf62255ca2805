"""glTF applier: for each stateful placement an animated copy of its model .glb,
build/runs/<scenario>/gltf/<TAG>.glb.

The package .glb (pipeline/export/gltf.py layout: a visual is the node named after it
under its link's node; Z-up IR transforms appear as C T C^-1 with C: (x, y, z) ->
(x, z, -y)) gets one animation "twin:<scenario>" with, per bound visual:
- rotate / translate: a `rotation` / `translation` sampler of the node's local transform
  C (rest @ delta) C^-1 (scale: `scale`, when the axis is a coordinate axis);
- shape: a `weights` sampler (all morph targets of the node's mesh, the bound one set);
- material: glTF cannot animate a KHR_materials_variants choice, so the per-step
  selection (variant names `<variable>:<material>`, as the writer names them) goes in
  the animation's extras["KHR_materials_variants_selection"] = [{"t", "node", "variant"}].
Input times are seconds (t = k step_s); LINEAR interpolation for the continuous
channels. Quaternions are kept on one hemisphere so slerp never takes the long way.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import glb
from ..export import names
from ..files import atomic_write
from ..geometry.transform import continuous_quaternions, quaternions_from_matrices


def _accessor(buffer: glb.Buffer, array: np.ndarray, kind: str, bounds: bool = False) -> int:
    return buffer.add_accessor(np.asarray(array, dtype=np.float32), kind, bounds=bounds)


def _visual_nodes(doc: dict) -> dict[tuple[str, str], int]:
    """(link name, visual name) -> node index."""
    parent = {c: i for i, n in enumerate(doc.get("nodes", [])) for c in n.get("children", [])}
    out = {}
    for i, n in enumerate(doc.get("nodes", [])):
        if i in parent and "mesh" in n:
            out[(doc["nodes"][parent[i]].get("name", ""), n.get("name", ""))] = i
    return out


def animate(data: bytes, tag: str, run) -> tuple[bytes, list[str]]:
    """An animated copy of one placement's model glb; returns (bytes, not applied)."""
    doc, binary = glb.parse(data, f"the model glb of {tag}")
    if not doc.get("buffers"):
        doc["buffers"] = [{"byteLength": 0}]
    buffer = glb.Buffer(doc.get("bufferViews", []), doc.get("accessors", []), bytearray(binary))
    nodes_by_visual = _visual_nodes(doc)
    times = np.asarray(run.times, dtype=np.float64)
    frames = [{(v.link, v.visual): v for v in f if v.tag == tag} for f in run.frames]
    keys = sorted({key for f in frames for key in f})
    t_acc = None
    channels, samplers, selection, skipped = [], [], [], []

    def channel(node: int, path: str, values: np.ndarray, kind: str):
        nonlocal t_acc
        if t_acc is None:
            t_acc = _accessor(buffer, times, "SCALAR", bounds=True)
        samplers.append({"input": t_acc, "output": _accessor(buffer, values, kind), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    for key in keys:
        node = nodes_by_visual.get(key)
        if node is None:
            skipped.append(f"{tag}: no node {key[1]!r} under link {key[0]!r}")
            continue
        # Every step needs a value: before a visual's first sample, hold the first one.
        first = next(f[key] for f in frames if key in f)
        seq = []
        for f in frames:
            first = f.get(key, first)
            seq.append(first)
        effects = {bo.binding["effect"] for bo in seq[0].outputs}
        mats = glb.to_y_up(np.array([v.transform for v in seq]))
        if "rotate" in effects:
            rotations = continuous_quaternions(quaternions_from_matrices(mats))
            channel(node, "rotation", glb.to_gltf_rotation(rotations), "VEC4")
        if "translate" in effects:
            channel(node, "translation", np.array([m[:3, 3] for m in mats]), "VEC3")
        if "scale" in effects:
            diag = np.array([np.diag(m[:3, :3]) for m in mats])
            if all(np.allclose(m[:3, :3], np.diag(np.diag(m[:3, :3])), atol=1e-12) for m in mats):
                channel(node, "scale", diag, "VEC3")
            else:
                skipped.append(f"{tag}/{key[1]}: scale along a non-coordinate axis has no glTF channel")
        if "shape" in effects:
            mesh = doc["meshes"][doc["nodes"][node]["mesh"]]
            targets = (mesh.get("extras") or {}).get("targetNames") or []
            n = len(mesh["primitives"][0].get("targets", []))
            if n == 0:
                skipped.append(f"{tag}/{key[1]}: shape binding but the mesh has no morph targets")
            else:
                w = np.zeros((len(seq), n))
                for k, v in enumerate(seq):
                    for name, weight in v.shape_weights.items():
                        if name in targets:
                            w[k, targets.index(name)] = weight
                channel(node, "weights", w.reshape(-1), "SCALAR")
        for bo_index, bo in enumerate(seq[0].outputs):
            if bo.binding["effect"] == "material":
                var = bo.binding["variable"]
                for k, v in enumerate(seq):
                    selection.append({"t": float(times[k]), "node": node, "variant": f"{var}:{v.material}"})
    if channels or selection:
        anim = {"name": f"twin:{run.scenario.name}", "channels": channels, "samplers": samplers}
        if selection:
            anim["extras"] = {"KHR_materials_variants_selection": selection}
        if channels:
            doc.setdefault("animations", []).append(anim)
        else:
            doc.setdefault("extras", {})["KHR_materials_variants_selection"] = selection
    for key, items in (("bufferViews", buffer.views), ("accessors", buffer.accessors)):
        if items:  # glTF allows no empty arrays
            doc[key] = items
    doc["buffers"][0]["byteLength"] = glb.padded_length(buffer.binary)
    return glb.pack(doc, buffer.binary), skipped


def write(run, out_dir: Path) -> dict:
    out_dir = Path(out_dir)
    files, skipped = [], []
    for ob in sorted(run.observed, key=lambda o: o.tag):
        src = Path(ob.package or "") / names.gltf_file(ob.asset)
        if not src.is_file():
            skipped.append(f"{ob.tag}: no {src.name} in the package")
            continue
        data, notes = animate(src.read_bytes(), ob.tag, run)
        skipped += notes
        dst = atomic_write(out_dir / f"{names.safe_name(ob.tag)}.glb", data)
        files.append(str(dst))
    return {"files": files, "not_applied": skipped}
