"""The live I/O section (issue 37): the substation's signals into `twin serve`, timed
against real peers on loopback (an IEC 61850 server, libiec61850's; Debian's mosquitto).

- IEC 61850 change -> published state: the IED's value changed, then the twin's PUB
  message that carries it; p50/p99 against the goal poll period + 100 ms;
- MQTT message -> published state: p50/p99 against the goal 50 ms;
- 1,000 MQTT signals at 10 Hz (10,000 messages a second) for the soak's length into the
  twin's input clients and hub (what `twin serve --inputs` runs, drained every 50 ms as its
  loop does): the lag of each drained value behind its publication, per minute, and the
  process's RSS, to show growth or its absence. 1,000 IEC 61850 attributes at 10 Hz would
  be 10,000 MMS reads a second from one poller; the soak uses MQTT, as bridges at that
  rate do.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


from .context import Context
from .live import _pcts, _serve, _stop

POLL_S = 0.1
MODEL = """MODEL(IED1){
LD(LD0){
LN(LLN0){
DO(Mod 0){
DA(stVal 0 12 0 1 0)=1;
DA(q 0 23 0 2 0);
DA(t 0 22 0 0 0);
}
}
LN(TTNK1){
DO(LevPct 0){
DA(mag 0 27 1 1 0){
DA(f 0 10 1 1 0);
}
DA(q 0 23 1 2 0);
DA(t 0 22 1 0 0);
}
}
}
}
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, seconds: float = 10.0) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port}")


class _Peers:
    """mosquitto and the IED simulator in `folder`, stopped together."""

    def __init__(self, folder: Path):
        broker = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        if not Path(broker).exists():
            raise RuntimeError("mosquitto is not installed: bash .ci/install-tools")
        self.mqtt_port, self.ied_port = _free_port(), _free_port()
        conf = folder / "mosquitto.conf"
        conf.write_text(f"listener {self.mqtt_port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
        (folder / "ied.cfg").write_text(MODEL)
        self.broker = subprocess.Popen([broker, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.ied = subprocess.Popen([sys.executable, "-m", "pipeline.bridges.ied_sim", str(folder / "ied.cfg"),
                                     str(self.ied_port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        if self.ied.stdout.readline().strip() != "ready":
            raise RuntimeError("the IED simulator did not start")
        _wait_port(self.mqtt_port)

    def ied_float(self, value: float) -> None:
        self.ied.stdin.write(f"float IED1LD0/TTNK1.LevPct.mag.f {value!r}\n")
        self.ied.stdin.flush()
        self.ied.stdout.readline()

    def close(self) -> None:
        for proc in (self.broker, self.ied):
            proc.terminate()
            proc.wait(10)


def _until_published(sub, port: str, value: float, timeout: float = 10.0) -> float | None:
    """The monotonic time the first message carrying port = value arrives, or None."""
    import zmq

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            raw = sub.recv()
        except zmq.Again:
            continue
        got = json.loads(raw)["values"].get(port)
        if got is not None and abs(got - value) < 1e-4:
            return time.monotonic()
    return None


def _targets(build: Path, sources: Path) -> list[tuple[str, tuple[float, float]]]:
    """Two settable float ports with a range, bound states first (the sample's oil
    levels; a scene without any has the sun's turbidity and the sky's aerosol)."""
    from ..live.client import LiveClient

    proc, ep = _serve(build, sources, "--no-render")
    c = LiveClient(ep["commands"])
    try:
        ports = [p for p in c("hello")["ports"] if p["settable"] and p["type"] == "float" and p.get("range")]
    finally:
        _stop(proc, c)
    ports.sort(key=lambda p: (not p["name"].startswith("render."), p["name"]))
    if len(ports) < 2:
        raise RuntimeError(f"the twin has {len(ports)} settable float ports, 2 needed")
    return [(p["name"], tuple(p["range"])) for p in ports[:2]]


def _to_twin(build: Path, sources: Path, peers: _Peers, folder: Path, changes: int) -> dict:
    import paho.mqtt.client as mqtt
    import zmq

    from ..live.client import LiveClient

    (TANK, iec_range), (TANK_MQTT, mqtt_range) = _targets(build, sources)
    inputs = folder / "inputs.toml"
    inputs.write_text(f"""
[[signal]]
source = "iec61850://127.0.0.1:{peers.ied_port}/IED1LD0/TTNK1.LevPct.mag.f"
target = "{TANK}"
period_s = {POLL_S}
[[signal]]
source = "mqtt://127.0.0.1:{peers.mqtt_port}/bench/level"
target = "{TANK_MQTT}"
""")
    proc, ep = _serve(build, sources, "--no-render", "--inputs", inputs)
    c = LiveClient(ep["commands"])
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.RCVTIMEO, 200)
    sub.connect(ep["publish"])
    pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    pub.connect("127.0.0.1", peers.mqtt_port)
    pub.loop_start()
    try:
        time.sleep(1.0)
        iec, mq, lost = [], [], 0
        for i in range(changes):
            frac = 0.1 + 0.8 * (i % 80) / 80.0 + 0.0025  # a new value inside each port's range every time
            value = iec_range[0] + frac * (iec_range[1] - iec_range[0])
            t0 = time.monotonic()
            peers.ied_float(value)
            t1 = _until_published(sub, TANK, value)
            if t1 is None:
                lost += 1
            else:
                iec.append((t1 - t0) * 1000.0)
            t0 = time.monotonic()
            sent = mqtt_range[0] + frac * (mqtt_range[1] - mqtt_range[0])
            pub.publish("bench/level", repr(sent), qos=1).wait_for_publish(5)
            t1 = _until_published(sub, TANK_MQTT, sent)
            if t1 is None:
                lost += 1
            else:
                mq.append((t1 - t0) * 1000.0)
        return {"poll_period_s": POLL_S, "iec61850_to_published_ms": _pcts(iec),
                "iec61850_goal_ms": POLL_S * 1000.0 + 100.0, "mqtt_to_published_ms": _pcts(mq),
                "mqtt_goal_ms": 50.0, "not_seen": lost, "targets": [TANK, TANK_MQTT], "inputs": c("hello")["stats"]["inputs"]["rejected"]}
    finally:
        pub.loop_stop()
        pub.disconnect()
        sub.close()
        _stop(proc, c)


def _soak(peers: _Peers, signals: int, hz: float, seconds: float, folder: Path) -> dict:
    """`signals` MQTT topics at `hz` each into Feeds, drained every 50 ms."""
    import paho.mqtt.client as mqtt
    import psutil

    from ..bridges.feeds import Feeds
    from ..bridges.inputs import read_inputs

    path = folder / "soak.toml"
    path.write_text("".join(f'[[signal]]\nsource = "mqtt://127.0.0.1:{peers.mqtt_port}/soak/{i}"\n'
                            f'json_pointer = "/t"\ntarget = "n{i}.value"\n' for i in range(signals)))
    sigs = read_inputs(path)
    stop = threading.Event()
    sent = [0]

    def publisher():
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        client.max_queued_messages_set(0)
        client.connect("127.0.0.1", peers.mqtt_port)
        client.loop_start()
        period = 1.0 / hz
        next_round = time.monotonic()
        while not stop.is_set():
            for i in range(signals):
                client.publish(f"soak/{i}", json.dumps({"t": time.time()}), qos=0)
            sent[0] += signals
            next_round += period
            time.sleep(max(0.0, next_round - time.monotonic()))
        client.loop_stop()
        client.disconnect()

    me = psutil.Process()
    lags_by_minute: list[list[float]] = [[]]
    rss = [me.memory_info().rss]
    received = 0
    with Feeds(sigs) as feeds:
        time.sleep(1.0)  # subscribed
        worker = threading.Thread(target=publisher, daemon=True)
        t_start = time.monotonic()
        worker.start()
        while time.monotonic() - t_start < seconds:
            time.sleep(0.05)
            now = time.time()
            updates = feeds.hub.drain()
            received += len(updates)
            lags_by_minute[-1].extend(now - u.value for u in updates if u.value is not None)
            if time.monotonic() - t_start > 60.0 * len(lags_by_minute):
                lags_by_minute.append([])
                rss.append(me.memory_info().rss)
        stop.set()
        worker.join(10)
        rss.append(me.memory_info().rss)
        faults = sum(s["faults"] for s in feeds.hub.status().values())
    windows = [{"minute": k, **{key: v * 1000.0 if key != "n" else v for key, v in _pcts(lags).items()}}
               for k, lags in enumerate(lags_by_minute) if lags]
    return {"signals": signals, "hz": hz, "seconds": seconds, "published": sent[0],
            "offered_per_s": signals * hz, "drained_updates": received, "faults": faults,
            "lag_ms_by_minute": windows, "rss_mb": [r / 2**20 for r in rss],
            "rss_growth": (rss[-1] - rss[1]) / rss[1] if len(rss) > 2 else None,
            "load_average": list(os.getloadavg())}


def live_io_section(ctx: Context) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="live-io-", dir=ctx.work))
    peers = _Peers(folder)
    try:
        twin = _to_twin(ctx.sample_build(), ctx.sources, peers, folder, changes=ctx.pick(10, 100))
        soak = _soak(peers, signals=1000, hz=10.0, seconds=ctx.pick(2.0, 600.0), folder=folder)
    finally:
        peers.close()
    return {"to_published": twin, "soak": soak}
