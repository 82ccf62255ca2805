"""The Gazebo world's moving parts (scene.world_joints): each movable joint of a grouped
placement is a joint of a non-static model that gz-sim's JointPositionController moves,
listening on the topic the live twin publishes on; dartsim moves its links and nothing
else; at rest the placement shows what its variant placed alone shows, as it does in a
world written without moving parts ([gazebo] moving_parts = "none")."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from fixtures_assets import articulated_asset
from pipeline import config, ir
from pipeline.export.names import MOVABLE_JOINTS, joint_command_topic, lod_model_name
from pipeline.export.package import write_package
from pipeline.scene import world_joints, world_sdf
from pipeline.scene.placements import Placed, yaw_matrix
from pipeline.validate import gazebo

SAFE = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)
CI = bool(os.environ.get("CI"))
ASSET = articulated_asset()
# tag -> (yaw, ENU position, LOD, scale); A-3 repeats A-1 exactly (piled on its point)
PLACES = {"A-1": (0.3, (10.0, 5.0, 1.0), 0, 1.0), "A-2": (-2.0, (-40.0, 12.0, 3.0), 1, 1.0),
          "A-3": (0.3, (10.0, 5.0, 1.0), 0, 1.0), "A-4": (1.1, (25.0, -30.0, 0.5), 1, 1.5)}


def _placed() -> list[Placed]:
    return [Placed(ir.Placement(tag, ASSET.id, "L1", 0.0, 0.0, scale=scale), yaw_matrix(yaw, enu), yaw, lod)
            for tag, (yaw, enu, lod, scale) in PLACES.items()]


def _write_world(world: Path, models: Path, moving_parts: str | tuple[str, ...] = "all") -> Path:
    """A world of the fixture's four placements (no terrain: no package of it here),
    their switches moving as site.toml's [gazebo] moving_parts says."""
    world.parent.mkdir(exist_ok=True)
    world_sdf.write(world, site_name="w", origin_llh=(-12.7, -38.3, 48.0), placed=_placed(), terrain_model="none",
                    sun={"intensity": 1.0, "elevation_deg": 40.0, "azimuth_deg": 30.0}, models=models,
                    moves=lambda tag: config.moves_in_gazebo(moving_parts, tag))
    root = etree.parse(str(world), SAFE).getroot()
    for include in root.iter("include"):
        include.getparent().remove(include)
    world.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    return world


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    """The fixture's package and a world of its four placements (no terrain)."""
    out = tmp_path_factory.mktemp("world_joints")
    write_package(ASSET, out / "models")
    return out, _write_world(out / "scene" / "w.sdf", out / "models")


def _probe_joints(out: Path, world: Path) -> dict:
    """tools/gzprobe's report of `world` (the packages in out/models): its joints and
    controllers, and a short physics run; skipped without the probe (failed in CI)."""
    import json

    if not gazebo.available():
        if CI:
            pytest.fail(gazebo.PROBE_HINT)
        pytest.skip(gazebo.PROBE_HINT)
    env = dict(os.environ, SDF_PATH=str((out / "models").resolve()))
    done = subprocess.run([str(gazebo.PROBE), "world", str(world), "--joints", "--physics", "0.05"],
                          capture_output=True, text=True, env=env, timeout=300, check=False)
    return json.loads(done.stdout)


@pytest.fixture(scope="module")
def probed(built) -> dict:
    return _probe_joints(*built)


def _movable() -> list[ir.Joint]:
    return [j for j in ASSET.joints if j.type in MOVABLE_JOINTS]


def _below(link: str) -> set[str]:
    """`link` and every link below it."""
    out = {link}
    for j in ASSET.joints:
        if j.parent in out or j.parent == link:
            out |= _below(j.child)
    return out


def test_each_movable_joint_has_a_controller_on_the_twins_topic(built):
    _, world = built
    root = etree.parse(str(world), SAFE).getroot()
    moving = [m for m in root.findall("world/model") if m.get("name").endswith(world_joints.MODEL_SUFFIX)]
    assert moving and all(m.findtext("static") in (None, "false") for m in moving)
    plugins = {p.findtext("joint_name"): p for m in moving for p in m.findall("plugin")}
    joints = {j.get("name"): j for m in moving for j in m.findall("joint")}
    for tag in PLACES:
        for joint in _movable():
            plugin = plugins[f"{tag}__{joint.name}"]
            assert plugin.get("filename") == "ignition-gazebo-joint-position-controller-system"
            assert plugin.get("name") == "ignition::gazebo::systems::JointPositionController"
            assert plugin.findtext("topic") == joint_command_topic(tag, joint.name)
            assert plugin.findtext("use_velocity_commands") == "true"
            assert float(plugin.findtext("cmd_max")) == joint.velocity
            # a joint from the fixed base hangs on the world; one below a moving link on it
            parent = joints[f"{tag}__{joint.name}"].findtext("parent")
            assert parent == ("world" if joint.parent == "base" else f"{tag}__{joint.parent}")
    # the grouped model draws the fixed link only; the moving links draw in their own model
    grouped = [m for m in root.findall("world/model") if m.find("frame") is not None]
    drawn = {v.get("name") for m in grouped for v in m.iter("visual")}
    assert drawn and all(name.split("__")[1] == "base" for name in drawn)
    assert {link.get("name") for m in moving for link in m.findall("link")} == {
        f"{tag}__{name}" for tag in PLACES for name in ("arm", "gauge", "slider")}


def test_the_world_passes_ign_sdf(built):
    out, world = built
    if shutil.which("ign") is None:
        if CI:
            pytest.fail("ign is not installed (bash .ci/install-tools)")
        pytest.skip("ign is not installed")
    env = dict(os.environ, SDF_PATH=str((out / "models").resolve()))
    done = subprocess.run(["ign", "sdf", "-k", str(world)], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0 and "Valid" in done.stdout, done.stdout + done.stderr


def test_dartsim_moves_each_joints_links_and_nothing_else(probed):
    assert probed["world"]["errors"] == []
    joints = probed["joints"]
    assert joints["ok"] and joints["joints_failed"] == 0
    by_topic = {c["topic"]: c for c in joints["controllers"]}
    assert len(by_topic) == len(joints["controllers"]) == len(PLACES) * len(_movable())
    for tag in PLACES:
        for joint in _movable():
            c = by_topic[joint_command_topic(tag, joint.name)]
            assert c["found"] and c["in_physics"] and not c["static"] and c["velocity_commands"]
            far = joint.lower if abs(joint.lower) > abs(joint.upper) else joint.upper
            assert c["set"] == pytest.approx(far)
            assert {name.split("::")[1] for name in c["moved"]} == {f"{tag}__{n}" for n in _below(joint.child)}
            if joint.type == "revolute":
                turned = abs(far) if abs(far) <= math.pi else 2 * math.pi - abs(far)
                assert c["child_rotation_rad"] == pytest.approx(turned, abs=1e-9)
            else:  # the slide: along its axis, by the position set
                assert c["child_rotation_rad"] == pytest.approx(0.0, abs=1e-9)
                assert c["child_translation_m"] == pytest.approx(abs(far), abs=1e-9)
    physics = probed["physics"]
    assert physics["ok"] and physics["failed_joints"] == 0
    assert physics["joints"] == physics["velocity_commanded_joints"] == len(PLACES) * len(_movable())


def _visual_points(uses: list[dict], world_from_model: np.ndarray) -> np.ndarray:
    """(n, 3) every vertex of the meshes Gazebo placed (the probe's rows), in the world."""
    import collada

    points = []
    for use in uses:
        m = world_from_model @ np.array(use["model_from_mesh"]).reshape(4, 4)
        m[:3, :3] = m[:3, :3] * np.asarray(use["scale"])  # a mesh's <scale> in its own frame
        for geometry in collada.Collada(use["path"]).scene.objects("geometry"):
            for prim in geometry.primitives():
                points.append(np.asarray(prim.vertex, dtype=np.float64) @ m[:3, :3].T + m[:3, 3])
    return np.concatenate(points)


def _assert_each_placement_shows_its_variant_alone(out: Path, probed: dict, scratch: Path) -> None:
    """Every placement's visuals (grouped `<TAG>__...`, moving links `<TAG>__<link>`)
    have the same vertices, where Gazebo puts them, as the variant included alone at the
    placement's pose (at its scale)."""
    models = {m["name"]: m for m in probed["models"]}
    for tag, (yaw, enu, lod, scale) in PLACES.items():
        if tag == "A-3":
            continue  # drawn by A-1, which it repeats (its moving links are its own: checked above)
        uses = [(u, m) for m in models.values() for u in m["meshes"] if u["kind"] == "visual"
                and (u["name"].startswith(tag + "__") or u["link"].startswith(tag + "__"))]
        ours = np.concatenate([_visual_points([u], np.array(m["world_from_model"]).reshape(4, 4)) for u, m in uses])
        variant = lod_model_name(ASSET.id, lod)
        alone = scratch / f"{tag}.sdf"
        pose = " ".join(map(repr, (*enu, 0.0, 0.0, yaw)))
        alone.write_text(f'<?xml version="1.0"?><sdf version="1.9"><world name="w"><include><uri>model://{variant}'
                         f'</uri><name>{tag}</name><pose>{pose}</pose></include></world></sdf>\n')
        single = gazebo.probe_world(alone, [out / "models"])["models"][0]
        place = np.array(single["world_from_model"]).reshape(4, 4)
        scaled = place @ np.diag([scale, scale, scale, 1.0])  # the include drawn at the placement's scale
        theirs = _visual_points([u for u in single["meshes"] if u["kind"] == "visual"], scaled)
        assert len(ours) == len(theirs), tag
        np.testing.assert_allclose(np.sort(ours, axis=0), np.sort(theirs, axis=0), atol=1e-6, err_msg=tag)


def test_at_rest_a_placement_shows_what_its_variant_alone_shows(built, probed, tmp_path):
    """Its fixed link's visual in the grouped model and its moving links' in the model
    of moving parts."""
    out, _ = built
    _assert_each_placement_shows_its_variant_alone(out, probed, tmp_path)


def test_a_world_without_moving_parts_draws_each_switch_whole_at_rest(built, tmp_path):
    """[gazebo] moving_parts = "none": no joint, no controller, no model of moving parts;
    each placement is drawn by the static grouped model alone, whole and at rest (the
    world with them, from the same package, has all three)."""
    out, with_joints = built
    world = _write_world(tmp_path / "scene" / "w.sdf", out / "models", moving_parts="none")
    for path, moving in ((with_joints, True), (world, False)):
        root = etree.parse(str(path), SAFE).getroot()
        models = root.findall("world/model")
        assert bool(root.findall(".//joint")) == bool(root.findall(".//plugin")) == moving, path
        assert any(m.get("name").endswith(world_joints.MODEL_SUFFIX) for m in models) == moving, path
        assert all(m.findtext("static") == "true" for m in models) != moving, path
    root = etree.parse(str(world), SAFE).getroot()
    drawn = {v.get("name") for v in root.iter("visual")}
    # the whole model as one visual, or at the finest LOD (no whole mesh) a copy of every
    # link's visuals; A-3 repeats A-1: its frame alone
    each_visual = {f"{link.name}__{v.name}" for link in ASSET.links for v in link.visuals}
    assert drawn == {f"{tag}__{name}" for tag, (_, _, lod, _) in PLACES.items() if tag != "A-3"
                     for name in (each_visual if lod == 0 else {"whole"})}
    assert {f.get("name") for f in root.iter("frame")} == set(PLACES)
    probed = _probe_joints(out, world)
    assert probed["world"]["errors"] == [] and probed["joints"]["controllers"] == []
    assert probed["physics"]["ok"] and probed["physics"]["joints"] == 0
    _assert_each_placement_shows_its_variant_alone(out, probed, tmp_path)


def test_a_world_with_some_switches_moving_hangs_those_alone_on_joints(built, tmp_path):
    """[gazebo] moving_parts = ["A-2", "A-[4]"]: A-2's and A-4's moving links on joints
    with a controller each, and Gazebo's own loaders find every one in physics; A-1
    (and A-3, piled on it) drawn whole and at rest in the grouped model, as under "none"."""
    out, _ = built
    world = _write_world(tmp_path / "scene" / "w.sdf", out / "models", moving_parts=("A-2", "A-[4]"))
    root = etree.parse(str(world), SAFE).getroot()
    moving = [m for m in root.findall("world/model") if world_joints.MODEL_SUFFIX in m.get("name")]
    topics = {p.findtext("topic") for m in moving for p in m.findall("plugin")}
    assert topics == {joint_command_topic(tag, j.name) for tag in ("A-2", "A-4") for j in _movable()}
    assert {link.get("name").split("__")[0] for m in moving for link in m.findall("link")} == {"A-2", "A-4"}
    drawn = {v.get("name") for m in root.findall("world/model") if m.find("frame") is not None
             for v in m.iter("visual")}
    assert {name for name in drawn if name.startswith("A-1__")} == {f"A-1__{link.name}__{v.name}"
                                                                   for link in ASSET.links for v in link.visuals}
    assert {name.split("__")[1] for name in drawn if name.startswith(("A-2__", "A-4__"))} == {"base"}
    probed = _probe_joints(out, world)
    assert probed["world"]["errors"] == [] and probed["joints"]["joints_failed"] == 0
    controllers = probed["joints"]["controllers"]
    assert {c["topic"] for c in controllers} == topics
    assert all(c["found"] and c["in_physics"] and not c["static"] for c in controllers)
    assert probed["physics"]["ok"] and probed["physics"]["joints"] == len(topics)


def test_auto_moves_every_switch_within_the_parse_budget_and_none_beyond_it(built, tmp_path, monkeypatch):
    """[gazebo] moving_parts = "auto" (scene.world_sdf.write_within_budget): the four
    placements' world, estimated far under 1.5 GB, is the world with every switch
    moving; under a budget it exceeds, the world with none, byte for byte."""
    out, with_joints = built
    args = dict(site_name="w", origin_llh=(-12.7, -38.3, 48.0), placed=_placed(), terrain_model="none",
                sun={"intensity": 1.0, "elevation_deg": 40.0, "azimuth_deg": 30.0}, models=out / "models")
    for budget, expected in ((world_sdf.PARSE_BUDGET_MB, "all"), (100.0, "none")):
        monkeypatch.setattr(world_sdf, "PARSE_BUDGET_MB", budget)
        auto = tmp_path / expected / "auto.sdf"
        auto.parent.mkdir()
        chosen, estimate = world_sdf.write_within_budget(auto, **args)
        assert chosen == expected
        root = etree.parse(str(auto), SAFE).getroot()
        visuals, joints = len(list(root.iter("visual"))), len(list(root.iter("joint")))
        assert estimate == pytest.approx(world_sdf.PARSE_MB_BASE + world_sdf.PARSE_MB_PER_VISUAL * visuals
                                         + world_sdf.PARSE_MB_PER_JOINT * joints) if expected == "all" else \
            estimate > 100.0
        same = tmp_path / expected / "explicit.sdf"
        world_sdf.write(same, moves=lambda tag: expected == "all", **args)
        assert auto.read_bytes() == same.read_bytes()


def test_a_joint_posed_in_another_frame_is_one_clear_error(tmp_path):
    from pipeline.errors import UserError

    model = tmp_path / "model.sdf"
    model.write_text('<?xml version="1.0"?><sdf version="1.9"><model name="m"><link name="base"/><link name="blade"/>'
                     '<joint name="hinge" type="revolute"><parent>base</parent><child>blade</child>'
                     '<pose relative_to="base">0 0 1 0 0 0</pose><axis><xyz>0 1 0</xyz></axis></joint>'
                     '</model></sdf>\n')
    with pytest.raises(UserError) as caught:
        world_joints.read_articulation(model)
    assert caught.value.file == str(model) and caught.value.obj == "hinge" and "'base'" in caught.value.message
    model.write_text(model.read_text().replace('relative_to="base"', 'relative_to="blade"'))
    assert world_joints.read_articulation(model).moving == ("blade",)


def test_the_scene_records_what_auto_chose_and_warns_when_it_is_none(mini_copy, tmp_path, monkeypatch):
    """The scene task (in this process) on the mini build under a budget its world
    exceeds: placements.json records "none", chosen by "auto" with the estimate, and
    GZ012 among its findings; under the real budget, "all" and no GZ012."""
    import json

    from pipeline.scene.assemble import build_scene

    src, out = mini_copy
    for budget, chosen in ((world_sdf.PARSE_BUDGET_MB, "all"), (50.0, "none")):
        monkeypatch.setattr(world_sdf, "PARSE_BUDGET_MB", budget)
        staging = tmp_path / f"staging-{chosen}"
        build_scene(staging, str(src), str(out))
        record = json.loads((staging / "scene" / "placements.json").read_text())
        assert record["gazebo"]["moving_parts"] == chosen and record["gazebo"]["chosen_by"] == "auto"
        assert record["gazebo"]["parse_estimate_mb"] > 50
        warned = [f for f in record["findings"] if f["code"] == "GZ012"]
        assert len(warned) == (chosen == "none")
        if warned:
            assert warned[0]["severity"] == "warning" and "moving_parts" in warned[0]["message"]
