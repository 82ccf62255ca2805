"""The live twin's switch commands reach joints of the sample's Gazebo world: every
message `twin serve --gazebo` sends to open a switch goes to a topic on which a
JointPositionController of the written world listens, whose joint sdformat finds and
dartsim turns (tools/gzprobe --joints)."""

from __future__ import annotations

import json
import os
import subprocess
import threading
from collections import Counter
from types import SimpleNamespace

import pytest

from pipeline.bridges.gazebo import GazeboBridge
from pipeline.export.names import joint_command_topic
from pipeline.live.default_scenario import switch_node, switchgear
from pipeline.live.outside import GazeboOut
from pipeline.runtime.site import load_site
from pipeline.validate import gazebo

CI = bool(os.environ.get("CI"))


class _Recorded(GazeboBridge):
    """The twin's bridge with its line protocol kept here instead of sent to gzbridge."""

    def __init__(self):  # no gzbridge process: the lines are what is checked
        self.world, self.sent, self.failed, self.lines = "sample_substation", Counter(), Counter(), []
        self._errors, self._lock = set(), threading.Lock()

    def _send(self, cmd: str, *fields: str) -> None:
        self.sent[cmd] += 1
        self.lines.append((cmd, *fields))


def _open_every_switch(build, sources) -> list[tuple[str, ...]]:
    """The joint lines GazeboOut sends when every switch of the sample opens."""
    site = load_site(build, sources)
    tags = switchgear(site)
    twin = SimpleNamespace(site=site, switches={switch_node(t): t for t in tags},
                           engine=SimpleNamespace(values={(switch_node(t), "value"): True for t in tags}))
    bridge = _Recorded()
    GazeboOut("sample_substation", bridge=bridge)._switches(twin)
    return [line for line in bridge.lines if line[0] == "joint"]


def test_every_switch_command_reaches_a_joint_gazebo_moves(sample_build):
    if not gazebo.available():
        if CI:
            pytest.fail(gazebo.PROBE_HINT)
        pytest.skip(gazebo.PROBE_HINT)
    lines = _open_every_switch(sample_build, sample_build.parent / "sources")
    assert len(lines) > 100  # the sample's disconnect switches, two joints each
    world = next((sample_build / "scene").glob("*.sdf"))
    env = dict(os.environ, SDF_PATH=str((sample_build / "models").resolve()))
    done = subprocess.run([str(gazebo.PROBE), "world", str(world), "--no-meshes", "--joints"],
                          capture_output=True, text=True, env=env, timeout=600, check=False)
    report = json.loads(done.stdout)
    assert report["world"]["errors"] == [] and report["joints"]["joints_failed"] == 0
    listening = {c["topic"]: c for c in report["joints"]["controllers"]}
    for _, topic, position in lines:
        c = listening.get(topic)
        assert c is not None, f"no JointPositionController listens on {topic}"
        assert c["found"] and c["in_physics"] and not c["static"] and c["velocity_commands"]
        # the position the twin opens it to is the limit the probe sets: the probe turned it there
        assert c["set"] == pytest.approx(float(position))
        assert c["child_rotation_rad"] == pytest.approx(abs(float(position)), abs=1e-9)
        # its links move, nothing else: not the fixed parts (the grouped static model), not another switch
        tag = topic.split("/")[2]
        assert c["model"] + "::" + c["child"] in c["moved"]
        assert all(name.startswith(f"{c['model']}::{tag}__") for name in c["moved"])


def _switch_build(root, record: dict | None):
    """A build of two switches (their manifests' revolute joints) whose placements.json
    records `record` as what the world was written with (None: no record)."""
    from pipeline.export import manifest as manifest_io

    pkg = root / "models" / "dsw"
    pkg.mkdir(parents=True)
    joints = [{"name": "blade", "type": "revolute", "parent": "base", "child": "blade", "lower": 0.0, "upper": 1.5},
              {"name": "column", "type": "revolute", "parent": "base", "child": "column", "lower": -1.2, "upper": 0.0}]
    (pkg / manifest_io.MANIFEST).write_text(json.dumps({"category": "switchgear", "joints": joints}))
    (root / "scene").mkdir()
    placements = [{"tag": tag, "asset": "dsw", "enu": [float(k), 0.0, 0.0], "yaw_rad": 0.0}
                  for k, tag in enumerate(("89-1", "89-2"))]
    (root / "scene" / "placements.json").write_text(json.dumps({
        "origin": {"latitude_deg": -12.7, "longitude_deg": -38.3, "height_m": 48.0}, "timezone": "America/Bahia",
        "placements": placements, **({"gazebo": record} if record is not None else {})}))
    return root


def _push_open(build) -> tuple[GazeboOut, list]:
    site = load_site(build, build / "no-sources")
    tags = switchgear(site)
    twin = SimpleNamespace(site=site, switches={switch_node(t): t for t in tags}, wires=None,
                           engine=SimpleNamespace(values={(switch_node(t), "value"): True for t in tags}))
    bridge = _Recorded()
    out = GazeboOut("w", bridge=bridge)
    out._switches(twin)
    return out, [line for line in bridge.lines if line[0] == "joint"]


def test_a_world_built_without_moving_parts_gets_no_joint_command(tmp_path):
    """[gazebo] moving_parts = "none", as the build's placements.json records it: no
    joint command for any switch, each listed as not applied with the setting named;
    a build that records "all" (or nothing, as before the setting) gets its commands."""
    out, lines = _push_open(_switch_build(tmp_path / "none", {"moving_parts": "none"}))
    assert lines == []
    assert sorted(out.status()["not_applied"]) == [f"{tag} (switch: the world was built with [gazebo] moving_parts"
                                                   f" = \"none\", it has no joint to move)" for tag in ("89-1", "89-2")]
    for record in ({"moving_parts": "all"}, None):
        out, lines = _push_open(_switch_build(tmp_path / f"all-{record is None}", record))
        assert sorted(lines) == [("joint", joint_command_topic(tag, joint), repr(angle)) for tag in ("89-1", "89-2")
                                 for joint, angle in (("blade", 1.5), ("column", -1.2))]
        assert out.status()["not_applied"] == []


def test_a_world_built_with_some_switches_moving_commands_those_alone(tmp_path):
    """[gazebo] moving_parts = ["89-2"]: the joint commands of the switch the world moves,
    and the other listed as not applied, naming the patterns it matches none of."""
    out, lines = _push_open(_switch_build(tmp_path / "some", {"moving_parts": ["89-2", "Q*"]}))
    assert sorted(lines) == [("joint", joint_command_topic("89-2", joint), repr(angle))
                             for joint, angle in (("blade", 1.5), ("column", -1.2))]
    assert out.status()["not_applied"] == [
        "89-1 (switch: the world was built with [gazebo] moving_parts = ['89-2', 'Q*'] (its tag matches none), "
        "it has no joint to move)"]


def test_a_world_auto_built_at_rest_says_auto_chose_it(tmp_path):
    """moving_parts = "auto" over the parse budget, as placements.json records it: the
    switches are not applied, and the reason names "auto" rather than a "none" that
    site.toml does not hold."""
    record = {"moving_parts": "none", "chosen_by": "auto", "parse_estimate_mb": 3451}
    out, lines = _push_open(_switch_build(tmp_path / "auto", record))
    assert lines == []
    assert sorted(out.status()["not_applied"]) == [
        f'{tag} (switch: the world was built with [gazebo] moving_parts = "auto", which chose "none": every switch '
        "moving would take the world over its parse budget, it has no joint to move)" for tag in ("89-1", "89-2")]

