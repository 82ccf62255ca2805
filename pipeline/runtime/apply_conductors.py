"""The spans' sag following their temperature in a run: build/runs/<scenario>/
conductors.usda, a layer over the scene stage whose /Site/Conductors/<span> prims get
time-sampled `points` (and `extent`) at every step where the temperature changed.

Each span leaves the scene at the tension and temperature conductors.json records;
the change-of-state equation gives its tension at the run's temperature (hotter:
longer, lower), and its polyline keeps the segment count of the LOD the scene chose
(the curve count of the BasisCurves stays valid). The layer's opinions are local ones
in the stronger layer, so they win over the scene's LOD variant.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..files import atomic_path
from ..geometry import catenary as cat
from ..geometry.wires import bundle_paths

def sdf_choices(conductors_json: Path, temperatures: list[float | None]) -> list[str | None]:
    """Per step, the SDF conductors model a world shows (conductors.json's sdf_variants):
    the variant whose temperature is nearest the step's, or None for the world's own
    as-built model (nearest the build's reference temperature, or no temperature)."""
    record = json.loads(Path(conductors_json).read_text())
    choices = [(float(record["temperature_c"]), None)] + [(v["temperature_c"], v["uri"])
                                                          for v in record.get("sdf_variants", [])]
    out = []
    for temp in temperatures:
        out.append(None if temp is None else min(choices, key=lambda c: (abs(c[0] - temp), c[0]))[1])
    return out


def span_paths(span: dict, types: dict, temperature_c: float) -> tuple[list[np.ndarray], float]:
    """The span's subconductor polylines (relative to its first end) at
    `temperature_c`, with the chosen LOD's segment count, and its sag (m)."""
    t = types[span["type"]]
    p0, p1 = np.array(span["from"]["enu"]), np.array(span["to"]["enu"])
    w = span["weight_n_per_m"]
    ea = t["ea_n"] * t["bundle_count"]
    H = cat.change_of_state(p0, p1, w, ea, t["alpha_per_k"], span["tension_n"], span["temperature_c"], temperature_c)
    curve = cat.from_tension(p0, p1, H, w)
    pts = cat.points(curve, span["lods"][span["lod"]]["segments"])
    paths = bundle_paths(pts, curve.direction, np.array(t["bundle_offsets_m"]))
    return [p - p0 for p in paths], cat.sag(curve)


def span_points(span: dict, types: dict, temperature_c: float) -> tuple[np.ndarray, float]:
    """span_paths, bundle after bundle in one (n, 3) array, and the sag."""
    paths, sag = span_paths(span, types, temperature_c)
    return np.concatenate(paths), sag


def write(conductors_json: Path, scene_usda: Path, out_path: Path, times: list[float],
          temperatures: list[float | None], step_s: float) -> dict:
    """conductors.usda for the steps with a temperature; a summary."""
    from pxr import Gf, Sdf, Vt

    record = json.loads(Path(conductors_json).read_text())
    spans, types = record["spans"], record["types"]
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append(os.path.relpath(scene_usda, Path(out_path).parent))
    # a root layer states its own stage metadata (the sublayer's is not read from it)
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    layer.pseudoRoot.SetInfo("upAxis", "Z")
    layer.defaultPrim = "Site"
    layer.timeCodesPerSecond = 1.0 / step_s
    layer.startTimeCode, layer.endTimeCode = 0, max(len(times) - 1, 0)
    T = Sdf.ValueTypeNames
    prims = {}
    for s in spans:
        prim = Sdf.CreatePrimInLayer(layer, s["usd_path"])
        prims[s["id"]] = (Sdf.AttributeSpec(prim, "points", T.Point3fArray), Sdf.AttributeSpec(prim, "extent", T.Float3Array))
    last, samples, sags = None, 0, []
    for k, temp in enumerate(temperatures):
        if temp is None or (last is not None and temp == last):
            continue
        last = temp
        worst = 0.0
        for s in spans:
            pts, sag = span_points(s, types, float(temp))
            pts32 = pts.astype(np.float32)
            half = types[s["type"]]["diameter_m"] / 2.0
            points, extent = prims[s["id"]]
            layer.SetTimeSample(points.path, float(k), Vt.Vec3fArray.FromNumpy(pts32))
            lo, hi = pts32.min(axis=0) - half, pts32.max(axis=0) + half
            layer.SetTimeSample(extent.path, float(k), Vt.Vec3fArray([Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())]))
            worst = max(worst, sag)
        samples += 1
        sags.append((float(temp), worst))
    with atomic_path(Path(out_path)) as tmp:
        layer.Export(str(tmp))
    return {"file": str(out_path), "spans": len(spans), "samples": samples,
            "temperature_c": [min(t for t, _ in sags), max(t for t, _ in sags)] if sags else None,
            "largest_sag_m": [round(s, 6) for _, s in (min(sags), max(sags))] if sags else None}



def write_gltf(conductors_json: Path, out_path: Path, times: list[float], temperatures: list[float | None]) -> dict:
    """conductors.glb: a tube mesh per span (node named by its id) whose shape at each
    distinct temperature of the run is a morph target (the first temperature is the
    base), chosen step by step by a STEP `weights` animation "twin:conductors"."""
    from .. import glb
    from ..geometry.wires import tube

    record = json.loads(Path(conductors_json).read_text())
    spans, types = record["spans"], record["types"]
    steps = [(float(t), float(v)) for t, v in zip(times, temperatures) if v is not None]
    distinct = sorted({v for _, v in steps}, key=[v for _, v in steps].index)
    which = [distinct.index(v) for _, v in steps]
    doc = {"asset": {"version": "2.0", "generator": "substation-twin"}, "scene": 0, "scenes": [{"nodes": []}],
           "nodes": [], "meshes": [], "accessors": [], "bufferViews": [], "buffers": [], "animations": [],
           "materials": [{"name": "conductor_aluminium", "pbrMetallicRoughness": {
               "baseColorFactor": [0.62, 0.63, 0.64, 1.0], "metallicFactor": 0.9, "roughnessFactor": 0.45}}]}
    buf = glb.Buffer(doc["bufferViews"], doc["accessors"])
    channels, samplers = [], []
    step_times = buf.add_accessor(np.array([t for t, _ in steps], dtype=np.float32), "SCALAR", bounds=True)
    for s in spans:
        radius = types[s["type"]]["diameter_m"] / 2.0
        shapes, faces = [], None
        for temp in distinct:
            parts = [tube(p, radius, 6) for p in span_paths(s, types, temp)[0]]
            shapes.append(np.concatenate([v for v, _, _ in parts]))
            if faces is None:
                base, faces = 0, []
                for v, f, _ in parts:
                    faces.append(f + base)
                    base += len(v)
                normals = np.concatenate([n for _, _, n in parts])
        y_up = [glb.points_to_y_up(v).astype(np.float32) for v in shapes]
        prim = {"attributes": {"POSITION": buf.add_accessor(y_up[0], "VEC3", 34962, bounds=True),
                               "NORMAL": buf.add_accessor(glb.points_to_y_up(normals).astype(np.float32), "VEC3", 34962)},
                "indices": buf.add_accessor(np.concatenate(faces).reshape(-1).astype(np.uint32), "SCALAR", 34963),
                "material": 0, "mode": 4}
        if len(y_up) > 1:
            prim["targets"] = [{"POSITION": buf.add_accessor(v - y_up[0], "VEC3", 34962, bounds=True)} for v in y_up[1:]]
        mesh = {"name": s["id"], "primitives": [prim]}
        if len(y_up) > 1:
            mesh["weights"] = [0.0] * (len(y_up) - 1)
        doc["meshes"].append(mesh)
        doc["nodes"].append({"name": s["id"], "mesh": len(doc["meshes"]) - 1,
                             "translation": [float(c) for c in glb.points_to_y_up(np.array([s["from"]["enu"]]))[0]]})
        doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
        if len(y_up) > 1:
            weights = np.zeros((len(steps), len(y_up) - 1), dtype=np.float32)
            for k, j in enumerate(which):
                if j > 0:
                    weights[k, j - 1] = 1.0
            samplers.append({"input": step_times, "output": buf.add_accessor(weights.reshape(-1), "SCALAR"),
                             "interpolation": "STEP"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": len(doc["nodes"]) - 1, "path": "weights"}})
    if channels:
        doc["animations"].append({"name": "twin:conductors", "channels": channels, "samplers": samplers,
                                  "extras": {"temperature_c": distinct}})
    else:
        del doc["animations"]
    doc["buffers"] = [{"byteLength": glb.padded_length(buf.binary)}]
    glb.write(out_path, doc, bytes(buf.binary))
    return {"file": str(out_path), "spans": len(spans), "shapes": len(distinct)}
