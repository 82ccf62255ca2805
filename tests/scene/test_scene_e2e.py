"""End to end on a small site: build, then check every placement's pose in all three
formats against an independent pyproj computation from the raw DXF, and run the
formats' own validators on the scene files."""

from __future__ import annotations

import json
import math

import ezdxf
import numpy as np
import pytest
from lxml import etree

import mini_sources
from poses import SAFE_XML, _acc, angle_diff, gltf_poses, independent_poses, sdf_poses, usd_poses
from pipeline.builder.run import build
from pipeline.export import names
from pipeline.geometry.transform import xyz_rpy_to_matrix
from pipeline.scene.world_collisions import read_collada_triangles
from pipeline.validate import external, gazebo
from collision_cells import assert_in_cells, cell_parts


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


@pytest.mark.parametrize("units", [6, 4], ids=["m", "mm"])
def test_heights_take_the_drawing_unit_and_not_grid_scale(tmp_path, units):
    """grid_scale is the projection's horizontal factor: a site with s = 1.0005 and
    plinths up to 40 m places every INSERT where pyproj puts it (z x (s - 1) = 20 mm
    at 40 m was the error when z went through s)."""
    from pipeline.scene import assemble
    from pipeline.scene import placements as placing

    sources = mini_sources.make(tmp_path / "sources", rotation_deg=23.0, units=units, grid_scale=1.0005)
    high = [(t, a, lv, x, y, z, rot) for (t, a, lv, x, y, _, rot), z in
            zip(mini_sources.PLACEMENTS, (0.0, 7.5, 40.0, 12.25, 32.0, 39.999))]
    mini_sources.write_plan(sources / "floorplan" / "plan.dxf", high, units=units)
    site, fp, georef = assemble._load(sources)
    assert site.grid_scale == 1.0005
    assert {p.tag: p.z for p in fp.placements} == pytest.approx({t: z for t, *_, z, _ in high}, rel=1e-12)
    truth = independent_poses(sources)
    for placed in placing.place(site, list(fp.placements), georef):
        p, yaw = truth[placed.placement.tag]
        assert np.abs(placed.pose[:3, 3] - p).max() < 1e-6, (placed.placement.tag, placed.pose[:3, 3], p)
        assert angle_diff(math.degrees(placed.yaw), yaw) < 1e-6


SCALED = {"K-2": 2.0, "P-1": 0.5}  # INSERT scale factors of the scaled mini site


@pytest.fixture(scope="module")
def scaled_build(tmp_path_factory):
    """The mini site with [floorplan] insert_scale = "apply" and two INSERTs drawn scaled."""
    root = tmp_path_factory.mktemp("scaled")
    sources = mini_sources.make(root / "sources")
    with open(sources / "site.toml", "a") as f:
        f.write('\n[floorplan]\ninsert_scale = "apply"\n')
    doc = ezdxf.readfile(sources / "floorplan" / "plan.dxf")
    for ins in doc.modelspace().query("INSERT"):
        s = SCALED.get(ins.get_attrib_text("TAG"))
        if s:
            ins.dxf.xscale = ins.dxf.yscale = ins.dxf.zscale = s
    doc.saveas(sources / "floorplan" / "plan.dxf")
    out = root / "build"
    report = build(sources, out, jobs=2, quiet=True)
    assert not report.failed, report.failed
    return sources, out


def _scale_of(m: np.ndarray) -> float:
    return float(np.cbrt(np.linalg.det(np.asarray(m, dtype=np.float64)[:3, :3])))


def test_insert_scale_apply_reaches_every_output(scaled_build):
    from pxr import Usd, UsdGeom

    from pipeline import glb as container
    from pipeline.scene.world_sdf import GROUPED_SEPARATOR

    sources, out = scaled_build
    record = json.loads((out / "scene" / "placements.json").read_text())
    assert {p["tag"]: p.get("scale", 1.0) for p in record["placements"] if p.get("scale")} == SCALED
    truth = independent_poses(sources)

    # USD: a scale op after the turn; the composed transform scales by the factor
    stage = Usd.Stage.Open(str(out / "scene" / "mini.usda"))
    for prim in stage.GetPrimAtPath("/Site/Placements").GetChildren():
        tag = prim.GetCustomDataByKey("tag")
        m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64).T
        assert _scale_of(m) == pytest.approx(SCALED.get(tag, 1.0), rel=1e-12), tag
        assert np.linalg.norm(m[:3, 3] - truth[tag][0]) < 1e-3

    # glTF: every instance of a scaled placement carries its SCALE
    doc, binary = container.read(out / "scene" / "mini.glb")
    seen = set()
    for node in doc["nodes"]:
        inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
        if inst and "tags" in node.get("extras", {}):
            scales = _acc(doc, binary, inst["attributes"]["SCALE"])
            for tag, s in zip(node["extras"]["tags"], scales):
                assert s == pytest.approx([SCALED.get(tag, 1.0)] * 3, rel=1e-6), (tag, s)
                seen.add(tag)
    assert set(SCALED) <= seen

    # SDF: a scaled placement is a model of its own; its whole-model visual drawn at
    # its scale, at its frame, and its collision meshes at its scale in the world's
    # collision cells, as Gazebo places them
    world = etree.parse(str(out / "scene" / "mini.sdf"), SAFE_XML).getroot().find("world")
    seen_sdf = gazebo.probe_world(out / "scene" / "mini.sdf", [out / "models"], meshes=False)
    parts = cell_parts(seen_sdf)
    rows = {p["tag"]: p for p in record["placements"]}
    for tag, s in SCALED.items():
        model = world.find(f"model[@name='{tag}']")
        assert model is not None and model.find(f"frame[@name='{tag}']") is not None
        items = model.findall("link/visual") + model.findall("link/collision")
        assert [i.get("name") for i in items] == [f"{tag}{GROUPED_SEPARATOR}whole"]
        pose = [float(v) for v in model.find(f"frame[@name='{tag}']").findtext("pose").split()]
        m = xyz_rpy_to_matrix(pose[:3], pose[3:])
        vertices, _ = read_collada_triangles(out / "models" / rows[tag]["asset"] / names.WHOLE_COLLISION_FILE)
        assert_in_cells(s * vertices @ m[:3, :3].T + m[:3, 3], parts, rows[tag]["lod"] == 0, tag)
        for item in items:
            assert item.find("pose").get("relative_to") == tag
            assert [float(v) for v in item.findtext("pose").split()] == [0.0] * 6
            assert [float(v) for v in item.findtext("geometry/mesh/scale").split()] == pytest.approx([s] * 3)
    for item in world.iter("visual", "collision"):  # nobody else is scaled
        if item.find("pose") is not None and item.find("pose").get("relative_to") not in SCALED:
            assert item.find("geometry/mesh/scale") is None

    # tiles: the instances of a scaled placement at its scale
    found = {}
    for content in (out / "tiles" / "content").glob("*.glb"):
        tdoc, tbin = container.read(content)
        for node in tdoc["nodes"]:
            inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
            if inst:
                for tag, sc in zip(node["extras"]["tags"], _acc(tdoc, tbin, inst["attributes"]["SCALE"])):
                    found.setdefault(tag, set()).add(round(float(sc[0]), 5))
    assert {t: v for t, v in found.items() if v != {1.0}} == {t: {s} for t, s in SCALED.items()}


def test_scaled_scene_passes_the_validators(scaled_build):
    _, out = scaled_build
    assert external.ign_sdf(out / "scene" / "mini.sdf", [out / "models"]).status == "passed"
    assert external.usd_validation(out / "scene" / "mini.usda").status == "passed"
    [r] = external.gltf_validator([out / "scene" / "mini.glb"])
    assert r.status == "passed", r.messages
