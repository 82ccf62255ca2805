"""`twin serve --inputs --gazebo`: the twin hears a real IEC 61850 server (libiec61850)
and Debian's mosquitto, publishes what they say (and what is stale), renders it, and
pushes its sun and materials into gz-sim's transport (tools/gzbridge's stand-in for
gz-sim records what arrives). Everything on 127.0.0.1, on the tiny scene of test_live."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import zmq

import live_scene
from helpers import unavailable
from test_bridges import IEC, Broker, IedProcess, free_port, publish, wait_for
from test_live import ROOT, START, Client, _env
from pipeline import sun as sun_model
from pipeline.bridges.gazebo import BRIDGE

TANK_A1 = "render.reactor_A1.oil_level_tank"
COLUMN_A1 = "render.reactor_A1.oil_level_b1"
TANK_A2 = "render.reactor_A2.oil_level_tank"


class Published:
    """The PUB socket's messages, read as they come; `latest` holds each port's last value."""

    def __init__(self, endpoint: str):
        self.sock = zmq.Context.instance().socket(zmq.SUB)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)
        self.latest: dict = {}
        self.stale: list = []

    def pump(self) -> "Published":
        while self.sock.poll(0):
            msg = json.loads(self.sock.recv())
            self.latest.update(msg["values"])
            self.stale = msg.get("stale", [])
        return self


def test_the_substation_feeds_the_live_twin_and_the_twin_drives_gazebo(tmp_path):
    if not BRIDGE.is_file():
        unavailable(f"{BRIDGE} is not built (bash .ci/install-tools)")
    build, sources, config = live_scene.make(tmp_path / "scene")
    ied_port, mqtt_port = free_port(), free_port()
    ied = IedProcess(ied_port).start()
    ied.command("float IED1LD0/TTNK1.LevPct.mag.f 95.0")
    ied.command("dbpos IED1LD0/XCBR1.Pos.stVal on")
    broker = Broker(tmp_path, mqtt_port).start()
    (tmp_path / "bay.icd").write_bytes((IEC / "bay_ied.icd").read_bytes())
    inputs = tmp_path / "inputs.toml"
    inputs.write_text(f"""
scl = "bay.icd"
[[signal]]
source = "iec61850://127.0.0.1:{ied_port}/IED1LD0/TTNK1.LevPct.mag.f"
target = "{TANK_A1}"
period_s = 0.2
[[signal]]   # the breaker's position, shown on the tiny scene's oil column (it has no breaker)
source = "iec61850://127.0.0.1:{ied_port}/IED1LD0/XCBR1.Pos.stVal"
target = "{COLUMN_A1}"
map = {{ off = 0.0, on = 100.0, intermediate = 50.0 }}
period_s = 0.2
[[signal]]
source = "mqtt://127.0.0.1:{mqtt_port}/site/R-2/oil"
json_pointer = "/level"
target = "{TANK_A2}"
""")
    env = {**_env(), "IGN_PARTITION": f"twin_live_{os.getpid()}", "IGN_IP": "127.0.0.1"}
    sim = subprocess.Popen([str(BRIDGE), "sim", "--world", "live"], stdout=subprocess.PIPE, text=True, env=env)
    assert json.loads(sim.stdout.readline())["ready"]
    twin = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "serve", "--out", str(build), "--sources",
                             str(sources), "--port", "0", "--sensor", str(config), "--start", START, "--inputs",
                             str(inputs), "--gazebo", "live", "--no-foxglove"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = twin.stdout.readline()
        assert line, twin.stderr.read()[-3000:]
        endpoints = json.loads(line)
        c = Client(endpoints["commands"])
        pub = Published(endpoints["publish"])

        # The IED's level and breaker reach the published state; MQTT's too.
        time.sleep(0.3)  # subscribed: then a snapshot, as a late subscriber starts
        pub.latest.update(c("get")["values"])
        wait_for(lambda: pub.pump().latest.get(TANK_A1) == pytest.approx(95.0) and
                 pub.latest.get(COLUMN_A1) == 100.0, timeout=30)
        first = c("render", seed=7)
        assert first["ok"], first
        before = c.frames[0]
        wait_for(lambda: (publish(mqtt_port, "site/R-2/oil", b'{"level": 42.5}'),
                          pub.pump().latest.get(TANK_A2) == 42.5)[1], timeout=20, every=0.3)
        publish(mqtt_port, "site/R-2/oil", b'{"level": "full"}')  # a wrong type: counted, the twin goes on

        ied.command("float IED1LD0/TTNK1.LevPct.mag.f 30.0")  # below the lamp's threshold
        ied.command("dbpos IED1LD0/XCBR1.Pos.stVal off")
        wait_for(lambda: pub.pump().latest.get(TANK_A1) == pytest.approx(30.0) and
                 pub.latest.get(COLUMN_A1) == 0.0)
        assert c("get", ports=[TANK_A1])["values"][TANK_A1] == pytest.approx(30.0)
        after = c("render", seed=7)
        assert after["ok"], after
        assert c.frames[0] != before  # the pointer turned, the column sank, the lamp lit

        ied.kill()  # the IED goes away: its signals go stale, holding their values
        wait_for(lambda: {TANK_A1, COLUMN_A1} <= set(pub.pump().stale), timeout=20)
        assert pub.latest[TANK_A1] == pytest.approx(30.0) and TANK_A2 not in pub.stale
        assert set(c("get", ports=[TANK_A1])["stale"]) >= {TANK_A1, COLUMN_A1}
        ied = IedProcess(ied_port).start()  # back, with new values
        ied.command("float IED1LD0/TTNK1.LevPct.mag.f 55.0")
        ied.command("dbpos IED1LD0/XCBR1.Pos.stVal intermediate")
        wait_for(lambda: pub.pump().latest.get(TANK_A1) == pytest.approx(55.0) and
                 pub.latest.get(COLUMN_A1) == 50.0 and not pub.stale, timeout=30)

        stats = c("hello")["stats"]
        signals = stats["inputs"]["signals"]
        mqtt = next(v for k, v in signals.items() if k.startswith("signal[3]"))
        assert mqtt["faults"] == 1 and "'full' is not a number" in mqtt["last_fault"]
        assert stats["gazebo"]["failed"] == {} and stats["gazebo"]["sent"]["light"] >= 1
        values = c("get")["values"]
        el, az = values["sun.elevation"], values["sun.azimuth"]
        assert twin.poll() is None  # it never stopped
    finally:
        twin.send_signal(signal.SIGTERM)
        twin.wait(30)
        sim.send_signal(signal.SIGTERM)
        sim.wait(10)
        ied.kill()
        broker.stop()
    arrived = [json.loads(line) for line in sim.stdout.read().splitlines()]
    lights = [m for m in arrived if m.get("service") == "light_config"]
    assert lights and all(m["name"] == "sun" and m["light_type"] == 2 for m in lights)
    travel = -sun_model.direction_enu(el, az)  # the sun as the twin had it last
    last = np.asarray(lights[-1]["direction"])
    angle = math.degrees(math.acos(min(1.0, float(last @ travel / np.linalg.norm(last)))))
    assert angle < 0.01, angle
    lamps = [m for m in arrived if m.get("service") == "visual_config"]
    # the lamp of R-1 turned red below its threshold (the tiny asset's lamp_red, base colour 1 0 0)
    assert any(m["name"] == "R-1::body::lamp" and m["diffuse"][:3] == [1, 0, 0] for m in lamps), lamps
