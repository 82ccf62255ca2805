"""The wires' sag in `twin serve`: the tiny live scene with a conductors.json of two
spans (a level twin-bundle span and an inclined single one), driven by a real ZeroMQ
client: a `set` of a load current moves the published sag by what the thermal node
and the change-of-state equation give (checked against the level span's closed form,
H/w (cosh(wL/2H) - 1), to 0.1 mm), a held temperature wins over the thermal node, and
the MCAP recording carries a line strip per span whose lowest point is the sag."""

from __future__ import annotations

import json
import math
import signal
import time

import numpy as np
import pytest

import live_scene
from pipeline.geometry import catenary as cat
from pipeline.live import protocol
from pipeline.runtime import thermal
from test_live import START, Client, _subscriber, start_twin

G = 9.80665
RAIL = {"diameter_m": 0.02959, "mass_kg_per_m": 1.6, "ea_n": 3.26e7, "alpha_per_k": 20.9e-6, "bundle_count": 2,
        "bundle_spacing_m": 0.457, "max_temperature_c": 90.0, "bundle_offsets_m": [[-0.2285, 0.0], [0.2285, 0.0]],
        "r25_ohm_per_km": 0.0610, "r75_ohm_per_km": 0.0727}
BARE = {**RAIL, "bundle_count": 1, "bundle_spacing_m": 0.0, "bundle_offsets_m": [[0.0, 0.0]]}
del BARE["r25_ohm_per_km"], BARE["r75_ohm_per_km"]  # no resistances: its temperature is a constant
LEVEL = ([0.0, 0.0, 12.0], [40.0, 0.0, 12.0])
INCLINED = ([0.0, 5.0, 6.0], [30.0, 5.0, 14.0])
H_REF, T_REF = 9000.0, 15.0


def _span(sid: str, kind: str, ends, t: dict) -> dict:
    w = t["mass_kg_per_m"] * G * t["bundle_count"]
    curve = cat.from_tension(np.array(ends[0]), np.array(ends[1]), H_REF, w)
    return {"id": sid, "type": kind, "from": {"terminal": sid.split("~")[0], "enu": ends[0]},
            "to": {"terminal": sid.split("~")[1], "enu": ends[1]}, "tension_n": H_REF, "weight_n_per_m": w,
            "temperature_c": T_REF, "sag_m": round(cat.sag(curve), 6), "lod": 0,
            "lods": [{"segments": 24, "chord_error_m": 0.001}], "usd_path": f"/Site/Conductors/{kind}"}


@pytest.fixture(scope="module")
def wired(tmp_path_factory):
    build, sources, config = live_scene.make(tmp_path_factory.mktemp("wires"))
    record = {"temperature_c": 25.0, "types": {"RAIL": RAIL, "BARE": BARE},
              "spans": [_span("R-1.a~R-2.a", "RAIL", LEVEL, RAIL), _span("R-1.b~R-2.b", "BARE", INCLINED, BARE)]}
    (build / "scene" / "conductors.json").write_text(json.dumps(record))
    mcap = build.parent / "live.mcap"
    proc, endpoints = start_twin(build, sources, "--no-render", "--no-foxglove", "--record", mcap, "--start", START)
    client = Client(endpoints["commands"])
    yield proc, endpoints, client, mcap
    client.close()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        proc.wait(20)


def _level_sag(temperature_c: float) -> float:
    """The level RAIL span's sag at a temperature: change of state, then the closed form."""
    w = RAIL["mass_kg_per_m"] * G * 2
    H = cat.change_of_state(np.array(LEVEL[0]), np.array(LEVEL[1]), w, RAIL["ea_n"] * 2, RAIL["alpha_per_k"],
                            H_REF, T_REF, temperature_c)
    return H / w * (math.cosh(w * 40.0 / (2.0 * H)) - 1.0)


def _published_with(sub, group: str, seq: int) -> dict:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        msg = json.loads(sub.recv())
        protocol.check("published", msg)
        if msg["seq"] >= seq and group in msg.get("conductors", {}):
            return msg
    raise AssertionError(f"no published message with conductors.{group} after seq {seq}")


def test_the_groups_are_live_inputs(wired):
    _, _, c, _ = wired
    ports = {p["name"]: p for p in c("hello")["ports"]}
    assert ports["load_RAIL.value"]["settable"] and ports["load_RAIL.value"]["unit"] == "A"
    assert ports["thermal_RAIL.temperature"]["kind"] == "output"
    assert ports["render.conductors_RAIL.temperature"]["unit"] == "degC"
    assert "load_BARE.value" not in ports and ports["temperature_BARE.value"]["settable"]
    state = c("get", ports=["ambient.value"], conductors=True)
    assert set(state["conductors"]) == {"RAIL", "BARE"}
    assert state["conductors"]["BARE"]["temperature_c"] == 25.0


def test_a_load_current_moves_the_sag_by_the_change_of_state(wired):
    _, endpoints, c, _ = wired
    sub = _subscriber(endpoints["publish"])
    try:
        c("clock", action="pause")
        ok = c("set", values={"load_RAIL.value": {"value": 1600.0, "unit": "A"}, "ambient.value": 30.0})
        msg = _published_with(sub, "RAIL", ok["seq"])
        irradiance = c("get", ports=["sun.irradiance"])["values"]["sun.irradiance"]
        hot = thermal.temperature(800.0, 30.0, diameter_m=RAIL["diameter_m"], r25_ohm_per_km=0.0610,
                                  r75_ohm_per_km=0.0727, irradiance_w_m2=irradiance,
                                  elevation_m=live_scene.ORIGIN["height_m"])
        group = msg["conductors"]["RAIL"]
        assert group["temperature_c"] == pytest.approx(hot, abs=1e-6)
        assert group["sag_m"]["R-1.a~R-2.a"] == pytest.approx(_level_sag(hot), abs=1e-4)
        ok = c("set", values={"load_RAIL.value": 200.0})
        cool = _published_with(sub, "RAIL", ok["seq"])["conductors"]["RAIL"]
        assert cool["temperature_c"] < hot - 10.0
        moved = group["sag_m"]["R-1.a~R-2.a"] - cool["sag_m"]["R-1.a~R-2.a"]
        assert moved > 0.01  # hotter, longer, lower
        assert moved == pytest.approx(_level_sag(hot) - _level_sag(cool["temperature_c"]), abs=1e-4)
        # held from outside, the temperature wins over the thermal node; None lets it go
        ok = c("set", values={"render.conductors_RAIL.temperature": {"value": 75.0, "unit": "degC"}})
        held = _published_with(sub, "RAIL", ok["seq"])["conductors"]["RAIL"]
        assert held["temperature_c"] == 75.0
        assert held["sag_m"]["R-1.a~R-2.a"] == pytest.approx(_level_sag(75.0), abs=1e-4)
        ok = c("set", values={"render.conductors_RAIL.temperature": None})
        assert _published_with(sub, "RAIL", ok["seq"])["conductors"]["RAIL"]["temperature_c"] == \
            pytest.approx(cool["temperature_c"], abs=1e-9)
        # the inclined single conductor follows its constant, against the catenary's own sag
        ok = c("set", values={"temperature_BARE.value": 60.0})
        bare = _published_with(sub, "BARE", ok["seq"])["conductors"]["BARE"]
        w = BARE["mass_kg_per_m"] * G
        p0, p1 = np.array(INCLINED[0]), np.array(INCLINED[1])
        H = cat.change_of_state(p0, p1, w, BARE["ea_n"], BARE["alpha_per_k"], H_REF, T_REF, 60.0)
        assert bare["sag_m"]["R-1.b~R-2.b"] == pytest.approx(cat.sag(cat.from_tension(p0, p1, H, w)), abs=1e-6)
        bad = c("set", values={"load_RAIL.value": {"value": 5, "unit": "degC"}})
        assert not bad["ok"] and "unit mismatch" in bad["error"]
    finally:
        sub.close()
        c("clock", action="resume")


def test_the_recording_draws_each_span_as_a_line(wired):
    proc, _, c, mcap = wired
    c("set", values={"render.conductors_RAIL.temperature": 50.0})
    time.sleep(0.5)
    sag = c("get", ports=[], conductors=True)["conductors"]["RAIL"]["sag_m"]["R-1.a~R-2.a"]
    c("shutdown")
    proc.wait(30)
    from mcap.reader import make_reader

    scenes = []
    with open(mcap, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=["/conductors"]):
            assert schema.name == "foxglove.SceneUpdate"
            scenes.append(json.loads(message.data))
    assert len(scenes) >= 2
    [line] = [e for e in scenes[-1]["entities"] if e["id"] == "R-1.a~R-2.a"][0]["lines"]
    z = [p["z"] for p in line["points"]]
    assert len(z) == 25 and z[0] == pytest.approx(12.0) and z[-1] == pytest.approx(12.0)
    assert 12.0 - min(z) == pytest.approx(sag, abs=1e-6)  # 24 segments: the midpoint is a vertex


def _record() -> dict:
    return {"temperature_c": 25.0, "types": {"RAIL": RAIL, "BARE": BARE},
            "spans": [_span("R-1.a~R-2.a", "RAIL", LEVEL, RAIL), _span("R-1.b~R-2.b", "BARE", INCLINED, BARE)]}


def test_a_scenarios_conductors_temperature_moves_every_group():
    """A scenario's render.conductors.temperature (as `twin run` reads it) moves every
    group; a group's own input wins; without either a span is as built."""
    from pipeline.live.wires import LiveWires

    record = _record()
    wires = LiveWires(record)
    assert wires.temperatures({}) == {"BARE": None, "RAIL": None}
    assert wires.sags("RAIL", None) == {"R-1.a~R-2.a": record["spans"][0]["sag_m"]}
    every = {"conductors": {"temperature": 60.0}}
    assert wires.temperatures(every) == {"BARE": 60.0, "RAIL": 60.0}
    assert wires.temperatures({**every, "conductors_RAIL": {"temperature": 70.0}}) == {"BARE": 60.0, "RAIL": 70.0}
    assert set(wires.changes(every)) == {"BARE", "RAIL"} and wires.changes(every) == {}
    assert set(wires.changes({**every, "conductors_RAIL": {"temperature": 70.0}})) == {"RAIL"}
    assert wires.sags("RAIL", 60.0)["R-1.a~R-2.a"] == pytest.approx(_level_sag(60.0), abs=1e-6)


class _Bridge:
    def __init__(self):
        self.sent, self.failed, self.calls = {}, {}, []

    def sun(self, *a):
        self.calls.append(("sun", a))

    def joint(self, *a):
        self.calls.append(("joint", a))

    def visual(self, *a):
        self.calls.append(("visual", a))

    def close(self):
        pass


def test_gazebo_lists_the_conductors_as_not_applied(tmp_path):
    from pipeline.live.app import make_server
    from pipeline.live.outside import GazeboOut

    build, sources, _ = live_scene.make(tmp_path)
    (build / "scene" / "conductors.json").write_text(json.dumps(_record()))
    twin = make_server(build, sources, render=False, foxglove=False, start=START).twin
    twin.advance(0)
    out = GazeboOut("sample", bridge=_Bridge())
    out.push(twin)
    assert any(n.startswith("conductors (sag:") for n in out.status()["not_applied"])
    # without conductors nothing is said of them
    plain, sources2, _ = live_scene.make(tmp_path / "plain")
    twin = make_server(plain, sources2, render=False, foxglove=False, start=START).twin
    twin.advance(0)
    out = GazeboOut("sample", bridge=_Bridge())
    out.push(twin)
    assert not any(n.startswith("conductors") for n in out.status()["not_applied"])
