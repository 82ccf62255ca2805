"""The twin's bridges, each against the real peer: an IEC 61850 server (libiec61850),
Debian's mosquitto broker, and gz-sim's transport (tools/gzbridge's stand-in serves the
same services and topics). Everything on 127.0.0.1."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import DATA, ROOT
from pipeline.bridges import decode, scl
from pipeline.bridges.feeds import Feeds
from pipeline.bridges.hub import SignalHub
from pipeline.bridges.inputs import read_inputs
from pipeline.errors import UserError

IEC = DATA / "iec61850"
CI = bool(os.environ.get("CI"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout: float = 10.0, every: float = 0.02):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"not within {timeout} s: {predicate}")


def write(tmp_path: Path, text: str, name: str = "inputs.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# --- the inputs file ------------------------------------------------------------------

def test_an_inputs_file_reads_into_signals(tmp_path):
    shutil.copy(IEC / "bay_ied.icd", tmp_path / "bay.icd")
    path = write(tmp_path, """
scl = "bay.icd"
[[signal]]
source = "mqtt://127.0.0.1:1883/site/RE-A1/oil"
json_pointer = "/level"
target = "tank.level"
scale = 0.01
[[signal]]
source = "iec61850://127.0.0.1:10102/IED1LD0/XCBR1.Pos.stVal"
target = "breaker.open"
map = { off = 1.0, on = 0.0, intermediate = 0.5 }
period_s = 0.5
[[signal]]
source = "iec61850://127.0.0.1/IED1LD0/TTNK1.LevPct.mag.f"
target = "tank.gauge"
""")
    mqtt, breaker, level = read_inputs(path, settable={"tank.level", "breaker.open", "tank.gauge"})
    assert (mqtt.scheme, mqtt.host, mqtt.port, mqtt.path, mqtt.scale) == ("mqtt", "127.0.0.1", 1883, "site/RE-A1/oil", 0.01)
    assert (breaker.fc, breaker.period_s, breaker.quality_reference) == ("ST", 0.5, "IED1LD0/XCBR1.Pos.q")
    assert (level.port, level.fc, level.quality_reference) == (102, "MX", "IED1LD0/TTNK1.LevPct.q")


def test_every_problem_of_an_inputs_file_is_reported_at_once_naming_the_signal(tmp_path):
    shutil.copy(IEC / "bay_ied.icd", tmp_path / "bay.icd")
    path = write(tmp_path, """
scl = "bay.icd"
[[signal]]
source = "mqtt://127.0.0.1/site/+/oil"
target = "tank.level"
[[signal]]
source = "iec61850://127.0.0.1:10102/IED1LD0/XCBR9.Pos.stVal"
target = "breaker.open"
[[signal]]
source = "iec61850://127.0.0.1:10102/IED1LD0/XCBR1.Pos.stVal"
target = "nobody.here"
[[signal]]
source = "mqtt://127.0.0.1/site/a"
target = "tank.level"
[[signal]]
source = "mqtt://127.0.0.1/site/b"
target = "tank.level"
""")
    with pytest.raises(UserError) as e:
        read_inputs(path, settable={"tank.level", "breaker.open"})
    message = str(e.value)
    assert message.startswith(f"{path}: 4 problems:")
    assert "signal[1] (mqtt://127.0.0.1/site/+/oil): source: a signal is one topic: no + or # wildcards" in message
    assert "signal[2] (iec61850://127.0.0.1:10102/IED1LD0/XCBR9.Pos.stVal): IED1LD0/XCBR9.Pos.stVal is not in " \
           "the data model of bay.icd" in message
    assert "signal[3] (iec61850://127.0.0.1:10102/IED1LD0/XCBR1.Pos.stVal): target 'nobody.here' is not a " \
           "settable port of the twin" in message
    assert "signal[5] (mqtt://127.0.0.1/site/b): target 'tank.level' is already fed by signal[4]" in message


def test_an_inputs_file_that_breaks_its_schema_is_one_error_naming_the_key(tmp_path):
    path = write(tmp_path, '[[signal]]\nsource = "http://x/y"\ntarget = "a.b"\n')
    with pytest.raises(UserError, match=r"signal\[0\]\.source"):
        read_inputs(path)


def test_the_scl_index_holds_every_attribute_with_its_constraint(tmp_path):
    refs = scl.references(IEC / "bay_ied.icd")
    assert refs["IED1LD0/XCBR1.Pos.stVal"] == "ST"
    assert refs["IED1LD0/TTNK1.LevPct.mag.f"] == "MX" and refs["IED1LD0/TTNK1.LevPct.mag"] == "MX"
    assert refs["IED1LD0/LLN0.Mod.ctlModel"] == "CF"
    hostile = tmp_path / "hostile.scd"
    hostile.write_text('<?xml version="1.0"?><!DOCTYPE SCL [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                       '<SCL xmlns="http://www.iec.ch/61850/2003/SCL">&x;</SCL>')
    with pytest.raises(UserError, match="DOCTYPE"):
        scl.references(hostile)


def test_payloads_decode_through_pointer_map_scale_and_offset(tmp_path):
    (signal,) = read_inputs(write(tmp_path, """
[[signal]]
source = "mqtt://127.0.0.1/a"
json_pointer = "/readings/0/level~1pct"
target = "t.level"
scale = 0.5
offset = 1.0
"""))
    assert decode.to_number(signal, decode.mqtt_value(signal, b'{"readings": [{"level/pct": 40}]}')) == 21.0
    for bad, why in ((b"{", "not JSON"), (b'{"readings": []}', "no item"), (b'{"readings": [{"level/pct": "x"}]}',
                                                                               "not a number")):
        with pytest.raises(decode.BadValue, match=why):
            decode.to_number(signal, decode.mqtt_value(signal, bad))


# --- IEC 61850 ------------------------------------------------------------------------

class IedProcess:
    """The test IED in a process of its own, so a test can take it away and bring it back."""

    def __init__(self, port: int):
        self.port = port
        self.proc = None

    def start(self) -> "IedProcess":
        self.proc = subprocess.Popen([sys.executable, "-m", "pipeline.bridges.ied_sim", str(IEC / "bay_ied.cfg"),
                                      str(self.port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     cwd=ROOT)
        assert self.proc.stdout.readline().strip() == "ready"
        return self

    def command(self, line: str) -> None:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        assert self.proc.stdout.readline().strip() == "ok"

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()


def iec_inputs(tmp_path, port: int):
    shutil.copy(IEC / "bay_ied.icd", tmp_path / "bay.icd")
    return read_inputs(write(tmp_path, f"""
scl = "bay.icd"
[[signal]]
source = "iec61850://127.0.0.1:{port}/IED1LD0/XCBR1.Pos.stVal"
target = "breaker.open"
map = {{ off = 1.0, on = 0.0, intermediate = 0.5 }}
period_s = 0.1
[[signal]]
source = "iec61850://127.0.0.1:{port}/IED1LD0/TTNK1.LevPct.mag.f"
target = "tank.level"
period_s = 0.1
"""))


def latest(hub: SignalHub, seen: dict) -> dict:
    for u in hub.drain():
        seen[u.target] = (u.value, u.stale)
    return seen


def test_an_ied_feeds_the_hub_goes_stale_when_it_dies_and_live_when_it_returns(tmp_path):
    port = free_port()
    ied = IedProcess(port).start()
    ied.command("dbpos IED1LD0/XCBR1.Pos.stVal on")
    ied.command("float IED1LD0/TTNK1.LevPct.mag.f 63.5")
    seen: dict = {}
    try:
        with Feeds(iec_inputs(tmp_path, port)) as feeds:
            wait_for(lambda: latest(feeds.hub, seen).get("breaker.open") == (0.0, False)
                     and seen.get("tank.level") == (63.5, False))
            ied.command("dbpos IED1LD0/XCBR1.Pos.stVal off")
            ied.command("float IED1LD0/TTNK1.LevPct.mag.f 41.25")
            wait_for(lambda: latest(feeds.hub, seen).get("breaker.open") == (1.0, False)
                     and seen.get("tank.level") == (41.25, False))
            ied.command("quality IED1LD0/TTNK1.LevPct.q invalid")  # quality not good: hold, stale
            wait_for(lambda: latest(feeds.hub, seen).get("tank.level") == (41.25, True))
            ied.command("dbpos IED1LD0/XCBR1.Pos.stVal bad")  # bad-state: stale, not a value
            wait_for(lambda: latest(feeds.hub, seen).get("breaker.open") == (1.0, True))
            ied.kill()
            ied = IedProcess(port)
            ied.start()  # a new server: good quality again, breaker intermediate
            ied.command("dbpos IED1LD0/XCBR1.Pos.stVal intermediate")
            ied.command("float IED1LD0/TTNK1.LevPct.mag.f 12.0")
            wait_for(lambda: latest(feeds.hub, seen).get("breaker.open") == (0.5, False)
                     and seen.get("tank.level") == (12.0, False), timeout=20)
            status = feeds.hub.status()
            assert all(s["faults"] == 0 for s in status.values())
    finally:
        ied.kill()


def test_an_ied_that_goes_away_makes_its_signals_stale_holding_their_value(tmp_path):
    port = free_port()
    ied = IedProcess(port).start()
    ied.command("float IED1LD0/TTNK1.LevPct.mag.f 70.0")
    seen: dict = {}
    with Feeds(iec_inputs(tmp_path, port)) as feeds:
        wait_for(lambda: latest(feeds.hub, seen).get("tank.level") == (70.0, False))
        ied.kill()
        wait_for(lambda: latest(feeds.hub, seen).get("tank.level") == (70.0, True))
        assert feeds.hub.status()["signal[2] (iec61850://127.0.0.1:%d/IED1LD0/TTNK1.LevPct.mag.f)" % port]["stale"]


# --- MQTT -----------------------------------------------------------------------------

class Broker:
    """Debian's mosquitto on loopback, with a configuration of the test's own."""

    def __init__(self, tmp_path: Path, port: int):
        binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        if not Path(binary).exists():
            if CI:
                pytest.fail("mosquitto is not installed (bash .ci/install-tools)")
            pytest.skip("mosquitto is not installed (bash .ci/install-tools)")
        self.conf = tmp_path / "mosquitto.conf"
        self.conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
        self.binary, self.port, self.proc = binary, port, None

    def start(self) -> "Broker":
        self.proc = subprocess.Popen([self.binary, "-c", str(self.conf)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)

        def listening():
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", self.port)) == 0
        wait_for(listening)
        return self

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait()


def publish(port: int, topic: str, payload: bytes) -> None:
    import paho.mqtt.publish

    paho.mqtt.publish.single(topic, payload, qos=1, hostname="127.0.0.1", port=port)


def test_mqtt_messages_feed_the_hub_bad_payloads_are_counted_and_logged_once(tmp_path, caplog):
    port = free_port()
    broker = Broker(tmp_path, port).start()
    signals = read_inputs(write(tmp_path, f"""
[[signal]]
source = "mqtt://127.0.0.1:{port}/site/RE-A1/oil"
json_pointer = "/level"
target = "tank.level"
[[signal]]
source = "mqtt://127.0.0.1:{port}/site/89-3A/state"
target = "switch.open"
map = {{ open = 1.0, closed = 0.0 }}
"""))
    seen: dict = {}
    try:
        with caplog.at_level(logging.WARNING, logger="twin.inputs"), Feeds(signals) as feeds:
            wait_for(lambda: (publish(port, "site/RE-A1/oil", b'{"level": 55.5}'),
                              latest(feeds.hub, seen).get("tank.level") == (55.5, False))[1], timeout=15, every=0.2)
            publish(port, "site/89-3A/state", b"open")
            wait_for(lambda: latest(feeds.hub, seen).get("switch.open") == (1.0, False))
            for payload in (b"ajar", b"half", b'"closed"'):
                publish(port, "site/89-3A/state", payload)
            wait_for(lambda: latest(feeds.hub, seen).get("switch.open") == (0.0, False))
            status = feeds.hub.status()[signals[1].name]
            assert status["faults"] == 2 and "'half' is not one of the map's values" in status["last_fault"]
            assert sum("signal[2]" in r.getMessage() for r in caplog.records) == 1  # logged once
            broker.stop()
            wait_for(lambda: latest(feeds.hub, seen).get("tank.level") == (55.5, True))
            broker.start()
            wait_for(lambda: (publish(port, "site/RE-A1/oil", b'{"level": 60}'),
                              latest(feeds.hub, seen).get("tank.level") == (60.0, False))[1], timeout=20, every=0.3)
    finally:
        broker.stop()


# --- Gazebo out -----------------------------------------------------------------------

def _lines(proc, n: int, timeout_s: float) -> list[dict]:
    """`n` JSON lines of `proc`'s stdout, or a failure naming what came once `timeout_s`
    has passed: a message the simulator never got must fail the test, not hang the suite."""
    import queue
    import threading

    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    got, end = [], time.monotonic() + timeout_s
    while len(got) < n:
        try:
            got.append(json.loads(lines.get(timeout=max(0.0, end - time.monotonic()))))
        except queue.Empty:
            pytest.fail(f"the simulator printed {len(got)} of {n} messages in {timeout_s:g} s: {got}")
    return got


def test_the_sun_joints_poses_and_materials_reach_gz_sims_transport(tmp_path):
    from pipeline.bridges.gazebo import BRIDGE, GazeboBridge
    from pipeline.export.names import joint_command_topic

    if not BRIDGE.is_file():
        if CI:
            pytest.fail(f"{BRIDGE} is not built (bash .ci/install-tools)")
        pytest.skip(f"{BRIDGE} is not built")
    env = {**os.environ, "IGN_PARTITION": f"twin_test_{os.getpid()}", "IGN_IP": "127.0.0.1"}
    sim = subprocess.Popen([str(BRIDGE), "sim", "--world", "sample_substation", "--joint", joint_command_topic("89-3A", "blade")],
                           stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert json.loads(sim.stdout.readline())["ready"]
        travel = [0.2871, -0.4213, -0.86]
        norm = math.sqrt(sum(c * c for c in travel))
        travel = [c / norm for c in travel]
        pose = [[0.0, -1.0, 0.0, 12.5], [1.0, 0.0, 0.0, -3.25], [0.0, 0.0, 1.0, 0.75], [0, 0, 0, 1]]
        with GazeboBridge("sample_substation", env=env) as bridge:
            bridge.sun(travel, 0.8123, (1.0, 0.97, 0.92))
            bridge.joint("89-3A", "blade", 1.2345678901234567)
            bridge.pose("RE-A1", pose)
            bridge.visual("RE-A1::tank::oil", (0.9, 0.1, 0.1, 1.0))
        got = _lines(sim, 4, timeout_s=60)
    finally:
        sim.terminate()
        sim.wait()
    light, joint, set_pose, visual = sorted(got, key=lambda m: ["light_config", "/model", "set_pose",
                                                                 "visual_config"].index(
        m.get("service", "/model" if "topic" in m else "")))
    assert light["type"] == "ignition.msgs.Light" and light["name"] == "sun" and light["light_type"] == 2
    angle = math.degrees(math.acos(min(1.0, sum(a * b for a, b in zip(light["direction"], travel)))))
    assert angle < 0.01 and light["intensity"] == pytest.approx(0.8123, abs=1e-6)
    assert joint["type"] == "ignition.msgs.Double" and joint["data"] == 1.2345678901234567  # exact
    assert joint["topic"] == "/model/89-3A/joint/blade/0/cmd_pos"  # gz-sim's own form of the topic
    assert set_pose["position"] == [12.5, -3.25, 0.75]
    assert set_pose["orientation"] == pytest.approx([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], abs=1e-12)
    assert visual["diffuse"] == pytest.approx([0.9, 0.1, 0.1, 1.0], abs=1e-6)
