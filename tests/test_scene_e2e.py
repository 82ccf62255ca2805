"""End to end on a small site: build, then check every placement's pose in all three
formats against an independent pyproj computation from the raw DXF, and run the
formats' own validators on the scene files."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from lxml import etree
from pyproj import CRS, Transformer

import mini_sources
from pipeline.builder.run import build
from pipeline.validate import external

SAFE_XML = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)


def independent_poses(sources: Path) -> dict[str, tuple[np.ndarray, float]]:
    """TAG -> (ENU position, ENU yaw in degrees), from the DXF with ezdxf and pyproj
    only: similarity -> UTM -> WGS84 ellipsoidal -> ECEF -> ENU (numpy rotation)."""
    import tomllib

    site = tomllib.loads((sources / "site.toml").read_text())
    e0, n0 = site["plan"]["grid_origin"]
    r = math.radians(site["plan"].get("grid_rotation_deg", 0.0))
    s = site["plan"].get("grid_scale", 1.0)
    elev = {lv["name"]: lv["elevation"] for lv in site["levels"]}
    doc = ezdxf.readfile(sources / site["site"]["floorplan"])
    unit = {4: 0.001, 6: 1.0}[doc.header.get("$INSUNITS", 6)]
    crs = CRS.from_user_input(site["plan"]["crs"])
    to_geo = Transformer.from_crs(crs, CRS.from_epsg(4979), always_xy=True)
    to_ecef = Transformer.from_crs(CRS.from_epsg(4979), CRS.from_epsg(4978), always_xy=True)

    def grid(x, y):
        return e0 + s * (x * math.cos(r) - y * math.sin(r)), n0 + s * (x * math.sin(r) + y * math.cos(r))

    if "origin" in site:  # as given; by default the centre of the platforms, lowest level
        lon0, lat0, h0 = site["origin"]["lon"], site["origin"]["lat"], site["origin"]["height"]
    else:
        platforms = [np.array(p.get_points("xy")) * unit for p in doc.modelspace().query("LWPOLYLINE")]
        pts = np.concatenate(platforms)
        cx, cy = (pts.min(axis=0) + pts.max(axis=0)) / 2
        lon0, lat0, h0 = to_geo.transform(*grid(cx, cy), min(elev.values()))
    o = np.array(to_ecef.transform(lon0, lat0, h0))
    la, lo = math.radians(lat0), math.radians(lon0)
    rot = np.array([[-math.sin(lo), math.cos(lo), 0],
                    [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                    [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])

    def enu(x, y, h):
        lon, lat, hh = to_geo.transform(*grid(x, y), h)
        return rot @ (np.array(to_ecef.transform(lon, lat, hh)) - o)

    out = {}
    for ins in doc.modelspace().query("INSERT"):
        attrs = {a.dxf.tag: a.dxf.text for a in ins.attribs}
        x, y, z = (v * unit for v in ins.dxf.insert)
        h = elev[attrs["LEVEL"]] + z
        p = enu(x, y, h)
        a = math.radians(ins.dxf.rotation)
        q = enu(x + math.cos(a), y + math.sin(a), h)
        out[attrs["TAG"]] = (p, math.degrees(math.atan2(q[1] - p[1], q[0] - p[0])))
    return out


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def sdf_poses(world: Path) -> dict[str, tuple[np.ndarray, float]]:
    root = etree.parse(str(world), SAFE_XML).getroot()
    out = {}
    # a placement is an <include> or, grouped with others of its variant, a <frame>
    for el in [*root.iter("include"), *root.findall("world/model/frame")]:
        name = el.findtext("name") if el.tag == "include" else el.get("name")
        v = [float(t) for t in el.findtext("pose").split()]
        out[name] = (np.array(v[:3]), math.degrees(v[5]))
    return out


def usd_poses(stage_path: Path) -> dict[str, tuple[np.ndarray, float]]:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(stage_path))
    out = {}
    for prim in stage.GetPrimAtPath("/Site/Placements").GetChildren():
        m = np.array(UsdGeom.Xformable(prim).GetLocalTransformation(), dtype=np.float64).T
        out[prim.GetCustomDataByKey("tag")] = (m[:3, 3], math.degrees(math.atan2(m[1, 0], m[0, 0])))
    return out


def gltf_poses(glb: Path) -> dict[str, tuple[np.ndarray, float]]:
    """Instance transforms of each asset's first visual node, back to Z-up ENU. The
    instance matrix is placement pose x the visual's model pose, so compare the root
    visual by removing its model-frame pose, read from the model's own glb."""
    from pipeline import glb as container
    from pipeline.geometry.transform import matrix_from_quaternion

    doc, binary = container.read(glb)
    out = {}
    for node in doc["nodes"]:
        inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
        if not inst or "tags" not in node.get("extras", {}):
            continue
        asset = node["name"].split("/")[0]
        visual = node["name"].split("/")[2]
        t = _acc(doc, binary, inst["attributes"]["TRANSLATION"])
        q = _acc(doc, binary, inst["attributes"]["ROTATION"])
        model_doc, _ = container.read(glb.parent.parent / "models" / asset / f"{asset}.glb")
        local = dict((model_doc["nodes"][i]["name"], m) for i, m in container.visual_nodes(model_doc))[visual]
        for tag, ti, qi in zip(node["extras"]["tags"], t, q):
            inst_m = matrix_from_quaternion(container.from_gltf_rotation(qi))
            inst_m[:3, 3] = ti
            placement_y = inst_m @ np.linalg.inv(local)
            pz = container.to_z_up(placement_y)
            out.setdefault(tag, (pz[:3, 3], math.degrees(math.atan2(pz[1, 0], pz[0, 0]))))
    return out


def _acc(doc, binary, index):
    from pipeline import glb

    return glb.accessor(doc, binary, index).astype(np.float64)


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
