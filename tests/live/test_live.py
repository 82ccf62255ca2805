"""`twin serve` driven as a robot team's software would: a ZeroMQ client on the command
socket and a subscriber on the PUB socket, against a tiny built scene (live_scene.py),
and a render compared byte for byte with `twin dataset`'s frame of the same camera,
instant, state and seed."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq

import live_scene
from pipeline.live import protocol

from helpers import ROOT, unavailable
START = "2025-03-20T09:00:00"  # the site's wall clock (America/Bahia, -03:00)


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")])}


def start_twin(build: Path, sources: Path, *args) -> tuple[subprocess.Popen, dict]:
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "serve", "--out", str(build), "--sources",
                             str(sources), "--port", "0", *map(str, args)], cwd=ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if not line:
        proc.wait(10)
        raise AssertionError(proc.stderr.read()[-3000:])
    return proc, json.loads(line)


class Client:
    """A REQ client: one request, one reply (a render reply's further frames kept)."""

    def __init__(self, endpoint: str, timeout_ms: int = 120000):
        self.ctx = zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.REQ)
        self.sock.setsockopt(zmq.RCVTIMEO, timeout_ms)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)
        self.frames: list[bytes] = []

    def raw(self, data: bytes) -> dict:
        self.sock.send(data)
        reply, *self.frames = self.sock.recv_multipart()
        return json.loads(reply)

    def __call__(self, cmd: str, **kw) -> dict:
        reply = self.raw(json.dumps({"cmd": cmd, **kw}).encode())
        protocol.check("error" if not reply["ok"] else f"reply_{cmd}", reply)
        return reply

    def close(self):
        self.sock.close()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return live_scene.make(tmp_path_factory.mktemp("live"))


@pytest.fixture(scope="module")
def twin(scene):
    build, sources, config = scene
    proc, endpoints = start_twin(build, sources, "--sensor", config, "--start", START)
    client = Client(endpoints["commands"])
    yield proc, endpoints, client
    client.close()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        finally:
            if proc.poll() is None:  # never leave a twin behind, whatever failed
                proc.kill()
                proc.wait(10)


def test_hello_describes_the_twin(twin):
    _, endpoints, c = twin
    h = c("hello")
    assert h["endpoints"] == endpoints
    assert h["site"]["timezone"] == "America/Bahia"
    ports = {p["name"]: p for p in h["ports"]}
    tank = ports["render.reactor_A1.oil_level_tank"]
    assert (tank["type"], tank["unit"], tank["settable"], tank["range"]) == ("float", "%", True, [0.0, 100.0])
    assert ports["sun.elevation"]["unit"] == "rad" and not ports["sun.elevation"]["settable"]
    assert {"clock", "sun", "render", "camera"} <= {n["id"] for n in h["nodes"]}
    assert h["cameras"]["presets"] == ["R-2>R-1"]
    assert h["versions"]["pyzmq"] and h["scene"]["sensor"]["width"] == 48


def test_get_all_or_named_ports_and_unknown_ones_are_named(twin):
    _, _, c = twin
    everything = c("get")["values"]
    assert everything["render.reactor_A1.oil_level_tank"] is not None and "sun.azimuth" in everything
    one = c("get", ports=["sun.elevation"])
    assert list(one["values"]) == ["sun.elevation"] and one["sim_time"].startswith("2025-03-20T")
    bad = c("get", ports=["sun.colour"])
    assert not bad["ok"] and "'sun.colour'" in bad["error"] and "unknown port" in bad["error"]
    bad = c("get", ports=["moon.elevation"])
    assert not bad["ok"] and "unknown node 'moon'" in bad["error"]


def _subscriber(endpoint: str):
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.RCVTIMEO, 5000)
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(endpoint)
    time.sleep(0.3)  # the subscription reaches the publisher
    return sub


def test_set_is_typed_and_unit_checked_and_published(twin):
    _, endpoints, c = twin
    sub = _subscriber(endpoints["publish"])
    try:
        ok = c("set", values={"render.reactor_A1.oil_level_tank": {"value": 42.5, "unit": "%"}})
        assert ok["values"] == {"render.reactor_A1.oil_level_tank": 42.5}
        deadline, seen = time.monotonic() + 5, None
        while time.monotonic() < deadline:
            msg = json.loads(sub.recv())
            protocol.check("published", msg)
            if "render.reactor_A1.oil_level_tank" in msg["values"]:
                seen = msg
                break
        assert seen is not None and seen["values"]["render.reactor_A1.oil_level_tank"] == 42.5
        assert seen["sim_time"].endswith("-03:00") and seen["seq"] >= ok["seq"] - 1
        assert c("get", ports=["render.reactor_A1.oil_level_tank"])["values"] == {
            "render.reactor_A1.oil_level_tank": 42.5}
    finally:
        sub.close()
    for values, words in [
        ({"render.reactor_A1.oil_level_tank": {"value": 40, "unit": "degC"}}, ["oil_level_tank", "unit mismatch", "degC"]),
        ({"render.reactor_A1.oil_level_tank": "full"}, ["oil_level_tank", "expected a float", "'full'"]),
        ({"render.reactor_A1.oil_level_tank": 140}, ["oil_level_tank", "out of range", "[0, 100]"]),
        ({"render.reactor_A1.oil_level_tank": True}, ["expected a float"]),
        ({"sun.elevation": 0.5}, ["sun.elevation", "output"]),
        ({"render.reactor_A9.oil_level_tank": 5}, ["unknown port", "reactor_A9"]),
        ({"aerosol.value": 11}, ["aerosol.value", "out of range"]),
    ]:
        bad = c("set", values=values)
        assert not bad["ok"] and all(w in bad["error"] for w in words), (values, bad)
    # a bad value among good ones changes nothing
    bad = c("set", values={"render.reactor_A2.oil_level_tank": 10, "render.reactor_A1.oil_level_tank": -1})
    assert not bad["ok"]
    assert c("get", ports=["render.reactor_A2.oil_level_tank"])["values"]["render.reactor_A2.oil_level_tank"] == 100.0


def _sim(c) -> float:
    from datetime import datetime

    return datetime.fromisoformat(c("clock", action="status")["clock"]["sim_time"]).timestamp()


def test_clock_pauses_resumes_changes_speed_and_seeks(twin):
    _, _, c = twin
    paused = c("clock", action="pause")["clock"]
    assert paused["paused"]
    t0 = _sim(c)
    time.sleep(0.3)
    assert _sim(c) == t0
    c("clock", action="speed", speed=20.0)
    c("clock", action="resume")
    w0, s0 = time.monotonic(), _sim(c)
    time.sleep(0.5)
    rate = (_sim(c) - s0) / (time.monotonic() - w0)
    assert 12.0 < rate < 21.0, rate  # simulated seconds per real second
    seek = c("clock", action="seek", to="2025-03-20T13:30:00")["clock"]
    assert seek["step_time"] == "2025-03-20T13:30:00-03:00" or seek["step_time"] > "2025-03-20T13:30:00"
    c("clock", action="pause")
    c("clock", action="seek", to="2025-03-20T12:00:00-03:00")
    status = c("clock", action="status")["clock"]
    assert status["step_time"] == "2025-03-20T12:00:00-03:00" and status["paused"]
    sun = c("get", ports=["sun.elevation"])["values"]["sun.elevation"]
    assert math.degrees(sun) > 70.0  # noon near the equinox at 12.7 S
    for kw, words in [({"action": "seek", "to": "2025-03-19T12:00:00"}, ["before the run's start"]),
                      ({"action": "seek", "to": "noon"}, ["'noon'", "ISO 8601"]),
                      ({"action": "speed", "speed": -1}, ["speed"]),
                      ({"action": "seek"}, ["'to' is a required property"]),
                      ({"action": "rewind"}, ["'rewind'"])]:
        bad = c("clock", **kw)
        assert not bad["ok"] and all(w in bad["error"] for w in words), (kw, bad)
    c("clock", action="speed", speed=1.0)


def test_camera_presets_poses_and_zoom(twin):
    _, _, c = twin
    cam = c("camera", preset="R-2>R-1")["camera"]
    assert cam["name"] == "ptz:R-2>R-1" and cam["zoom"] == 2.0 and cam["target"] == "R-1"
    cam = c("camera", zoom=45.0)["camera"]
    assert cam["hfov_deg"] == pytest.approx(math.degrees(1.047 / 45)) and not cam["optical"]
    assert cam["near"] == pytest.approx(0.1 + 0.01 * 35) and cam["far"] == pytest.approx(1000 - 10 * 35)
    assert c("get", ports=["camera.zoom"])["values"]["camera.zoom"] == 45.0
    cam = c("camera", eye=[0.0, -6.0, 1.5], look_at=[0.0, 0.0, 1.0], zoom=1.0)["camera"]
    assert cam["name"] == "pose" and cam["pose"][3] == 0.0 and cam["pose"][7] == -6.0
    for kw, words in [({"zoom": 150}, ["zoom", "100"]), ({"preset": "R-9>R-1"}, ["unknown PTZ preset", "R-9>R-1"]),
                      ({"point": "roof"}, ["unknown inspection point", "'roof'"]),
                      ({"pose": [1.0] * 16}, ["not a rigid"]), ({"pose": [0.0] * 16, "target": "Q-7"}, ["Q-7"])]:
        bad = c("camera", **kw)
        assert not bad["ok"] and all(w in bad["error"] for w in words), (kw, bad)
    assert c("camera")["camera"]["name"] == "pose"  # unchanged by the failures


def test_the_websocket_carries_a_snapshot_then_the_published_messages(twin):
    from websockets.sync.client import connect

    _, endpoints, c = twin
    with connect(endpoints["websocket"]) as ws:
        snapshot = json.loads(ws.recv(timeout=5))
        protocol.check("published", snapshot)
        assert set(snapshot["values"]) == {p["name"] for p in c("hello")["ports"]}
        c("set", values={"render.reactor_A2.oil_level_b1": 33.0})
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            msg = json.loads(ws.recv(timeout=5))
            protocol.check("published", msg)
            if "render.reactor_A2.oil_level_b1" in msg["values"]:
                break
        assert msg["values"]["render.reactor_A2.oil_level_b1"] == 33.0 and msg["seq"] > snapshot["seq"]
    import urllib.request

    with urllib.request.urlopen(endpoints["page"], timeout=10) as r:
        assert b"/hello.json" in r.read() and r.headers["Content-Type"].startswith("text/html")


def test_malformed_input_gets_an_error_and_the_twin_goes_on(twin):
    _, endpoints, c = twin
    for raw, words in [(b"{", ["malformed JSON"]), (b"\xff\xfe", ["malformed JSON"]), (b"[1, 2]", ["JSON object"]),
                       (b'{"cmd": "fly"}', ["unknown command 'fly'"]), (b'{"ports": []}', ['missing "cmd"']),
                       (b'{"cmd": "get", "ports": "sun.elevation"}', ["get", "ports"])]:
        reply = c.raw(raw)
        protocol.check("error", reply)
        assert all(w in reply["error"] for w in words), (raw, reply)
    # two frames where one is expected
    c.sock.send_multipart([b'{"cmd": "hello"}', b"extra"])
    reply = json.loads(c.sock.recv_multipart()[0])
    assert not reply["ok"] and "one frame" in reply["error"]
    # a client that vanishes with a request in flight
    d = zmq.Context.instance().socket(zmq.DEALER)
    d.setsockopt(zmq.LINGER, 0)
    d.connect(endpoints["commands"])
    d.send_multipart([b"", b'{"cmd": "render"}'])
    time.sleep(0.5)  # the request is in; the client goes before its reply
    d.close()
    assert c("hello")["ok"]


def test_a_render_is_the_datasets_frame_byte_for_byte(twin, scene):
    """The dataset's frame 0, reproduced live: its instant, camera pose, zoom and target,
    oil levels, sky and seed set through the protocol."""
    build, sources, config = scene
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "dataset", str(config), "--out", str(build),
                           "--sources", str(sources)], cwd=ROOT, env=_env(), capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder = build / "datasets" / "live"
    record = json.loads((folder / "records" / "000000.json").read_text())
    _, _, c = twin
    c("clock", action="pause")
    assert c("clock", action="seek", to=record["local_time"])["clock"]["step_time"] == record["local_time"]
    cam = record["camera"]
    # the dataset's PTZ preset by its name: the same pose, zoom and target
    assert cam["name"] == "ptz:R-2>R-1"
    live_cam = c("camera", preset="R-2>R-1")["camera"]
    assert live_cam["pose"] == [v for row in cam["pose"] for v in row] and live_cam["zoom"] == cam["zoom"]
    state_of = {"R-1": "reactor_A1", "R-2": "reactor_A2"}
    values = {f"render.{state_of[tag]}.{var}": v for tag, levels in record["states"]["oil_levels"].items()
              for var, v in levels.items()}
    values |= {"tau_atm.value": record["sky"]["tau_atm"], "aerosol.value": record["sky"]["aerosol_density"]}
    assert c("set", values=values)["ok"]
    reply = c("render", seed=record["seed"], mask=True, depth=True, labels=True)
    assert reply["ok"], reply
    assert reply["frames"] == ["image/png", "mask/png", "depth/npy"] and len(c.frames) == 3
    png, mask, depth = c.frames
    assert png == (folder / "images" / "000000.png").read_bytes()
    assert mask == (folder / "masks" / "000000.png").read_bytes()
    assert depth == (folder / "depth" / "000000.npy").read_bytes()
    live = reply["labels"]
    for key in ("camera", "sun", "sky", "states", "gauges", "annotations", "local_time", "exposure", "seed"):
        assert live[key] == record[key], key
    # an explicit pose gives the same pixels
    assert c("camera", pose=live_cam["pose"], target="R-1")["ok"]
    assert c("render", seed=record["seed"])["ok"] and c.frames[0] == png
    # a changed state renders another frame, in the same process (no reload)
    pid = c("hello")["stats"]["render_process"]["pid"]
    c("set", values={"render.reactor_A1.oil_level_tank": 5.0 if values["render.reactor_A1.oil_level_tank"] > 50 else 95.0})
    again = c("render", seed=record["seed"])
    assert again["ok"] and c.frames[0] != png
    stats = c("hello")["stats"]
    assert stats["render_process"]["pid"] == pid and stats["render_process"]["starts"] == 1


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    # a zombie still answers kill 0: its state says so
    status = Path(f"/proc/{pid}/status")
    return not status.exists() or "\nState:\tZ" in status.read_text()


def test_a_render_process_that_dies_is_an_error_reply_and_the_next_render_starts_another(twin):
    _, endpoints, c = twin
    # a client that vanishes with a render in flight: its reply is counted as undelivered
    # once that render ends (the twin's first render waits for the scene to load)
    first = c("hello")["stats"]
    before, requests, renders = first["undelivered_replies"], first["requests"], first["renders"]
    d = zmq.Context.instance().socket(zmq.DEALER)
    d.setsockopt(zmq.LINGER, 0)
    d.connect(endpoints["commands"])
    d.send_multipart([b"", b'{"cmd": "render"}'])
    for hellos in range(1, 600):  # the twin has counted the render request: the client may go
        if c("hello")["stats"]["requests"] >= requests + 1 + hellos:
            break
        time.sleep(0.1)
    d.close()
    # its render done (an undelivered reply of an earlier test may be counted meanwhile:
    # a kill before this render ends would fail it, and the next render would be good)
    end = time.monotonic() + 300
    while ((stats := c("hello")["stats"])["undelivered_replies"] <= before or stats["renders"] <= renders) \
            and time.monotonic() < end:
        time.sleep(0.5)
    assert stats["undelivered_replies"] > before and stats["renders"] == renders + 1
    pid = stats["render_process"]["pid"]
    os.kill(pid, signal.SIGKILL)
    bad = c("render")
    assert not bad["ok"] and "render process died" in bad["error"]
    assert c("get", ports=["clock.t"])["ok"]  # the clock goes on
    good = c("render")
    assert good["ok"] and c.frames[0].startswith(b"\x89PNG")
    stats = c("hello")["stats"]
    assert stats["render_failures"] >= 1 and stats["render_process"]["starts"] == 2
    assert stats["render_process"]["pid"] != pid and _gone(pid)


def test_shutdown_ends_the_twin_and_its_blender_process(twin):
    proc, _, c = twin
    pid = c("hello")["stats"]["render_process"]["pid"]
    assert pid and not _gone(pid)
    assert c("shutdown") == {"ok": True}
    assert proc.wait(30) == 0
    assert _gone(pid)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_the_twin_with_no_child_left(scene, sig):
    build, sources, config = scene
    proc, endpoints = start_twin(build, sources, "--sensor", config, "--start", START)
    c = Client(endpoints["commands"])
    try:
        pid = c("hello")["stats"]["render_process"]["pid"]
        assert pid
        proc.send_signal(sig)
        assert proc.wait(30) == 0
        assert _gone(pid)
        assert "Traceback" not in proc.stderr.read()
    finally:
        c.close()
        if proc.poll() is None:
            proc.kill()


# --- robotics tools: MCAP and Foxglove's live protocol ----------------------------------------


def _mcap(path: Path) -> dict[str, list]:
    from mcap.reader import make_reader

    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            out.setdefault(channel.topic, []).append((schema.name, json.loads(schema.data), message.log_time,
                                                      json.loads(message.data)))
    return out


def test_serve_records_mcap_and_speaks_foxglove(scene, tmp_path):
    import asyncio
    import base64

    import websockets

    build, sources, config = scene
    rec = tmp_path / "live.mcap"
    proc, endpoints = start_twin(build, sources, "--sensor", config, "--start", START, "--record", rec)
    c = Client(endpoints["commands"])
    try:
        async def advertised():
            async with websockets.connect(endpoints["foxglove"], subprotocols=["foxglove.sdk.v1"]) as ws:
                topics = {}
                while not {"/tf", "/twin/state", "/camera/image"} <= set(topics):
                    msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
                    if msg.get("op") == "advertise":
                        topics |= {ch["topic"]: ch["schemaName"] for ch in msg["channels"]}
                return topics

        topics = asyncio.run(advertised())
        assert topics["/tf"] == "foxglove.FrameTransforms" and topics["/camera/image"] == "foxglove.CompressedImage"
        c("set", values={"render.reactor_A1.oil_level_tank": 10.0})
        c("set", values={"render.reactor_A1.oil_level_tank": 90.0})
        assert c("render")["ok"]
        png = c.frames[0]
        assert c("shutdown")["ok"] and proc.wait(30) == 0
    finally:
        c.close()
        if proc.poll() is None:
            proc.kill()
    got = _mcap(rec)
    assert set(got) == {"/tf", "/twin/state", "/camera/image"}
    states = [m for *_, m in got["/twin/state"]]
    for m in states:
        protocol.check("published", m)
    assert [m["seq"] for m in states] == sorted(m["seq"] for m in states)
    levels = [m["values"]["render.reactor_A1.oil_level_tank"] for m in states
              if "render.reactor_A1.oil_level_tank" in m["values"]]
    assert levels[-2:] == [10.0, 90.0]
    # the pointer's transform follows the level: two different rotations of R-1's pointer
    pointer = [m for *_, tf in got["/tf"] for m in tf["transforms"] if m["child_frame_id"] == "R-1/body/pointer"]
    assert len({json.dumps(p["rotation"], sort_keys=True) for p in pointer}) >= 2
    first = got["/tf"][0][3]["transforms"]
    assert {("enu", "R-1"), ("enu", "R-2"), ("enu", "camera")} <= {(t["parent_frame_id"], t["child_frame_id"])
                                                                 for t in first}
    (name, _, log_time, image), = got["/camera/image"]
    assert name == "foxglove.CompressedImage" and image["format"] == "png"
    assert base64.b64decode(image["data"]) == png
    assert log_time == (image["timestamp"]["sec"] * 10**9 + image["timestamp"]["nsec"])


def test_twin_run_records_mcap(scene, tmp_path):
    build, _, _ = scene
    scenario = ROOT / "tests" / "live_leak.toml"
    rec = tmp_path / "run.mcap"
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(scenario), "--out", str(build),
                           "--record", str(rec)], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = _mcap(rec)
    states = [m for *_, m in got["/twin/state"]]
    assert len(states) == 11 and states[4]["values"]["tank.level"] == pytest.approx(80.0 * 1.01)
    times = [t for _, _, t, _ in got["/twin/state"]]
    assert times[1] - times[0] == 10**9  # simulated time, 1 s steps
    pointer = [m for *_, tf in got["/tf"] for m in tf["transforms"] if m["child_frame_id"] == "R-1/body/pointer"]
    assert len(pointer) == 11 and pointer[0]["rotation"] != pointer[-1]["rotation"]


# --- the live page in Chromium ----------------------------------------------------------------


@pytest.mark.browser
def test_the_live_page_moves_the_pointer_within_a_second_of_a_set(scene):
    """A `set` of an oil level on the ZeroMQ socket shows as the pointer's new angle in
    the page (Chromium, headless) within 1 s; the angle is the binding's mapping."""
    import shutil

    from pipeline.viewer import check

    lacking = [n for n in check.missing() if n in ("node", "chromium", "playwright-core")]
    if lacking:
        unavailable(f"missing {', '.join(lacking)}: {check.HINT}")
    build, sources, config = scene
    proc, endpoints = start_twin(build, sources, "--sensor", config, "--start", START, "--no-render")
    c = Client(endpoints["commands"])
    page = None
    try:
        binding = next(b for b in c("hello")["scene"]["bindings"]
                       if b["tag"] == "R-1" and b["effect"] == "rotate")
        page = subprocess.Popen([shutil.which("node"), str(ROOT / "tools" / "live_check.mjs"), "--url",
                                 endpoints["page"], "--selector", "#pointer-R-1-pointer"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "CHROMIUM": str(check.chromium())})
        ready = json.loads(page.stdout.readline() or "{}")
        assert ready.get("ready"), (ready, page.stderr.read() if page.poll() is not None else "")
        d0, d1 = binding["domain"]
        r0, r1 = binding["range"]

        def degrees(level: float) -> float:
            return math.degrees(r0 + (level - d0) / (d1 - d0) * (r1 - r0))

        # The page may have drawn its snapshot before the twin's first step reached it (a
        # loaded machine): the timing starts once it shows the twin's present state.
        now = c("get", ports=["render.reactor_A1.oil_level_tank"])["values"]["render.reactor_A1.oil_level_tank"]
        angle = ready["angle"]
        for _ in range(5):
            if angle == pytest.approx(degrees(now), abs=1e-3):
                break
            page.stdin.write("watch\n")
            page.stdin.flush()
            angle = json.loads(page.stdout.readline())["angle"]
        assert angle == pytest.approx(degrees(now), abs=1e-3)
        for level in (20.0, 75.0):
            page.stdin.write("watch\n")
            page.stdin.flush()
            time.sleep(0.2)  # the page is watching
            sent = time.time()
            c("set", values={"render.reactor_A1.oil_level_tank": level})
            changed = json.loads(page.stdout.readline())
            assert "at" in changed, changed
            latency = changed["at"] / 1000.0 - sent
            print(f"set -> pointer in the page: {latency * 1000:.1f} ms")
            assert latency < 1.0, latency
            assert changed["angle"] == pytest.approx(degrees(level), abs=1e-3)
        page.stdin.write("quit\n")
        page.stdin.flush()
        page.wait(30)
    finally:
        if page is not None and page.poll() is None:
            page.kill()
        c.close()
        proc.terminate()
        try:
            proc.wait(60)
        finally:
            if proc.poll() is None:
                proc.kill()


# --- bad command lines ----------------------------------------------------------------------


def test_bad_flags_and_a_taken_port_are_one_clear_error(scene, tmp_path):
    build, sources, config = scene
    taken = zmq.Context.instance().socket(zmq.REP)
    port = taken.bind_to_random_port("tcp://127.0.0.1")
    try:
        for args, words in [(["--port", port], ["cannot serve", str(port)]),
                            (["--speed", "0"], ["--speed", "speed 0.0"]),
                            (["--start", "yesterday"], ["--start", "'yesterday'"]),
                            (["--out", tmp_path / "nothing"], ["no built scene"])]:
            proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "serve", "--out", str(build), "--sources",
                                   str(sources), "--no-render", "--no-foxglove", *map(str, args)], cwd=ROOT,
                                  env=_env(), capture_output=True, text=True, timeout=120)
            assert proc.returncode == 1, (args, proc.stdout, proc.stderr)
            assert all(w in proc.stderr for w in words) and "Traceback" not in proc.stderr, (args, proc.stderr)
    finally:
        taken.close()
