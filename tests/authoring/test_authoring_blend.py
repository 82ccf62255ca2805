"""The bpy-authored sample assets (sources/authoring, helper A's set): the committed
.blend files regenerate to the same content, hold the joints, bindings and indicators
the pipeline and the floor plan rely on, and stay within their triangle ranges."""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import SOURCES
from pipeline.config import load_asset_config

AUTHORING = SOURCES / "authoring"
ASSETS = SOURCES / "assets"

# Evaluated visual triangles per asset (sources/authoring/ASSETS.md).
TRIANGLE_RANGES = {
    "shunt_reactor": (120_000, 250_000),
    "disconnect_switch_cb": (50_000, 100_000),
    "disconnect_switch_vb": (50_000, 100_000),
    "ptz_camera_mast": (5_000, 20_000),
    "circuit_breaker": (80_000, 200_000),
    "current_transformer": (40_000, 100_000),
    "potential_transformer": (40_000, 100_000),
    "power_transformer": (150_000, 300_000),
}
# Approximate size X x Y x Z (m) of each asset; the floor plan is laid out with them.
SIZES = {
    "shunt_reactor": (8, 5, 7.5),
    "disconnect_switch_cb": (5.6, 0.8, 7.0),
    "disconnect_switch_vb": (5, 0.8, 6),
    "ptz_camera_mast": (0.6, 0.6, 6.5),
    "circuit_breaker": (3.5, 1.2, 8),
    "current_transformer": (1.2, 1.2, 6.5),
    "potential_transformer": (1.2, 1.2, 7),
    "power_transformer": (11, 7, 10),
}
MAX_SOURCES_BYTES = 25 * 1024 * 1024


def _module(name: str):
    spec = importlib.util.spec_from_file_location(f"authoring_{name}", AUTHORING / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def blend_path(asset_id: str, root: Path = ASSETS) -> Path:
    return root / asset_id / f"{asset_id}.blend"


# --- without Blender -------------------------------------------------------------------


@pytest.mark.parametrize("asset_id", sorted(TRIANGLE_RANGES))
def test_asset_toml_loads_and_names_the_blend(asset_id):
    cfg = load_asset_config(ASSETS / asset_id / "asset.toml")
    assert cfg.source == blend_path(asset_id)
    assert cfg.triangle_budget >= TRIANGLE_RANGES[asset_id][1]
    assert list(cfg.lod_budgets_m) == sorted(cfg.lod_budgets_m)


def test_sources_folder_stays_under_25_mb():
    total = sum(p.stat().st_size for p in SOURCES.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    assert total < MAX_SOURCES_BYTES, f"sources/ holds {total / 1e6:.1f} MB"


def test_make_all_runs_every_authoring_script_and_no_helper():
    names = [p.stem for p in _module("make_all").authoring_scripts()]
    assert names == sorted(names)
    assert set(TRIANGLE_RANGES) <= set(names)
    assert not {"kit", "digest", "make_all", "_parts"} & set(names)


# --- with Blender ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def digest():
    pytest.importorskip("bpy")
    return _module("digest")


@pytest.fixture(scope="module")
def summaries(digest):
    """digest.summary of every committed file (opens each once)."""
    return {asset_id: digest.summary(blend_path(asset_id)) for asset_id in sorted(TRIANGLE_RANGES)}


def open_asset(digest, asset_id: str):
    import bpy

    digest.open_blend(blend_path(asset_id))
    bpy.context.view_layer.update()
    return bpy.data.objects


@pytest.mark.blender
@pytest.mark.parametrize("asset_id", sorted(TRIANGLE_RANGES))
def test_triangles_and_size_match_the_asset_table(summaries, asset_id):
    s = summaries[asset_id]
    lo, hi = TRIANGLE_RANGES[asset_id]
    assert lo <= s["triangles"] <= hi
    extent = np.subtract(s["bounds"][1], s["bounds"][0])
    assert np.all(extent <= np.multiply(SIZES[asset_id], 1.1)), extent
    assert np.all(extent >= np.multiply(SIZES[asset_id], 0.8)), extent
    assert s["bounds"][0][2] == pytest.approx(0.0, abs=1e-3)  # standing on the ground


@pytest.mark.blender
def test_regenerated_assets_have_the_committed_content(digest, summaries, tmp_path):
    ids = ["disconnect_switch_cb", "disconnect_switch_vb", "shunt_reactor"]
    subprocess.run([sys.executable, str(AUTHORING / "make_all.py"), "--out", str(tmp_path), "--only", *ids],
                   check=True, capture_output=True, timeout=300)
    for asset_id in ids:
        assert digest.digest_blend(blend_path(asset_id, tmp_path)) == summaries[asset_id]["digest"], asset_id
        committed = (ASSETS / asset_id / "asset.toml").read_text()
        assert (tmp_path / asset_id / "asset.toml").read_text() == committed


@pytest.mark.blender
def test_digest_sees_a_moved_vertex(digest):
    import bpy

    original = digest.digest_blend(blend_path("ptz_camera_mast"))
    bpy.data.objects["camera_body"].data.vertices[0].co.x += 1e-4
    assert digest.digest_current() != original


def _local_axis(ob, k: int) -> np.ndarray:
    m = np.array(ob.matrix_world)[:3, :3]
    return m[:, k] / np.linalg.norm(m[:, k])


def _assert_dial_gauge(objects, center):
    for name in ("gauge_tank_dial_white", "gauge_tank_dial_red", "gauge_tank_pointer"):
        assert name in objects, name
    assert objects["gauge_tank_dial_white"].active_material.name == "dial_white"
    assert objects["gauge_tank_dial_red"].active_material.name == "dial_red"
    pointer = objects["gauge_tank_pointer"]
    assert pointer.active_material.name == "pointer_black"
    np.testing.assert_allclose(np.array(pointer.matrix_world.translation), center, atol=1e-6)
    np.testing.assert_allclose(_local_axis(pointer, 2), (0.0, -1.0, 0.0), atol=1e-6)  # out of the dial
    assert pointer["state"] == "oil_level_tank"
    assert pointer["state_effect"] == "rotate"
    assert list(pointer["state_domain"]) == [0.0, 100.0]
    assert list(pointer["state_range"]) == pytest.approx([-2.356, 2.356])


@pytest.mark.blender
def test_shunt_reactor_indicators(digest, summaries):
    objects = open_asset(digest, "shunt_reactor")
    assert summaries["shunt_reactor"]["joints"] == {}
    _assert_dial_gauge(objects, (0.0, -1.80, 2.80))
    lamp = objects["alarm_lamp"]
    assert np.linalg.norm(np.array(lamp.matrix_world.translation) - (0.45, -1.80, 2.80)) < 0.05
    assert lamp["state_effect"] == "material"
    assert list(lamp["state_materials"]) == ["lamp_alarm", "lamp_off"]
    assert list(lamp["state_thresholds"]) == [25.0]
    import bpy

    assert "lamp_alarm" in bpy.data.materials  # kept although no object shows it yet
    for i, x in ((1, -1.5), (2, 1.5)):
        _assert_sight_glass(objects, f"gauge_b{i}_oil", f"oil_level_b{i}", (x, -0.6, 5.8))


def _assert_sight_glass(objects, name: str, state: str, near):
    oil = objects[name]
    assert oil.active_material.name == "oil_amber"
    assert oil["state"] == state and oil["state_effect"] == "shape"
    assert list(oil["state_range"]) == [0.0, 1.0]
    keys = oil.data.shape_keys.key_blocks
    assert [k.name for k in keys] == ["Basis", "full"]
    height = {k.name: np.ptp([v.co.z for v in k.data]) for k in keys}
    assert height["Basis"] < 0.01 and 0.2 < height["full"] < 0.3
    centre = np.array(oil.matrix_world.translation) + (0.0, 0.0, height["full"] / 2)
    assert np.linalg.norm(centre - near) < 0.1
    assert "gauge_glass" in {ob.active_material.name for ob in objects
                             if ob.type == "MESH" and ob.name.startswith(name.rsplit("_", 1)[0])}


@pytest.mark.blender
def test_power_transformer_dial_gauge(digest):
    _assert_dial_gauge(open_asset(digest, "power_transformer"), (2.0, -3.05, 3.0))


def _assert_joint(ob, axis, lower, upper):
    assert ob.type == "EMPTY" and ob["joint"] == "revolute"
    assert list(ob.get("joint_axis", (0.0, 0.0, 1.0))) == list(axis)
    assert (ob["joint_lower"], ob["joint_upper"]) == pytest.approx((lower, upper))
    assert ob["joint_effort"] > 0 and ob["joint_velocity"] > 0
    assert ob.children, f"joint {ob.name} moves nothing"


def _ancestors(ob) -> list[str]:
    names = []
    while ob.parent is not None:
        ob = ob.parent
        names.append(ob.name)
    return names


@pytest.mark.blender
def test_centre_break_switch_joints_collision_and_mirrored_blade(digest, summaries):
    objects = open_asset(digest, "disconnect_switch_cb")
    _assert_joint(objects["joint_column_1"], (0.0, 0.0, 1.0), 0.0, 1.571)
    _assert_joint(objects["joint_column_2"], (0.0, 0.0, 1.0), -1.571, 0.0)
    pivots = [np.array(objects[f"joint_column_{i}"].matrix_world.translation) for i in (1, 2)]
    assert np.linalg.norm(pivots[1] - pivots[0]) == pytest.approx(4.6)
    assert summaries["disconnect_switch_cb"]["collision_objects"] == ["collision_beam", "collision_legs"]
    for i in (1, 2):
        assert f"joint_column_{i}" in _ancestors(objects[f"blade_{i}_tube"])
    mirrored = [ob.name for ob in objects if ob.type == "MESH" and np.linalg.det(np.array(ob.matrix_world)) < 0]
    assert "blade_2_tube" in mirrored
    # The mirrored half reaches back towards the middle, like the first half.
    for i, sign in ((1, 1.0), (2, -1.0)):
        tube = objects[f"blade_{i}_tube"]
        tip = max((tube.matrix_world @ v.co for v in tube.data.vertices), key=lambda p: sign * p.x)
        assert abs(tip.x) < 0.1


@pytest.mark.blender
def test_vertical_break_switch_chains_blade_joint_under_operating_column(digest):
    objects = open_asset(digest, "disconnect_switch_vb")
    _assert_joint(objects["joint_operating_column"], (0.0, 0.0, 1.0), -0.35, 0.0)
    _assert_joint(objects["joint_blade"], (0.0, 1.0, 0.0), 0.0, 1.6)
    assert "joint_operating_column" in _ancestors(objects["joint_blade"])
    assert "joint_blade" in _ancestors(objects["blade_tube"])
    # Positive blade angles lift the free end: the blade lies along -X from the hinge.
    hinge = np.array(objects["joint_blade"].matrix_world.translation)
    tube = objects["blade_tube"]
    ends = [np.array(tube.matrix_world @ v.co) for v in tube.data.vertices]
    assert min(p[0] for p in ends) < hinge[0] - 3.5


@pytest.mark.blender
def test_ptz_camera_pan_and_tilt(digest):
    objects = open_asset(digest, "ptz_camera_mast")
    _assert_joint(objects["joint_pan"], (0.0, 0.0, 1.0), -3.0, 3.0)
    _assert_joint(objects["joint_tilt"], (1.0, 0.0, 0.0), -1.5, 0.6)
    assert "joint_pan" in _ancestors(objects["joint_tilt"])
    # Tilt about model -X: negative angles turn the -Y view downwards.
    np.testing.assert_allclose(_local_axis(objects["joint_tilt"], 0), (-1.0, 0.0, 0.0), atol=1e-6)
    assert math.isclose(objects["joint_pan"].matrix_world.translation.z, 5.95, abs_tol=1e-6)
