"""End to end on a small site: build, then check every placement's pose in all three
formats against an independent pyproj computation from the raw DXF, and run the
formats' own validators on the scene files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from lxml import etree

import mini_sources
from poses import SAFE_XML, angle_diff, gltf_poses, independent_poses, sdf_poses, usd_poses
from pipeline.builder.run import build
from pipeline.validate import external


@pytest.fixture(scope="module", params=[(23.0, 6), (0.0, 6), (90.0, 4), (180.0, 6)],
                ids=["rot23-m", "rot0-m", "rot90-mm", "rot180-m"])
def built(request, tmp_path_factory):
    rot, units = request.param
    if (rot, units) == (23.0, 6):  # mini_sources' defaults: the run's shared mini build
        return request.getfixturevalue("mini_build")
    root = tmp_path_factory.mktemp(f"site{int(rot)}")
    sources = mini_sources.make(root / "sources", rotation_deg=rot, units=units)
    out = root / "build"
    report = build(sources, out, jobs=2, quiet=True)
    assert not report.failed, report.failed
    return sources, out


@pytest.mark.parametrize("reader, tol_deg, name", [
    (sdf_poses, 1e-3, "sdf"), (usd_poses, 1e-3, "usd"), (gltf_poses, 1e-3, "gltf")])
def test_every_pose_matches_independent_pyproj(built, reader, tol_deg, name):
    sources, out = built
    truth = independent_poses(sources)
    ext = {"sdf": ".sdf", "usd": ".usda", "gltf": ".glb"}[name]
    got = reader(out / "scene" / f"mini{ext}")
    got.pop("terrain", None)
    assert set(got) == set(truth)
    for tag, (p, yaw) in truth.items():
        q, yaw2 = got[tag]
        tol_m = 1e-3 if name != "gltf" else 2e-3  # glTF instances are float32
        assert np.linalg.norm(q - p) < tol_m, (tag, q, p)
        assert angle_diff(yaw, yaw2) < tol_deg, (tag, yaw, yaw2)


def test_world_passes_ign_sdf(built):
    _, out = built
    r = external.ign_sdf(out / "scene" / "mini.sdf", [out / "models"])
    assert r.status == "passed", r.messages


def test_stage_validates_with_references_resolved(built):
    from pxr import Usd

    _, out = built
    stage = Usd.Stage.Open(str(out / "scene" / "mini.usda"))
    prims = stage.GetPrimAtPath("/Site/Placements").GetChildren()
    assert prims and all(p.IsInstance() for p in prims)
    assert all(p.GetPrototype().GetChildren() for p in prims)  # the reference resolved
    r = external.usd_validation(out / "scene" / "mini.usda")
    assert r.status == "passed", r.messages


def test_scene_glb_validates(built):
    _, out = built
    [r] = external.gltf_validator([out / "scene" / "mini.glb"])
    assert r.status == "passed", r.messages


def test_placements_sit_on_terrain_and_inside_platforms(built):
    _, out = built
    record = json.loads((out / "scene" / "placements.json").read_text())
    codes = [f["code"] for f in record["findings"]]
    assert "PLACE003" not in codes and "PLACE005" not in codes, record["findings"]
    assert sum(record["lod_histogram"].values()) == len(mini_sources.PLACEMENTS)


def test_more_placements_grow_the_glb_by_instances_only(tmp_path):
    """Cost follows unique assets: doubling the placements of the same assets adds
    only instance transforms to the scene .glb (well under 5 %)."""
    base = mini_sources.make(tmp_path / "one")
    double = mini_sources.make(tmp_path / "two")
    extra = [(f"{t}b", a, lv, x + 1.5, y + 3.0, z, rot) for t, a, lv, x, y, z, rot in mini_sources.PLACEMENTS]
    mini_sources.write_plan(double / "floorplan" / "plan.dxf", mini_sources.PLACEMENTS + extra)
    cache = tmp_path / "cache"
    build(base, tmp_path / "b1", cache=cache, quiet=True)
    build(double, tmp_path / "b2", cache=cache, quiet=True)
    s1 = (tmp_path / "b1" / "scene" / "mini.glb").stat().st_size
    s2 = (tmp_path / "b2" / "scene" / "mini.glb").stat().st_size
    assert s2 > s1
    assert (s2 - s1) / s1 < 0.05, (s1, s2)


def test_the_worlds_sun_is_13_00_on_the_sites_clock(built):
    """mini's site.toml: timezone America/Bahia (UTC-3), date 2025-06-21."""
    _, out = built
    record = json.loads((out / "scene" / "placements.json").read_text())
    assert record["timezone"] == "America/Bahia"
    sun = record["sun"]
    assert (sun["time_local"], sun["time_utc"]) == ("2025-06-21T13:00:00-03:00", "2025-06-21T16:00:00+00:00")
    world = etree.parse(str(out / "scene" / "mini.sdf"), SAFE_XML).getroot().find("world")
    light = world.find("light[@name='sun']")
    assert float(light.findtext("intensity")) == pytest.approx(sun["intensity"]) and sun["intensity"] > 0.5
    assert 40.0 < sun["elevation_deg"] < 60.0  # a June (winter) afternoon at 12.7 S
