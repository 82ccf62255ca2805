"""pipeline.ingest.blend on small .blend files authored by tests/blend_fixtures.py in a
subprocess (a clean Blender), plus the sample assets when they exist."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline import ir
from pipeline.config import load_asset_config
from pipeline.errors import UserError
from pipeline.ingest.blend import build_mesh, read_blend, read_blend_path, split_rigid

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _has_bpy() -> bool:
    import importlib.util

    return importlib.util.find_spec("bpy") is not None


blender = pytest.mark.skipif(not _has_bpy(), reason="needs bpy (pip install 'substation-twin[blender]')")


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    out = tmp_path_factory.mktemp("blend")
    marker = out / "marker"
    run = subprocess.run(
        [sys.executable, str(HERE / "blend_fixtures.py"), str(out), str(marker)],
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
