"""What robotics tools read: MCAP recordings (the `mcap` writer) and Foxglove's live
WebSocket protocol (foxglove-sdk), both with Foxglove's message schemas in JSON encoding:

    /tf            foxglove.FrameTransforms: every placement in the ENU frame, every moving
                   part (a bound visual) in its placement's, and the camera
    /twin/state    the published message (seq, sim_time, wall_time, values), schemas/live
    /camera/image  foxglove.CompressedImage: each rendered frame, PNG
    /conductors    foxglove.SceneUpdate: a line strip per span (its bundle centre, ENU),
                   sent when a conductor group's temperature changes its sag

Message times are simulated time (ns since the Unix epoch): a recording plays back on
the twin's clock."""

from __future__ import annotations

import base64
import datetime as dt
import json
from pathlib import Path

import numpy as np

from .protocol import schema as live_schema

WORLD = "enu"


def _xyz(names: str) -> dict:
    return {"type": "object", "properties": {n: {"type": "number"} for n in names}}


_TIME = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                          "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
# Foxglove's message definitions (foxglove.FrameTransform(s), foxglove.CompressedImage)
# written as JSON Schemas; `bytes` fields are base64 strings in JSON encoding.
FRAME_TRANSFORM = {"title": "foxglove.FrameTransform", "type": "object", "properties": {
    "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
    "translation": _xyz("xyz"), "rotation": _xyz("xyzw")}}
SCHEMAS = {
    "foxglove.FrameTransforms": {"title": "foxglove.FrameTransforms", "type": "object",
                                 "properties": {"transforms": {"type": "array", "items": FRAME_TRANSFORM}}},
    "foxglove.CompressedImage": {"title": "foxglove.CompressedImage", "type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"}, "format": {"type": "string"}}},
}
_COLOR = {"type": "object", "properties": {n: {"type": "number"} for n in "rgba"}}
_POSE = {"type": "object", "properties": {"position": _xyz("xyz"), "orientation": _xyz("xyzw")}}
LINE_STRIP = 0  # foxglove.LineType
SCHEMAS["foxglove.SceneUpdate"] = {"title": "foxglove.SceneUpdate", "type": "object", "properties": {
    "deletions": {"type": "array", "items": {"type": "object"}},
    "entities": {"type": "array", "items": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": _TIME, "frame_locked": {"type": "boolean"},
        "metadata": {"type": "array", "items": {"type": "object", "properties": {
            "key": {"type": "string"}, "value": {"type": "string"}}}},
        "lines": {"type": "array", "items": {"type": "object", "properties": {
            "type": {"type": "integer"}, "pose": _POSE, "thickness": {"type": "number"},
            "scale_invisible": {"type": "boolean"}, "points": {"type": "array", "items": _xyz("xyz")},
            "color": _COLOR, "colors": {"type": "array", "items": _COLOR},
            "indices": {"type": "array", "items": {"type": "integer"}}}}}}}}}}
TOPICS = {"/tf": "foxglove.FrameTransforms", "/twin/state": "substation_twin.State",
          "/camera/image": "foxglove.CompressedImage", "/conductors": "foxglove.SceneUpdate"}
WIRE_PX = 2.0  # a 30 mm conductor is under a pixel from most views: the line is drawn in pixels
WIRE_COLOUR = {"r": 0.85, "g": 0.55, "b": 0.2, "a": 1.0}


def state_schema() -> dict:
    doc = live_schema()
    return {**doc["$defs"]["published"], "title": "substation_twin.State", "$defs": doc["$defs"]}


def schema_of(name: str) -> dict:
    return state_schema() if name == "substation_twin.State" else SCHEMAS[name]


def ns(when: dt.datetime) -> int:
    return int(round(when.timestamp() * 1e9))


def stamp(t_ns: int) -> dict:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def transform(parent: str, child: str, m: np.ndarray, t_ns: int) -> dict:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(m, float)[:3, :3]).as_quat()  # x, y, z, w
    x, y, z = (float(v) for v in np.asarray(m, float)[:3, 3])
    return {"timestamp": stamp(t_ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": {"x": x, "y": y, "z": z},
            "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}


def link_pose(manifest: dict, link: str) -> np.ndarray:
    for rec in manifest.get("links", []):
        if rec["name"] == link:
            return np.array(rec["pose"], float).reshape(4, 4)
    return np.eye(4)


def frame_transforms(site, visual_states, t_ns: int, camera_pose=None, placements: bool = False) -> dict:
    """foxglove.FrameTransforms: the moving parts (child "TAG/link/visual" of "TAG"), the
    camera (child "camera" of "enu"), and with `placements` every placement ("TAG" of "enu")."""
    out = []
    if placements:
        out += [transform(WORLD, p["tag"], site.pose(p), t_ns) for p in site.placements]
    for vs in visual_states:
        m = site.manifests[site.placement(vs.tag)["asset"]]
        out.append(transform(vs.tag, f"{vs.tag}/{vs.link}/{vs.visual}", link_pose(m, vs.link) @ vs.transform, t_ns))
    if camera_pose is not None:
        out.append(transform(WORLD, "camera", camera_pose, t_ns))
    return {"transforms": out}


def conductor_scene(wires, temperatures: dict, t_ns: int) -> dict:
    """foxglove.SceneUpdate: an entity per span (id: the span id) with its line strip at
    its group's temperature (`temperatures`: type -> degC or None) and its sag."""
    entities = []
    for name, spans in sorted(wires.groups.items()):
        temp, sags = temperatures[name], wires.sags(name, temperatures[name])
        for s in spans:
            pts = wires.polyline(s, temp)
            entities.append({
                "timestamp": stamp(t_ns), "frame_id": WORLD, "id": s["id"], "lifetime": stamp(0), "frame_locked": False,
                "metadata": [{"key": "type", "value": name}, {"key": "sag_m", "value": f"{sags[s['id']]:.6f}"},
                             {"key": "temperature_c", "value": "as built" if temp is None else f"{temp:.3f}"}],
                "lines": [{"type": LINE_STRIP, "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                                                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                           "thickness": WIRE_PX, "scale_invisible": True,
                           "points": [{"x": float(x), "y": float(y), "z": float(z)} for x, y, z in pts],
                           "color": WIRE_COLOUR, "colors": [], "indices": []}]})
    return {"deletions": [], "entities": entities}


class McapLog:
    """An MCAP file of the three topics; `log(topic, message dict, t_ns)`."""

    def __init__(self, path: Path):
        from mcap.writer import Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "wb")
        self.writer = Writer(self._fh)
        self.writer.start(profile="", library="substation-twin")
        self.channels, self.seq = {}, 0
        for topic, name in TOPICS.items():
            sid = self.writer.register_schema(name=name, encoding="jsonschema",
                                              data=json.dumps(schema_of(name), sort_keys=True).encode())
            self.channels[topic] = self.writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)

    def log(self, topic: str, message: dict, t_ns: int) -> None:
        self.seq += 1
        self.writer.add_message(self.channels[topic], log_time=t_ns, publish_time=t_ns, sequence=self.seq,
                                data=json.dumps(message, separators=(",", ":"), allow_nan=False).encode())

    def close(self) -> None:
        if self._fh is not None:
            self.writer.finish()
            self._fh.close()
            self._fh = None


class FoxgloveLive:
    """Foxglove's live WebSocket protocol (foxglove-sdk's server) on the same topics."""

    def __init__(self, host: str, port: int):
        import foxglove

        self.server = foxglove.start_server(name="substation-twin", host=host, port=port)
        self.channels = {topic: foxglove.Channel(topic, schema=schema_of(name), message_encoding="json")
                         for topic, name in TOPICS.items()}

    @property
    def port(self) -> int:
        return self.server.port

    def log(self, topic: str, message: dict, t_ns: int) -> None:
        self.channels[topic].log(message, log_time=t_ns)

    def close(self) -> None:
        self.server.stop()


class Recorder:
    """The live twin's sinks for robotics tools (an McapLog, a FoxgloveLive or both):
    each published step's state and moving parts, each render's image."""

    def __init__(self, twin, sinks: list):
        self.twin, self.sinks = twin, sinks
        self._placed = False
        self._last = None
        self._wires_last = None

    def state(self, twin, msg: dict) -> None:
        t_ns = ns(dt.datetime.fromisoformat(msg["sim_time"]))
        for s in self.sinks:
            s.log("/twin/state", msg, t_ns)
        values = twin.graph.nodes[twin.render_id].values if twin.render_id else {}
        key = (json.dumps(values, sort_keys=True), twin.camera.pose.tobytes())
        if key != self._last:  # transforms only when a part or the camera moved
            self._last = key
            tf = frame_transforms(twin.site, twin.mapper.states(values), t_ns, twin.camera.pose,
                                  placements=not self._placed)
            self._placed = True
            for s in self.sinks:
                s.log("/tf", tf, t_ns)
        if twin.wires is not None:
            temperatures = twin.wires.temperatures(values)
            if temperatures != self._wires_last:  # the lines only when a sag changed
                self._wires_last = temperatures
                scene = conductor_scene(twin.wires, temperatures, t_ns)
                for s in self.sinks:
                    s.log("/conductors", scene, t_ns)

    def image(self, plan, png: bytes) -> None:
        t_ns = ns(plan.shot.when)
        msg = {"timestamp": stamp(t_ns), "frame_id": "camera", "format": "png",
               "data": base64.b64encode(png).decode("ascii")}
        for s in self.sinks:
            s.log("/camera/image", msg, t_ns)

    def close(self) -> None:
        for s in self.sinks:
            s.close()


def record_run(scenario_path: Path, build: Path, path: Path) -> dict:
    """`twin run --record`: the scenario's states and moving parts, step by step, as MCAP
    (runtime.run.simulate, as `twin run` steps it)."""
    from ..runtime import graph
    from ..runtime.run import load_observed, scene_zone, simulate
    from ..runtime.site import load_site

    build = Path(build)
    scenario = graph.load_scenario(scenario_path, scene_zone(build))
    data, records = simulate(scenario, load_observed(build))
    site = load_site(build, build)  # poses and manifests only: no site.toml needed
    log = McapLog(path)
    try:
        for i, (r, states) in enumerate(zip(records, data.frames)):
            when = scenario.start + dt.timedelta(seconds=r["t"])
            t_ns = ns(when)
            msg = {"seq": r["k"], "k": r["k"], "sim_time": when.astimezone(scenario.zone or dt.timezone.utc).isoformat(),
                   "wall_time": when.isoformat(), "values": r["outputs"]}
            log.log("/twin/state", msg, t_ns)
            log.log("/tf", frame_transforms(site, states, t_ns, placements=i == 0), t_ns)
    finally:
        log.close()
    return {"mcap": str(path), "messages": log.seq}
