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

import json
import os
import struct
from pathlib import Path

import numpy as np

from ..export import names
from ..geometry.transform import quaternion_from_matrix

_C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_GLB_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_FLOAT = 5126


def read_glb(data: bytes) -> tuple[dict, bytearray]:
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2:
        raise ValueError("not a glTF 2.0 binary")
    offset, doc, binary = 12, None, bytearray()
    while offset < length:
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8: offset + 8 + size]
        if kind == _JSON:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == _BIN:
            binary = bytearray(chunk)
        offset += 8 + size
    return doc, binary


def glb_bytes(doc: dict, binary: bytes) -> bytes:
    text = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(text), _JSON) + text
    if binary:
        chunks += struct.pack("<II", len(binary), _BIN) + binary
    return struct.pack("<III", _GLB_MAGIC, 2, 12 + len(chunks)) + chunks


def _accessor(doc: dict, binary: bytearray, array: np.ndarray, kind: str, minmax: bool = False) -> int:
    array = np.ascontiguousarray(array, dtype="<f4")
    binary.extend(b"\0" * (-len(binary) % 4))
    doc.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(binary), "byteLength": array.nbytes})
    binary.extend(array.tobytes())
    acc = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": _FLOAT,
           "count": int(array.shape[0]), "type": kind}
    if minmax:
        acc["min"], acc["max"] = [float(array.min())], [float(array.max())]
    doc.setdefault("accessors", []).append(acc)
    return len(doc["accessors"]) - 1


def _visual_nodes(doc: dict) -> dict[tuple[str, str], int]:
    """(link name, visual name) -> node index."""
    parent = {c: i for i, n in enumerate(doc.get("nodes", [])) for c in n.get("children", [])}
    out = {}
    for i, n in enumerate(doc.get("nodes", [])):
        if i in parent and "mesh" in n:
            out[(doc["nodes"][parent[i]].get("name", ""), n.get("name", ""))] = i
    return out


def _y_up(m: np.ndarray) -> np.ndarray:
    c4 = np.eye(4)
    c4[:3, :3] = _C
    return c4 @ m @ c4.T


def _quats(mats: list[np.ndarray]) -> np.ndarray:
    qs, prev = [], None
    for m in mats:
        w, x, y, z = quaternion_from_matrix(m)
        q = np.array([x, y, z, w])
        if prev is not None and float(q @ prev) < 0:
            q = -q
        qs.append(q)
        prev = q
    return np.array(qs)


def animate(data: bytes, tag: str, run) -> tuple[bytes, list[str]]:
    """An animated copy of one placement's model glb; returns (bytes, not applied)."""
    doc, binary = read_glb(data)
    if not doc.get("buffers"):
        doc["buffers"] = [{"byteLength": 0}]
    nodes_by_visual = _visual_nodes(doc)
    times = np.asarray(run.times, dtype=np.float64)
    frames = [{(v.link, v.visual): v for v in f if v.tag == tag} for f in run.frames]
    keys = sorted({key for f in frames for key in f})
    t_acc = None
    channels, samplers, selection, skipped = [], [], [], []

    def channel(node: int, path: str, values: np.ndarray, kind: str):
        nonlocal t_acc
        if t_acc is None:
            t_acc = _accessor(doc, binary, times, "SCALAR", minmax=True)
        samplers.append({"input": t_acc, "output": _accessor(doc, binary, values, kind), "interpolation": "LINEAR"})
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
        mats = [_y_up(v.transform) for v in seq]
        if "rotate" in effects:
            channel(node, "rotation", _quats(mats), "VEC4")
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
    doc["buffers"][0]["byteLength"] = len(binary) + (-len(binary) % 4)
    return glb_bytes(doc, binary), skipped


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
        out_dir.mkdir(parents=True, exist_ok=True)
        dst = out_dir / f"{names.safe_name(ob.tag)}.glb"
        tmp = dst.with_name(dst.name + ".tmp")
        tmp.write_bytes(data)
        os.replace(tmp, dst)
        files.append(str(dst))
    return {"files": files, "not_applied": skipped}
