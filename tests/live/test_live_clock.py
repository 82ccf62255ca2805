"""The live twin's clock and its graph stepping, without sockets: simulated time = real
time x speed, pause, resume, seek; a set while paused shows in the same step; a jump
back in time reruns every node at the new step."""

from __future__ import annotations

import datetime as dt

import pytest

import live_scene
from helpers import TESTS
from pipeline.live.clock import SimClock, parse_instant

T0 = dt.datetime(2025, 3, 20, 9, 0, tzinfo=dt.timezone(dt.timedelta(hours=-3)))


class Wall:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_simulated_time_is_real_time_times_speed():
    wall = Wall()
    c = SimClock(T0, speed=60.0, wall=wall)
    wall.t += 2.0
    assert c.now() == T0 + dt.timedelta(minutes=2)
    c.pause()
    wall.t += 10.0
    assert c.now() == T0 + dt.timedelta(minutes=2) and c.wall_until(T0 + dt.timedelta(hours=1)) == float("inf")
    c.resume()
    c.set_speed(1.0)
    wall.t += 3.0
    assert c.now() == T0 + dt.timedelta(minutes=2, seconds=3)
    assert c.wall_until(T0 + dt.timedelta(minutes=2, seconds=13)) == pytest.approx(10.0)
    c.seek(T0 + dt.timedelta(hours=5))
    wall.t += 1.0
    assert c.now() == T0 + dt.timedelta(hours=5, seconds=1)
    for bad in (0, -1.0, float("nan"), 1e9, True, "fast"):
        with pytest.raises(ValueError):
            c.set_speed(bad)
    assert c.speed == 1.0


def test_instants_without_an_offset_are_the_sites_wall_clock():
    import zoneinfo

    bahia = zoneinfo.ZoneInfo("America/Bahia")
    assert parse_instant("2025-03-20T09:00:00", bahia).utcoffset() == dt.timedelta(hours=-3)
    assert parse_instant("2025-03-20T12:00:00Z", bahia) == dt.datetime(2025, 3, 20, 12, tzinfo=dt.timezone.utc)
    with pytest.raises(ValueError, match="ISO 8601"):
        parse_instant("tomorrow", bahia)
    with pytest.raises(ValueError, match="no UTC offset"):
        parse_instant("2025-03-20T09:00:00", None)


@pytest.fixture
def twin(tmp_path):
    from pipeline.live.app import make_server

    build, sources, config = live_scene.make(tmp_path)
    return make_server(build, sources, None, start="2025-03-20T09:00:00", port=0, sensor=config, render=False,
                       foxglove=False).twin


def test_the_graph_steps_with_the_clock_sets_apply_at_once_and_seeks_rerun_everything(twin):
    first = twin.advance(0)
    assert [k for k, _ in first] == [0] and first[0][1]["render.reactor_A1.oil_level_tank"] == 100.0
    assert [k for k, _ in twin.advance(3)] == [1, 2, 3]
    assert twin.advance(3) == []  # nothing due, nothing set
    twin.set({"render.reactor_A1.oil_level_tank": 30})  # an int is a float's value
    (k, changed), = twin.advance(3)
    assert k == 3 and changed == {"render.reactor_A1.oil_level_tank": 30.0}
    el3 = twin.get(["sun.elevation"])["sun.elevation"]
    (k, changed), = twin.advance(3 + 5000)  # further than MAX_CATCH_UP: one jump
    assert k == 5003 and "sun.elevation" in changed and twin.instant() == parse_instant(
        "2025-03-20T10:23:23", twin.scenario.zone)
    (k, _), = twin.advance(3)  # back in time: every node runs again at step 3
    assert k == 3 and twin.get(["sun.elevation"])["sun.elevation"] == el3
    assert twin.get(["render.reactor_A1.oil_level_tank"])["render.reactor_A1.oil_level_tank"] == 30.0
    with pytest.raises(ValueError, match="before the run's start"):
        twin.step_of(parse_instant("2025-03-20T08:59:59", twin.scenario.zone))


def test_turbidity_set_from_outside_changes_the_irradiance(twin):
    twin.advance(0)
    before = twin.get(["sun.irradiance"])["sun.irradiance"]
    twin.set({"tau_atm.value": 0.6})
    twin.advance(0)
    assert twin.get(["sun.irradiance"])["sun.irradiance"] < before
    assert twin.frame_plan(48, 36).tau_atm == 0.6


def test_a_held_input_let_go_reads_its_edge_again(tmp_path):
    from pathlib import Path

    from pipeline.live.app import make_server

    build, sources, _ = live_scene.make(tmp_path)
    scenario = tmp_path / "leak.toml"
    scenario.write_text((TESTS / "live_leak.toml").read_text())
    twin = make_server(build, sources, scenario, port=0, render=False, foxglove=False).twin
    twin.advance(4)
    port = "render.reactor_A1.oil_level_tank"
    assert twin.get([port])[port] == twin.get(["tank.level"])["tank.level"] == pytest.approx(80.0 * 1.01)
    twin.set({port: 12.5})
    twin.advance(5)
    assert twin.get([port])[port] == 12.5
    twin.set({port: None})
    twin.advance(6)
    assert twin.get([port])[port] == twin.get(["tank.level"])["tank.level"] == pytest.approx(70.0 * 1.01)
    with pytest.raises(ValueError, match="output"):
        twin.set({"tank.level": None})


def test_show_only_hides_exactly_the_other_placements(tmp_path):
    """CyclesScene.show_only: the loaded placements not named are hidden, the named
    ones shown, lights untouched, and a render right after it draws just those."""
    pytest.importorskip("bpy")
    from pipeline.render.cycles import CyclesScene
    from pipeline.render.sensor import PhoneCamera
    from pipeline.runtime.site import load_site

    build, sources, _ = live_scene.make(tmp_path)
    scene = CyclesScene(load_site(build, sources), PhoneCamera(width=64, height=48, samples=1), 0)
    try:
        import numpy as np

        from pipeline.geometry.pinhole import look_at
        from pipeline.runtime import camera as camera_model
        from pipeline.runtime.site import Shot

        scene.load_many(["R-1", "R-2"])
        scene.set_instances({"R-1": 1, "R-2": 2})
        when = dt.datetime(2025, 3, 20, 12, tzinfo=dt.timezone.utc)
        scene.set_shot(Shot(when, look_at((0.25, -14.0, 3.0), (0.25, -2.0, 0.5)), camera_model.lens(1.0), 1.0, 1.0,
                            800.0))

        def seen():  # what a render shows: its instance ids
            ids = scene.render_labels()[0]
            return set(np.unique(ids).tolist()) - {0}

        assert seen() == {1, 2}
        scene.sun.hide_render, moon = True, scene.moon.hide_render

        def hidden():  # out of the view layer, the objects a render's dependency graph holds
            shown = set(scene.bpy.context.view_layer.objects)
            return {tag: {ob not in shown for ob in objs.values()} for tag, objs in scene.objects.items()}

        both = scene.render()
        scene.show_only(["R-1"])
        only_1 = scene.render()  # the picture first: the label pass's own settings must not be what updates it
        assert hidden() == {"R-1": {False}, "R-2": {True}} and scene.sun.hide_render and scene.moon.hide_render == moon
        assert seen() == {1}
        scene.show_only(["R-2"])
        only_2 = scene.render()
        assert hidden() == {"R-1": {True}, "R-2": {False}}
        scene.load_many(["R-1", "R-2"])  # loading again keeps what show_only hid
        assert hidden() == {"R-1": {True}, "R-2": {False}}
        assert seen() == {2}
        scene.show_only(["R-1"])
        assert np.array_equal(scene.render(), only_1)
        assert not np.array_equal(only_1, both) and not np.array_equal(only_1, only_2)
        scene.load("R-1")  # already loaded: nothing new
        scene.show_only(["R-1", "R-2"])
        assert hidden() == {"R-1": {False}, "R-2": {False}}
    finally:
        scene.close()


def test_a_browser_that_falls_behind_loses_messages_counted_and_told():
    """The WebSocket side never waits: a full queue drops the message, counts it, and
    the browser's next delivered message says how many it missed."""
    import asyncio
    import json

    from pipeline.live import websocket

    async def run():
        feed = websocket.WebSocketFeed(hello=dict, snapshot=dict)
        slow, fast = websocket._Client(), websocket._Client()
        feed.clients |= {slow, fast}
        for seq in range(websocket.QUEUE + 5):
            feed.publish({"seq": seq, "values": {}})
            fast.queue.get_nowait()  # this one keeps up
        assert slow.queue.qsize() == websocket.QUEUE and feed.dropped == 5 and fast.dropped == 0
        first = json.loads(slow.queue.get_nowait())
        assert first["seq"] == 0 and "dropped" not in first
        feed.publish({"seq": 999, "values": {}})
        while slow.queue.qsize() > 1:
            slow.queue.get_nowait()
        last = json.loads(slow.queue.get_nowait())
        assert last == {"seq": 999, "values": {}, "dropped": 5} and slow.dropped == 0

    asyncio.run(run())
