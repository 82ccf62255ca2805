"""`twin render SCENARIO`: a scenario's steps as shots from the inspection point that
targets the placement its render node drives."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from ..runtime import camera as camera_model
from .frames import render_shots, write_json
from ..perception.gauge import placed_dial
from ..geometry.pinhole import look_at
from .sensor import PhoneCamera
from ..runtime.site import Shot, BuiltSite, load_site

def scenario_shots(scenario_path: Path, site: BuiltSite, every: int = 1) -> tuple[object, list[Shot]]:
    """Run the scenario's graph and turn each (every-th) step into a Shot: camera at the
    inspection point whose target is the placement the render node drives, looking at
    its main-tank gauge; zoom, sun and states from the graph's nodes."""
    from ..errors import UserError
    from ..runtime import graph, run

    scenario = graph.load_scenario(scenario_path, site.zone)
    observed = run.load_observed(site.build)
    data, records = run.simulate(scenario, observed)
    fed = sorted({vs.tag for frame in data.frames for vs in frame})
    if not fed:
        raise UserError(scenario.path, "edges", "the render node drives no built placement")
    target = fed[0]
    point = next((p for p in site.inspection.values() if p["target"] == target), None)
    if point is None:
        raise UserError(scenario.path, target, "no inspection point in site.toml targets this placement")
    dial = placed_dial(site, target)
    if dial is None:
        raise UserError(scenario.path, target, "the placement the render node drives has no gauge to look at")
    pose = look_at(point["enu"], dial.centre)
    cams = sorted(n["id"] for n in scenario.nodes if n["type"] == "camera")
    shots = []
    for i, (t, frame, rec) in enumerate(zip(data.times, data.frames, records)):
        if i % every:
            continue
        out = rec["outputs"]
        zoom = out.get(f"{cams[0]}.zoom", 1.0) if cams else 1.0
        el, az, irr = data.sun[i] if data.sun else (-1.0, 0.0, 0.0)
        states = {}
        for ob in observed:
            vals = {o.binding["variable"]: o.value for vs in frame if vs.tag == ob.tag for o in vs.outputs}
            if vals:
                states[ob.tag] = vals
        when = (scenario.start + dt.timedelta(seconds=t)).astimezone(scenario.zone)
        wires = data.conductor_temperature[i] if data.conductor_temperature else None
        shots.append(Shot(when, pose, camera_model.lens(zoom), el, az, irr,
                          states, frame, target, wires))
    return scenario, shots


def render_scenario(scenario_path, out, sources: Path, *, cam: PhoneCamera | None = None, every: int = 1,
                    progress=None) -> Path:
    """`twin render SCENARIO`: frames, labels and a dataset manifest in
    out/runs/<scenario>/render/. Returns the manifest's path."""
    cam = cam or PhoneCamera()
    site = load_site(Path(out), sources)
    scenario, shots = scenario_shots(Path(scenario_path), site, every)
    folder = Path(out) / "runs" / scenario.name / "render"
    records = render_shots(site, shots, folder, cam=cam, seed=scenario.seed, progress=progress)
    return dataset_manifest(folder, scenario.name, scenario.seed, cam, records)


def dataset_manifest(folder: Path, name: str, seed: int, cam: PhoneCamera, records: list[dict]) -> Path:
    data = {"dataset": name, "seed": seed, "renderer": "blender-cycles-cpu", "camera": cam.__dict__,
            "frames": [{"image": r["image"], "labels": r["image"][:-4] + ".json", "sha256": r["sha256"],
                        "time": r["labels"]["time"]} for r in records]}
    write_json(folder / "dataset.json", data)
    return folder / "dataset.json"
