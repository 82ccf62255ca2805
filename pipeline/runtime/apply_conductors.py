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

def span_points(span: dict, types: dict, temperature_c: float) -> tuple[np.ndarray, float]:
    """The span's polyline paths (bundle after bundle, relative to its first end) at
    `temperature_c`, with the chosen LOD's segment count, and its sag (m)."""
    t = types[span["type"]]
    p0, p1 = np.array(span["from"]["enu"]), np.array(span["to"]["enu"])
    w = span["weight_n_per_m"]
    ea = t["ea_n"] * t["bundle_count"]
    H = cat.change_of_state(p0, p1, w, ea, t["alpha_per_k"], span["tension_n"], span["temperature_c"], temperature_c)
    curve = cat.from_tension(p0, p1, H, w)
    pts = cat.points(curve, span["lods"][span["lod"]]["segments"])
    paths = bundle_paths(pts, curve.direction, np.array(t["bundle_offsets_m"]))
    return np.concatenate([p - p0 for p in paths]), cat.sag(curve)


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

