"""`twin serve` renders the conductors: a span strung across the live camera's view of
the tiny live scene is in a render request's picture and labels, at the temperature
the live graph's conductor_thermal node gives its group (its conductor type)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import live_scene
from wire_scenario import thermal_wire

HEAT = """
[scenario]
name = "heat"
seed = 1
duration_s = 60.0
step_s = 1.0
start = "2025-03-20T12:00:00-03:00"

[[nodes]]
id = "load"
type = "constant"
params = { value = 900.0, unit = "A" }

[[nodes]]
id = "render"
type = "render"
""" + thermal_wire("load.value")


def _strung_across(pose: np.ndarray, ahead: float, half: float) -> dict:
    """conductors.json with one span `ahead` metres in front of the camera, level,
    `half` metres to either side, between R-1 and R-2's (made-up) terminals."""
    from pipeline.geometry import catenary as cat

    centre = pose[:3, 3] - ahead * pose[:3, 2]
    p0, p1 = centre - half * pose[:3, 0], centre + half * pose[:3, 0]
    w = 1.6 * 9.80665
    curve = cat.from_sag(p0, p1, 0.01 * 2 * half)
    span = {"id": "R-1.a~R-2.a", "type": "T", "from": {"terminal": "R-1.a", "enu": p0.tolist()},
            "to": {"terminal": "R-2.a", "enu": p1.tolist()}, "tension_n": curve.a * w, "weight_n_per_m": w,
            "temperature_c": 25.0, "lod": 0, "lods": [{"segments": 16}]}
    types = {"T": {"diameter_m": 0.03, "ea_n": 3.0e7, "alpha_per_k": 2.0e-5, "bundle_count": 1,
                   "bundle_offsets_m": [[0.0, 0.0]]}}
    return {"temperature_c": 25.0, "types": types, "spans": [span]}


@pytest.mark.blender
def test_a_live_render_shows_and_labels_the_wires_at_the_graphs_temperature(tmp_path):
    pytest.importorskip("bpy")
    from pipeline.live.app import make_server, sensor_of
    from pipeline.live.render_worker import RenderJob, RenderWorker

    build, sources, config = live_scene.make(tmp_path)
    scenario = tmp_path / "heat.toml"
    scenario.write_text(HEAT)
    twin = make_server(build, sources, scenario, port=0, sensor=config, render=False, foxglove=False).twin
    twin.advance(2)
    temperature = twin.get(["wire.temperature"])["wire.temperature"]
    assert temperature > 40.0
    cam, _, _ = sensor_of(config)
    # conductors.json before the twin: its groups (a type each) take the scenario's temperature
    (build / "scene" / "conductors.json").write_text(json.dumps(_strung_across(twin.camera.pose, 8.0, 4.0)))
    twin = make_server(build, sources, scenario, port=0, sensor=config, render=False, foxglove=False).twin
    twin.advance(2)
    plan = twin.frame_plan(cam.width, cam.height, seed=3)
    assert plan.shot.conductor_temperature_c == {"T": temperature}
    worker = RenderWorker(RenderJob(str(build), str(sources), cam, 1))
    try:
        out = worker.render(plan, mask=True, depth=False)
    finally:
        worker.close()
    mask = cv2.imdecode(np.frombuffer(out["mask"], np.uint8), cv2.IMREAD_UNCHANGED)
    iid = 3  # after the two placements
    assert (mask == iid).sum() > 10
    wires = out["record"]["conductors"]
    assert (wires["temperature_c"], wires["temperature_from"]) == ({"T": temperature}, "state")
    assert [(s["instance_id"], s["span"], s["tags"]) for s in wires["spans"]] == [(iid, "R-1.a~R-2.a", ["R-1", "R-2"])]
    assert any(a.get("span") == "R-1.a~R-2.a" and a["instance_id"] == iid for a in out["record"]["annotations"])
