"""pipeline.ingest.blend on small .blend files authored by tests/blend_fixtures.py in a
subprocess (a clean Blender), plus the sample assets when they exist."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from helpers import CORPUS, ROOT, TESTS
from pipeline import ir
from pipeline.config import load_asset_config
from pipeline.errors import UserError
from pipeline.ingest.blend import build_mesh, read_blend, read_blend_path, split_rigid


def _has_bpy() -> bool:
    import importlib.util

    return importlib.util.find_spec("bpy") is not None


blender = pytest.mark.skipif(not _has_bpy(), reason="needs bpy (pip install 'substation-twin[blender]')")


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    out = tmp_path_factory.mktemp("blend")
    marker = out / "marker"
    run = subprocess.run(
        [sys.executable, str(TESTS / "blend_fixtures.py"), str(out), str(marker)],
        capture_output=True, text=True, timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert not list(out.glob("marker*")), "authoring must not have run the hostile code"
    return out


@pytest.fixture(scope="module")
def full(fx):
    return read_blend_path(fx / "full.blend", "full", "test", mass_kg=50.0)


def _visual(asset: ir.Asset, name: str) -> tuple[ir.Link, ir.Visual]:
    for link, v in asset.visuals():
        if v.name == name:
            return link, v
    raise KeyError(name)


def _signed_volume(mesh: ir.Mesh) -> float:
    t = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# --- pure helpers (no Blender) -------------------------------------------------------


def test_split_rigid_keeps_rotation_and_bakes_mirror():
    rot = _rot_z(40.0) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])
    m = np.eye(4)
    m[:3, :3] = rot @ np.diag([2.0, -0.5, 3.0])
    m[:3, 3] = (1.0, 2.0, 3.0)
    p, s = split_rigid(m)
    assert np.isclose(np.linalg.det(p[:3, :3]), 1.0)
    assert np.allclose(p[:3, :3].T @ p[:3, :3], np.eye(3))
    assert np.allclose(p[:3, 3], (1.0, 2.0, 3.0))
    assert np.allclose(p[:3, :3] @ s, m[:3, :3])
    assert np.linalg.det(s) < 0
    unscaled = np.eye(4)
    unscaled[:3, :3] = rot
    p, s = split_rigid(unscaled)
    assert np.allclose(p[:3, :3], rot) and np.allclose(s, np.eye(3))
    with pytest.raises(ValueError):
        split_rigid(np.diag([1.0, 0.0, 1.0, 1.0]))


def test_build_mesh_splits_uv_seams_and_flips_mirrored_winding():
    co = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    tris = np.array([[0, 1, 2], [2, 1, 3]])
    uvs = np.array([[[0, 0], [1, 0], [0, 1]], [[0.5, 0.5], [1, 0], [1, 1]]])  # vertex 2 disagrees
    mesh = build_mesh(co, tris, uvs, np.diag([-1.0, 1.0, 1.0]))
    assert len(mesh.vertices) == 5
    t = mesh.vertices[mesh.faces]
    normals = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(normals[:, 2] > 0)  # +Z before the mirror, still +Z after it
    assert np.allclose(mesh.uvs[mesh.faces], uvs[:, ::-1])


# --- fixture files -----------------------------------------------------------------------


@pytest.mark.blender
@blender
def test_links_and_two_joints(full):
    assert [link.name for link in full.links] == ["base", "hinge_link", "slider_link"]
    assert full.root_link.name == "base"
    hinge, slider = full.joints
    assert (hinge.name, hinge.type, hinge.parent, hinge.child) == ("hinge", "revolute", "base", "hinge_link")
    assert (hinge.lower, hinge.upper, hinge.effort, hinge.velocity) == pytest.approx((-0.5, 1.2, 10.0, 1.5))
    assert np.allclose(hinge.pose[:3, :3], _rot_z(30.0), atol=1e-6)
    assert np.allclose(hinge.pose[:3, 3], (1.0, 0.0, 1.0))
    assert np.allclose(hinge.axis, (0.0, 0.0, 1.0))
    assert np.allclose(full.link("hinge_link").pose, hinge.pose)

    # The slider Empty sits under the arm (scale 1, 0.2, 0.2): its pivot frame drops
    # the scale, its authored axis (1, 0, 1) is seen through it, as Blender draws it.
    assert (slider.type, slider.parent, slider.child) == ("prismatic", "hinge_link", "slider_link")
    assert (slider.lower, slider.upper) == pytest.approx((0.0, 0.3))
    assert np.allclose(slider.axis, np.array([1.0, 0.0, 0.2]) / math.hypot(1.0, 0.2), atol=1e-6)
    expected = (1.0 + 1.5 * math.cos(math.radians(30)), 1.5 * math.sin(math.radians(30)), 1.0)
    assert np.allclose(slider.pose[:3, 3], expected, atol=1e-6)
    assert np.allclose(slider.pose[:3, :3], _rot_z(30.0), atol=1e-6)
    assert slider.pose.dtype == np.float64


@pytest.mark.blender
@blender
def test_visual_poses_are_rigid_and_scale_is_baked(full):
    link, arm = _visual(full, "arm")
    assert link.name == "hinge_link"
    assert np.allclose(arm.pose, np.array([[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]), atol=1e-6)
    lo, hi = arm.mesh.bounds()
    assert np.allclose(hi - lo, (1.0, 0.2, 0.2), atol=1e-6)
    link, carriage = _visual(full, "carriage")
    assert link.name == "slider_link"
    world = link.pose @ carriage.pose
    assert np.allclose(world[:3, :3] @ world[:3, :3].T, np.eye(3), atol=1e-6)
    assert np.allclose(world[:3, 3], full.joints[1].pose[:3, 3], atol=1e-6)
    lo, hi = carriage.mesh.bounds()
    assert np.allclose(hi - lo, (1.0, 0.2, 0.2), atol=1e-6)


@pytest.mark.blender
@blender
def test_collision_mesh_is_not_a_visual(full):
    base = full.link("base")
    assert [c.name for c in base.collisions] == ["frame_collision"]
    assert "frame_collision" not in [v.name for _, v in full.visuals()]
    lo, hi = base.collisions[0].mesh.bounds()
    assert np.allclose(hi - lo, 1.1, atol=1e-6)
    assert np.allclose(base.collisions[0].pose[:3, 3], (0.0, 0.0, 0.5))


@pytest.mark.blender
@blender
def test_array_modifier_is_evaluated(full):
    _, rail = _visual(full, "rail")
    assert rail.mesh.triangle_count == 5 * 12
    lo, hi = rail.mesh.bounds()
    assert np.allclose(hi - lo, (5.0, 1.0, 1.0))


@pytest.mark.blender
@blender
def test_negative_scale_keeps_faces_outward(full):
    _, frame = _visual(full, "frame")
    assert _signed_volume(frame.mesh) == pytest.approx(1.0)
    _, mirrored = _visual(full, "mirrored")
    assert np.isclose(np.linalg.det(mirrored.pose[:3, :3]), 1.0)
    assert _signed_volume(mirrored.mesh) == pytest.approx(2.0)  # |det(scale)| = 2, outward
    world = mirrored.mesh.vertices @ mirrored.pose[:3, :3].T + mirrored.pose[:3, 3]
    assert np.allclose(world.min(axis=0), (-2.5, -0.5, -1.0)) and np.allclose(world.max(axis=0), (-1.5, 0.5, 1.0))


@pytest.mark.blender
@blender
def test_materials_split_and_principled_inputs(full):
    names = sorted(v.name for _, v in full.visuals() if v.name.startswith("twotone"))
    assert names == ["twotone__paint", "twotone__steel"]
    for name in names:
        _, v = _visual(full, name)
        assert v.mesh.triangle_count == 6 and v.material == name.split("__")[1]
    alarm = full.material("lamp_alarm")
    assert alarm.base_color == pytest.approx((1.0, 0.1, 0.0, 0.8), abs=1e-6)
    assert alarm.emission == pytest.approx((4.0, 2.0, 1.0), abs=1e-6)
    assert (alarm.metallic, alarm.roughness) == pytest.approx((0.0, 0.3), abs=1e-6)
    assert full.material("steel").metallic == pytest.approx(1.0)


@pytest.mark.blender
@blender
def test_uvs_split_where_corners_disagree(full):
    _, box = _visual(full, "uvbox")
    assert box.mesh.uvs is not None and len(box.mesh.vertices) > 8
    corners = {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)}
    for tri in box.mesh.uvs[box.mesh.faces]:
        assert {tuple(map(float, uv)) for uv in tri} <= corners and len({tuple(uv) for uv in tri}) == 3


@pytest.mark.blender
@blender
def test_shape_key_and_bindings(full):
    _, level = _visual(full, "level")
    (key,) = level.mesh.shape_keys
    assert key.name == "full"
    assert level.mesh.vertices[:, 2].max() == pytest.approx(0.5)  # the basis, not the 0.7 mix
    assert key.vertices[:, 2].max() == pytest.approx(1.5)
    by_target = {b.target: b for b in full.bindings}
    assert set(by_target) == {"lamp", "level", "pointer"}
    shape = by_target["level"]
    assert (shape.variable, shape.effect, shape.shape_key) == ("oil_level", "shape", "full")
    lamp = by_target["lamp"]
    assert (lamp.effect, lamp.materials, lamp.thresholds) == ("material", ("lamp_off", "lamp_alarm"), (0.5,))
    assert lamp.output(0.7) == 1 and lamp.output(0.2) == 0
    pointer = by_target["pointer"]
    assert (pointer.effect, pointer.axis, pointer.range) == ("rotate", (0.0, 0.0, 1.0), (0.0, 4.0))
    assert {m.name for m in full.materials} >= {"lamp_off", "lamp_alarm"}


@pytest.mark.blender
@blender
def test_shape_keys_through_modifiers(fx):
    asset = read_blend_path(fx / "shape_modifier.blend", "g", "test")
    _, gauge = _visual(asset, "gauge")
    assert gauge.mesh.triangle_count == 48  # a cube subdivided once
    (key,) = gauge.mesh.shape_keys
    assert key.vertices.shape == gauge.mesh.vertices.shape
    assert key.vertices[:, 2].max() > 2.0 * gauge.mesh.vertices[:, 2].max()
    assert asset.bindings[0].shape_key == "high"


@pytest.mark.blender
@blender
def test_view_layer_objects_hidden_ones_included(fx):
    asset = read_blend_path(fx / "visibility.blend", "v", "test")
    counts = {v.name: v.mesh.triangle_count for _, v in asset.visuals()}
    # Hidden objects are evaluated like visible ones (the subsurf applies); an
    # excluded collection is not part of the asset.
    assert counts == {"hidden": 48, "on_shelf": 12, "shown": 12}


@pytest.mark.blender
@blender
def test_mass_is_split_and_deterministic(fx, full):
    assert sum(link.mass for link in full.links) == pytest.approx(50.0)
    assert all(link.mass > 0 for link in full.links)
    assert full.link("base").mass > full.link("hinge_link").mass
    again = read_blend_path(fx / "full.blend", "full", "test", mass_kg=50.0)
    for a, b in zip(full.visuals(), again.visuals()):
        assert a[1].name == b[1].name and np.array_equal(a[1].mesh.vertices, b[1].mesh.vertices)
    assert full.metadata == again.metadata == (
        ("source_format", "blend"),
        ("notes", "level: shape key values full=0.7 left to its shape binding (the rest mesh is the reference key)"))


@pytest.mark.blender
@blender
def test_no_state_leaks_between_files(fx, full):
    read_blend_path(fx / "full.blend", "full", "test")
    other = read_blend_path(fx / "shape_modifier.blend", "g", "test")
    assert [v.name for _, v in other.visuals()] == ["gauge"]
    assert [m.name for m in other.materials] == ["steel"]


@pytest.mark.blender
@blender
def test_hostile_file_runs_nothing(fx, tmp_path):
    hostile = tmp_path / "hostile.blend"
    shutil.copy(fx / "hostile.blend", hostile)
    asset = read_blend_path(hostile, "h", "test")
    assert not list(fx.glob("marker*"))
    assert ("notes", "tri.location[0]: Python driver not evaluated") in asset.metadata
    _, tri = _visual(asset, "tri")
    assert np.allclose(tri.pose[:3, 3], 0.0)  # the driver would have set x = 1
    # Control: the same file with auto-execution on does write both files, so the
    # assertion above can fail.
    trusting = textwrap.dedent(f"""
        import bpy
        bpy.context.preferences.filepaths.use_scripts_auto_execute = True
        bpy.ops.wm.open_mainfile(filepath={str(hostile)!r}, load_ui=False, use_scripts=True)
        bpy.context.evaluated_depsgraph_get().update()
    """)
    subprocess.run([sys.executable, "-c", trusting], capture_output=True, timeout=120)
    assert sorted(p.name for p in fx.glob("marker*")) == ["marker.driver", "marker.text"]
    for p in fx.glob("marker*"):
        p.unlink()


@pytest.mark.blender
@blender
@pytest.mark.parametrize("fraction", [0.0, 0.1, 0.5, 0.97])
def test_truncated_file_is_a_user_error(fx, tmp_path, fraction):
    data = (fx / "full.blend").read_bytes()
    bad = tmp_path / "cut.blend"
    bad.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(UserError) as err:
        read_blend_path(bad, "cut", "test")
    assert err.value.file == str(bad) and "truncated or corrupt" in err.value.message


@pytest.mark.blender
@blender
def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(UserError, match="file not found"):
        read_blend_path(tmp_path / "nope.blend", "x", "test")
    text = tmp_path / "text.blend"
    text.write_text("not a blend file\n")
    with pytest.raises(UserError, match="not a readable .blend"):
        read_blend_path(text, "x", "test")


@pytest.mark.blender
@blender
@pytest.mark.parametrize(
    "name, obj, words",
    [
        ("bad_joint", "hinge", "joint = 'rotary'"),
        ("zero_axis", "hinge", "zero length"),
        ("bad_effect", "box", "state_effect = 'wobble'"),
        ("empty_mesh", "nothing", "no faces"),
        ("orphan_collision", "hinge_collision", "no visual geometry"),
        ("nan", "bad_points", "NaN"),
        ("no_geometry", None, "no mesh objects"),
    ],
)
def test_bad_input_names_file_and_object(fx, name, obj, words):
    with pytest.raises(UserError) as err:
        read_blend_path(fx / f"{name}.blend", name, "test")
    assert err.value.file == str(fx / f"{name}.blend")
    assert err.value.obj == obj
    assert words in err.value.message


def _asset_folder(tmp_path: Path, fx: Path, bindings: str) -> Path:
    folder = tmp_path / "rig"
    folder.mkdir()
    shutil.copy(fx / "full.blend", folder / "rig.blend")
    (folder / "asset.toml").write_text(
        'category = "test"\nsource = "rig.blend"\nmass_kg = 20.0\n' + textwrap.dedent(bindings)
    )
    return folder / "asset.toml"


@pytest.mark.blender
@blender
def test_asset_toml_bindings_are_merged(fx, tmp_path):
    toml = _asset_folder(tmp_path, fx, """
        [[bindings]]
        target = "twotone"
        variable = "temperature"
        effect = "translate"
        domain = [0.0, 100.0]
        range = [0.0, 0.2]
        axis = [0.0, 0.0, 2.0]
    """)
    asset = read_blend(load_asset_config(toml))
    assert asset.id == "rig" and asset.source == str(toml.parent / "rig.blend")
    merged = [b for b in asset.bindings if b.variable == "temperature"]
    assert [b.target for b in merged] == ["twotone__paint", "twotone__steel"]
    assert merged[0].axis == (0.0, 0.0, 1.0) and merged[0].range == (0.0, 0.2)
    assert len(asset.bindings) == 5
    assert sum(link.mass for link in asset.links) == pytest.approx(20.0)


@pytest.mark.blender
@blender
def test_asset_toml_binding_with_unknown_target(fx, tmp_path):
    toml = _asset_folder(tmp_path, fx, """
        [[bindings]]
        target = "no_such_thing"
        variable = "x"
        effect = "rotate"
        domain = [0.0, 1.0]
    """)
    with pytest.raises(UserError) as err:
        read_blend(load_asset_config(toml))
    assert err.value.file == str(toml) and err.value.obj == "bindings[0].target"


# --- the sample assets ---------------------------------------------------------------------

SAMPLES = sorted(
    p for p in (ROOT / "sources" / "assets").glob("*/asset.toml") if (p.parent / f"{p.parent.name}.blend").exists()
)


@pytest.mark.blender
@blender
@pytest.mark.parametrize("toml", SAMPLES, ids=[p.parent.name for p in SAMPLES])
def test_sample_asset(toml):
    cfg = load_asset_config(toml)
    if cfg.source.suffix != ".blend":
        pytest.skip("not a .blend source")
    t0 = time.perf_counter()
    asset = read_blend(cfg)
    elapsed = time.perf_counter() - t0
    print(f"{cfg.id}: {asset.triangle_count()} triangles read in {elapsed:.2f} s")
    assert asset.root_link.name == "base"
    assert len({link.name for link in asset.links}) == len(asset.links)
    assert {j.child for j in asset.joints} == {link.name for link in asset.links} - {"base"}
    assert asset.triangle_count() > 0
    assert sum(link.mass for link in asset.links) == pytest.approx(cfg.mass_kg)
    visuals = {v.name: v for _, v in asset.visuals()}
    for b in asset.bindings:
        assert b.target in visuals
        if b.effect == "shape":
            assert b.shape_key in [k.name for k in visuals[b.target].mesh.shape_keys]
        for m in b.materials:
            asset.material(m)
    effects = {(b.variable, b.effect) for b in asset.bindings}
    if cfg.id == "shunt_reactor":
        assert {("oil_level_tank", "rotate"), ("oil_level_tank", "material")} <= effects
        assert {("oil_level_b1", "shape"), ("oil_level_b2", "shape")} <= effects
    if cfg.id == "disconnect_switch_cb":
        revolute = [j for j in asset.joints if j.type == "revolute"]
        assert len(revolute) == 2
        assert all(j.lower is not None and j.upper is not None and j.lower < j.upper for j in revolute)


@blender
def test_textures_packed_and_beside_the_file_are_read_outside_ones_warned(fx):
    asset = read_blend_path(fx / "textured.blend", "textured", "test")
    painted = asset.material("painted")
    assert painted.base_color[:3] == (1.0, 1.0, 1.0)  # a linked Base Color: the image alone
    assert set(painted.textures()) == {"base_color", "normal"}
    assert painted.normal_texture.data == (fx / "bumps.png").read_bytes()
    from PIL import Image
    import io

    albedo = np.asarray(Image.open(io.BytesIO(painted.base_color_texture.data)).convert("RGB"))
    assert albedo.shape == (2, 4, 3) and albedo[..., 0].max() > 200 and albedo[..., 2].max() > 200
    _, panel = _visual(asset, "panel")
    np.testing.assert_allclose(np.sort(panel.mesh.uvs, axis=0), np.sort([[0, 0], [1, 0], [1, 1], [0, 1]], axis=0))
    assert asset.material("outside").textures() == {}
    warning = dict(asset.metadata)["warning.textures"]
    assert "'far'" in warning and "outside" in warning


# --- real .blend files: the corpus, units, what is not carried -------------------------------

BLEND_CORPUS = CORPUS / "blend"
ROBOT = BLEND_CORPUS / "RobotExpressive.blend"
APPLY = BLEND_CORPUS / "27_apply_modifier_with_shapekeys.blend"
corpus = pytest.mark.skipif(not BLEND_CORPUS.is_dir(), reason="needs ../shared/corpus")


def blend_tree(root: Path, asset_id: str, src: Path, extra: str = ""):
    """sources/assets/<asset_id>/ in `root` with a copy of `src` and an asset.toml."""
    folder = root / "sources" / "assets" / asset_id
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(src, folder / src.name)
    (folder / "asset.toml").write_text(f'category = "test"\nsource = "{src.name}"\n{extra}')
    return load_asset_config(folder / "asset.toml")


def model_points(asset: ir.Asset) -> np.ndarray:
    """(n, 3) every visual vertex in the model frame."""
    return np.concatenate([v.mesh.vertices @ (link.pose @ v.pose)[:3, :3].T + (link.pose @ v.pose)[:3, 3]
                           for link, v in asset.visuals()])


def in_blender(script: str, *args) -> dict:
    """Run `script` in a clean Blender (a subprocess); it prints one JSON line last."""
    import json

    run = subprocess.run([sys.executable, "-c", textwrap.dedent(script), *map(str, args)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


# The robot's meshes in world space with bpy alone, in the rest pose reached another way
# than the reader's (every pose bone's transform cleared, no action), and as saved.
ROBOT_BOUNDS = """
    import json, sys
    import bpy
    from mathutils import Matrix
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False, use_scripts=False)
    def bounds():
        dg = bpy.context.evaluated_depsgraph_get()
        pts = []
        for ob in bpy.context.view_layer.objects:
            if ob.type == "MESH":
                ev = ob.evaluated_get(dg)
                pts += [list(ev.matrix_world @ v.co) for v in ev.to_mesh().vertices]
                ev.to_mesh_clear()
        return [[min(p[i] for p in pts) for i in range(3)], [max(p[i] for p in pts) for i in range(3)]]
    saved = bounds()
    for ob in bpy.data.objects:
        if ob.type == "ARMATURE":
            ob.animation_data_clear()
            for pb in ob.pose.bones:
                pb.matrix_basis = Matrix.Identity(4)
    print(json.dumps({"saved": saved, "rest": bounds()}))
"""


@pytest.mark.blender
@blender
@corpus
def test_rigged_robot_is_read_in_its_rest_pose_and_says_what_it_leaves(tmp_path):
    cfg = blend_tree(tmp_path, "robot", ROBOT)
    asset = read_blend(cfg)
    p = model_points(asset)
    figures = in_blender(ROBOT_BOUNDS, ROBOT)
    np.testing.assert_allclose([p.min(axis=0), p.max(axis=0)], figures["rest"], rtol=1e-3, atol=1e-4)
    assert not np.allclose(figures["saved"], figures["rest"], atol=1e-2)  # saved mid-action, not at rest
    meta = dict(asset.metadata)
    armature, animation = meta["warning.armature"], meta["warning.animation"]
    assert "RobotArmature (43 bones)" in armature and "rest pose" in armature
    assert "action 'Robot_Death' at frame 23" in armature
    assert animation.startswith("14 actions are not carried (Robot_Dance, Robot_Death")
    from pipeline.validate.checks import check_asset

    assert sorted(f.message for f in check_asset(asset) if f.code == "HIER013") == sorted([armature, animation])
    # the face's expressions stay shape keys of each of its visuals
    heads = [v for _, v in asset.visuals() if v.name.startswith("Head")]
    assert heads and all([k.name for k in v.mesh.shape_keys] == ["Angry", "Surprised", "Sad"] for v in heads)


@pytest.mark.blender
@blender
@corpus
def test_the_saved_action_and_frame_do_not_change_the_rest_pose(tmp_path):
    """Saved on another action at another frame, the robot reads the same."""
    other = tmp_path / "robot_waving.blend"
    in_blender("""
        import json, sys
        import bpy
        bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False, use_scripts=False)
        arm = bpy.data.objects["RobotArmature"]
        arm.animation_data.action = bpy.data.actions["Robot_Wave"]
        bpy.context.scene.frame_set(40)
        bpy.ops.wm.save_as_mainfile(filepath=sys.argv[2])
        print(json.dumps({}))
    """, ROBOT, other)
    a = read_blend(blend_tree(tmp_path / "a", "robot", ROBOT))
    b = read_blend(blend_tree(tmp_path / "b", "robot", other))
    np.testing.assert_allclose(model_points(a), model_points(b), atol=1e-6)
    assert "action 'Robot_Wave' at frame 40" in dict(b.metadata)["warning.armature"]


@pytest.mark.blender
@blender
@corpus
@pytest.mark.parametrize("extra, factor, axes", [
    ('units = "cm"\n', 0.01, [0, 1, 2]),
    ('scale = 0.1\n', 0.1, [0, 1, 2]),
    ('units = "in"\nscale = 2.0\n', 0.0508, [0, 1, 2]),
    ('up_axis = "Y"\n', 1.0, [0, 2, 1]),
])
def test_units_scale_and_up_axis_of_a_unitless_file(tmp_path, extra, factor, axes):
    """The robot's scene has no unit system: Blender units are metres unless asset.toml
    says otherwise."""
    base = model_points(read_blend(blend_tree(tmp_path / "a", "robot", ROBOT)))
    asset = read_blend(blend_tree(tmp_path / "b", "robot", ROBOT, extra))
    size = np.ptp(model_points(asset), axis=0)
    np.testing.assert_allclose(size, np.ptp(base, axis=0)[axes] * factor, rtol=1e-9)


@pytest.mark.blender
@blender
def test_units_and_up_axis_move_joints_links_and_limits(fx):
    """Millimetres, Y up: every length scaled, the model frame turned, joint axes and
    rotations kept in their own frames, a prismatic joint's limits in metres."""
    a = read_blend_path(fx / "full.blend", "full", "test", mass_kg=50.0)
    b = read_blend_path(fx / "full.blend", "full", "test", mass_kg=50.0, units="mm", up_axis="Y")
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(model_points(b), model_points(a) @ turn.T * 0.001, atol=1e-12)
    for ja, jb in zip(a.joints, b.joints):
        np.testing.assert_allclose(jb.pose[:3, :3], turn @ ja.pose[:3, :3], atol=1e-12)
        np.testing.assert_allclose(jb.pose[:3, 3], turn @ ja.pose[:3, 3] * 0.001, atol=1e-12)
        np.testing.assert_array_equal(jb.axis, ja.axis)
        if ja.type == "prismatic":
            assert (jb.lower, jb.upper) == pytest.approx((ja.lower * 0.001, ja.upper * 0.001))
        else:
            assert (jb.lower, jb.upper) == (ja.lower, ja.upper)
    assert [link.mass for link in b.links] == pytest.approx([link.mass for link in a.links])
    assert dict(b.metadata)["units_m"] == "0.001 (asset.toml)" and dict(b.metadata)["up_axis"] == "Y (asset.toml)"


@pytest.mark.blender
@blender
def test_unit_scale_of_the_scene_is_the_files_unit(tmp_path):
    """A scene in millimetres (unit scale 0.001): a 2000-unit cube is 2 m."""
    path = tmp_path / "mm.blend"
    in_blender("""
        import json, sys
        import bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.context.scene.unit_settings.system = "METRIC"
        bpy.context.scene.unit_settings.scale_length = 0.001
        bpy.ops.mesh.primitive_cube_add(size=2000.0, location=(0.0, 0.0, 1000.0))
        bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
        print(json.dumps({}))
    """, path)
    asset = read_blend(blend_tree(tmp_path, "cube", path))
    p = model_points(asset)
    np.testing.assert_allclose([p.min(axis=0), p.max(axis=0)], [[-1.0, -1.0, 0.0], [1.0, 1.0, 2.0]], atol=1e-9)
    assert dict(asset.metadata)["units_m"] == "0.001 (file)"
    asset = read_blend(blend_tree(tmp_path / "over", "cube", path, 'units = "cm"\n'))  # asset.toml's unit wins
    assert np.ptp(model_points(asset), axis=0) == pytest.approx([20.0, 20.0, 20.0])


@pytest.mark.blender
@blender
@corpus
def test_a_blender_5_file_with_saved_shape_key_values(tmp_path):
    from pipeline.ingest.blend import header_version

    assert header_version(APPLY) == (5, 0)  # the new BLENDER17-01 header
    asset = read_blend(blend_tree(tmp_path, "apply", APPLY))
    _, sub = _visual(asset, "modifier")
    assert sub.mesh.triangle_count == 48  # its subdivision modifier applied, keys carried through it
    for name in ("modifier", "no_modifier"):
        (key,) = _visual(asset, name)[1].mesh.shape_keys
        assert key.name == "Key 1" and key.vertices.shape == _visual(asset, name)[1].mesh.vertices.shape
    notes = dict(asset.metadata)["notes"]
    assert "no_modifier: shape key values Key 1=1 make its rest mesh" in notes
    assert not any(k.startswith("warning.") for k, _ in asset.metadata)  # bpy 5.0 reads 5.0 files whole


# A cube whose key "up" lifts its top face by 1, saved at 0.5, on a plain object, one
# with a subdivision modifier, and one a shape binding drives.
SAVED_KEYS = """
    import json, sys
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for name, x in (("plain", 0.0), ("subdivided", 4.0), ("bound", 8.0)):
        bpy.ops.mesh.primitive_cube_add(size=2.0, location=(x, 0.0, 1.0))
        ob = bpy.context.object
        ob.name = name
        ob.shape_key_add(name="Basis")
        key = ob.shape_key_add(name="up")
        for p in key.data:
            if p.co.z > 0:
                p.co.z += 1.0
        key.value = 0.5
        if name == "subdivided":
            ob.modifiers.new("sub", "SUBSURF").levels = 1
        if name == "bound":
            ob["state"], ob["state_effect"], ob["state_domain"] = "level", "shape", [0.0, 1.0]
    bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
    print(json.dumps({}))
"""


@pytest.mark.blender
@blender
def test_saved_shape_key_values_make_the_rest_mesh_unless_a_binding_drives_them(tmp_path):
    path = tmp_path / "keys.blend"
    in_blender(SAVED_KEYS, path)
    asset = read_blend(blend_tree(tmp_path, "keys", path))
    top = {}
    for name in ("plain", "subdivided", "bound"):
        link, v = _visual(asset, name)
        (key,) = v.mesh.shape_keys
        world = (link.pose @ v.pose)
        rest_z = (v.mesh.vertices @ world[:3, :3].T + world[:3, 3])[:, 2]
        key_z = (key.vertices @ world[:3, :3].T + world[:3, 3])[:, 2]
        top[name] = (rest_z.max(), key_z.max())
    assert top["plain"] == pytest.approx((2.5, 3.0))  # the saved half-lift is the rest, "up" the full lift
    assert top["bound"] == pytest.approx((2.0, 3.0))  # the binding sets the weight: rest at the basis
    assert top["subdivided"][1] > top["subdivided"][0] > 2.0  # the half-lift, through the modifier
    notes = dict(asset.metadata)["notes"]
    assert "plain: shape key values up=0.5 make its rest mesh" in notes
    assert "bound: shape key values up=0.5 left to its shape binding" in notes


@pytest.mark.blender
@blender
@corpus
def test_a_file_from_a_newer_blender_is_read_with_a_warning_that_reaches_the_user(tmp_path):
    from pipeline.builder.run import source_warnings
    from pipeline.engine.scheduler import BuildReport
    from pipeline.builder.source_task import build_source
    from pipeline.ingest.blend import header_version
    from pipeline.validate.checks import check_asset

    newer = tmp_path / "newer.blend"
    newer.write_bytes(APPLY.read_bytes().replace(b"BLENDER17-01v0500", b"BLENDER17-01v0502", 1))
    assert header_version(newer) == (5, 2)
    cfg = blend_tree(tmp_path, "newer", newer)
    asset = read_blend(cfg)
    warning = dict(asset.metadata)["warning.blender_version"]
    assert warning.startswith("saved by Blender 5.2 (file version 5.2.") and "newer than the Blender 5.0" in warning
    assert [f.message for f in check_asset(asset) if f.code == "HIER013"] == [warning]
    result = build_source(tmp_path / "staging", str(cfg.path))
    assert result["warnings"] == [warning]
    assert source_warnings(BuildReport(results={"source:newer": result})) == [f"newer: warning: {warning}"]


@pytest.mark.blender
@blender
def test_a_file_with_python_says_so_once_in_the_tools_words(fx, tmp_path):
    """Blender's own log would tell the user to "enable auto-execution": the reader
    says instead, once, naming the file, that its Python was not run and why."""
    hostile = tmp_path / "hostile.blend"
    shutil.copy(fx / "hostile.blend", hostile)
    script = textwrap.dedent(f"""
        from pipeline.ingest.blend import read_blend_path
        asset = read_blend_path({str(hostile)!r}, "h", "test")
        print(dict(asset.metadata).get("warning.scripts", "none"))
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "auto-execution" not in run.stdout + run.stderr
    assert "PyDriver" not in run.stdout + run.stderr and "BPY_driver_exec" not in run.stderr
    warning = run.stdout.strip().splitlines()[-1]
    assert warning.startswith("hostile.blend: ") and "not run" in warning and "untrusted" in warning
    assert "tri.location[0]" in warning and "evil.py" in warning
    assert not list(fx.glob("marker*"))
    # a file without Python gets no such warning
    plain = read_blend_path(fx / "full.blend", "full", "test")
    assert "warning.scripts" not in dict(plain.metadata)


@pytest.mark.blender
@blender
def test_reading_a_blend_in_a_build_worker_leaves_no_temp_folder(fx, tmp_path):
    """bpy makes a blender_* session folder in the temp folder and removes it only in
    its exit handler, which a build's pool worker (os._exit) never ran."""
    temp = tmp_path / "tmp"
    temp.mkdir()
    script = textwrap.dedent(f"""
        from pipeline.engine.executors import local_pool
        from pipeline.engine.worker import Workers
        from pipeline.ingest.blend import read_blend_path
        pool = local_pool(Workers(1, 1))
        asset = pool.submit(read_blend_path, {str(fx / "full.blend")!r}, "full", "test").result()
        pool.shutdown(wait=True)
        print(len(asset.links))
    """)
    env = {**os.environ, "TMPDIR": str(temp)}
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    assert int(run.stdout.split()[-1]) >= 1  # the worker did read the file
    assert sorted(p.name for p in temp.iterdir()) == []
