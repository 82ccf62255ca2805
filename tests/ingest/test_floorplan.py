"""The DXF floor-plan reader and the sample floor plan (sources/floorplan/substation.dxf)."""

from __future__ import annotations

import importlib.util
import math
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from helpers import ROOT
from pipeline.config import FloorplanOptions, load_site
from pipeline.errors import UserError
from pipeline.ingest.floorplan import points_in_polygon, read_floorplan

SOURCES = ROOT / "sources"
SAMPLE_DXF = SOURCES / "floorplan" / "substation.dxf"
AUTHORING = SOURCES / "authoring" / "floorplan.py"
LEVELS = {"L1", "L2", "L3"}


def asset_ids() -> set[str]:
    """The asset ids of the ASSETS.md table."""
    text = (SOURCES / "authoring" / "ASSETS.md").read_text()
    return set(re.findall(r"^\| ([a-z_]+) \|", text, flags=re.M)) - {"id"}  # minus the header row


def insert(block, tag=None, level="L1", at=(0.0, 0.0, 0.0), rotation=0.0, state=None, scale=(1, 1, 1)):
    return {"block": block, "tag": tag, "level": level, "at": at, "rotation": rotation, "state": state, "scale": scale}


def make_dxf(path: Path, inserts, units=6, platforms=(), extra=None, factor=1.0) -> Path:
    """A small floor plan. Coordinates are given in metres and multiplied by `factor`
    (1000 for a millimetre drawing)."""
    doc = ezdxf.new("R2010", setup=False)
    if units is not None:
        doc.header["$INSUNITS"] = units
    for name in sorted({i["block"] for i in inserts}):
        doc.blocks.new(name).add_line((0, 0), (1, 0))
    msp = doc.modelspace()
    for level, pts in platforms:
        msp.add_lwpolyline([(x * factor, y * factor) for x, y in pts], close=True, dxfattribs={"layer": f"PLATFORM_{level}"})
    for i in inserts:
        x, y, z = (v * factor for v in i["at"])
        sx, sy, sz = i["scale"]
        ref = msp.add_blockref(i["block"], (x, y, z), dxfattribs={"rotation": i["rotation"], "xscale": sx, "yscale": sy, "zscale": sz})
        for name in ("tag", "level", "state"):
            if i[name] is not None:
                ref.add_attrib(name.upper(), i[name], (x, y))
    if extra:
        extra(msp)
    doc.saveas(path)
    return path


SQUARE = [(-50.0, -50.0), (50.0, -50.0), (50.0, 50.0), (-50.0, 50.0)]
SMALL = [
    insert("circuit_breaker", "52-1A", "L1", (10.0, 5.0, 0.0), 90.0),
    insert("shunt_reactor", "RE-A1", "L1", (-20.25, 30.5, 0.35), 180.0, state="reactor_A1"),
    insert("disconnect_switch_cb", "89-11A", "L2", (3.125, -7.5, 1.5), -90.0, state="89-11A"),
]


# --- reader ------------------------------------------------------------------------


def test_metres_and_millimetres_give_the_same_placements(tmp_path):
    plats = [("L1", SQUARE)]
    m = read_floorplan(make_dxf(tmp_path / "m.dxf", SMALL, units=6, platforms=plats))
    mm = read_floorplan(make_dxf(tmp_path / "mm.dxf", SMALL, units=4, platforms=plats, factor=1000.0))
    assert (m.units, mm.units) == ("m", "mm")
    assert len(m.placements) == len(mm.placements) == 3
    for a, b in zip(m.placements, mm.placements):
        assert (a.tag, a.asset_id, a.level, a.state, a.heading_deg) == (b.tag, b.asset_id, b.level, b.state, b.heading_deg)
        assert np.allclose((a.x, a.y, a.z), (b.x, b.y, b.z), rtol=0, atol=1e-9)
    assert np.allclose(m.platforms[0].outline, mm.platforms[0].outline, rtol=0, atol=1e-9)
    assert np.allclose(mm.platforms[0].outline, SQUARE, rtol=0, atol=1e-9)


def test_attributes_rotation_z_and_order(tmp_path):
    fp = read_floorplan(make_dxf(tmp_path / "a.dxf", SMALL), known_assets=asset_ids(), levels=LEVELS)
    assert [p.tag for p in fp.placements] == ["52-1A", "89-11A", "RE-A1"]  # sorted by TAG
    cb, ds, re_ = fp.placements
    assert (cb.asset_id, cb.level, cb.x, cb.y, cb.z, cb.heading_deg, cb.state) == ("circuit_breaker", "L1", 10.0, 5.0, 0.0, 90.0, None)
    assert (re_.x, re_.y, re_.z, re_.heading_deg, re_.state) == (-20.25, 30.5, 0.35, 180.0, "reactor_A1")
    assert (ds.level, ds.z, ds.heading_deg, ds.state) == ("L2", 1.5, 270.0, "89-11A")  # -90 -> 270
    assert all(p.handle for p in fp.placements) and len({p.handle for p in fp.placements}) == 3


def test_ignored_entities_are_counted_and_platforms_read(tmp_path):
    def extra(msp):
        msp.add_line((0, 0), (5, 0), dxfattribs={"layer": "ANNOTATION"})
        msp.add_line((0, 1), (5, 1), dxfattribs={"layer": "ANNOTATION"})
        msp.add_text("note", dxfattribs={"layer": "ANNOTATION"})
        msp.add_circle((0, 0), 2.0, dxfattribs={"layer": "PLATFORM_L1"})  # not an outline
        msp.add_lwpolyline([(0, 0), (1, 0), (1, 1)], close=True, dxfattribs={"layer": "OTHER"})

    plats = [("L2", [(100, 0), (130, 0), (130, 20), (100, 20)]), ("L1", SQUARE)]
    fp = read_floorplan(make_dxf(tmp_path / "a.dxf", SMALL[:1], platforms=plats, extra=extra), levels=LEVELS)
    assert fp.ignored == (("CIRCLE", 1), ("LINE", 2), ("LWPOLYLINE", 1), ("TEXT", 1))
    assert [p.level for p in fp.platforms] == ["L1", "L2"]
    assert np.array_equal(fp.platforms[1].outline, [(100, 0), (130, 0), (130, 20), (100, 20)])


def test_platform_with_arc_is_flattened(tmp_path):
    def extra(msp):
        # A 20 x 10 terrace whose east side is a half circle (bulge 1 = 180 degrees).
        msp.add_lwpolyline([(0, 0, 0), (20, 0, 1), (20, 10, 0), (0, 10, 0)], format="xyb", close=True, dxfattribs={"layer": "PLATFORM_L1"})

    fp = read_floorplan(make_dxf(tmp_path / "a.dxf", [], extra=extra))
    outline = fp.platforms[0].outline
    assert outline[:, 0].max() == pytest.approx(25.0, abs=0.011)  # the arc's apex
    assert len(outline) > 10


def test_unitless_needs_plan_units_and_inches_are_read(tmp_path):
    path = make_dxf(tmp_path / "u.dxf", SMALL[:1], units=0)
    with pytest.raises(UserError) as e:
        read_floorplan(path)
    assert e.value.file == str(path) and e.value.obj == "$INSUNITS" and "[plan] units" in e.value.message
    fp = read_floorplan(path, options=FloorplanOptions(units="m"))
    assert fp.units == "m" and fp.placements[0].x == 10.0
    fp = read_floorplan(make_dxf(tmp_path / "in.dxf", SMALL[:1], units=1))
    assert fp.units == "in" and fp.placements[0].x == pytest.approx(0.254, rel=1e-15)


BAD = {
    "duplicate_tag": ([insert("circuit_breaker", "52-1A"), insert("current_transformer", "52-1A", at=(5, 0, 0))], "52-1A", "duplicate TAG"),
    "unknown_level": ([insert("circuit_breaker", "52-1A", level="L9")], "52-1A", "LEVEL 'L9'"),
    "unknown_block": ([insert("wave_trapp", "LT-1A")], "LT-1A", "'wave_trapp' is not an asset (no sources/assets/wave_trapp/)"),
    "missing_level": ([insert("circuit_breaker", "52-1A", level=None)], "52-1A", "no LEVEL"),
    "negative_scale": ([insert("circuit_breaker", "52-1A", scale=(-1, 1, 1))], "52-1A", "mirrored"),
    "non_uniform_scale": ([insert("circuit_breaker", "52-1A", scale=(1, 2, 1))], "52-1A", "non-uniform"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_inserts_raise_one_user_error_naming_file_and_object(tmp_path, case):
    inserts, obj, message = BAD[case]
    path = make_dxf(tmp_path / f"{case}.dxf", inserts)
    with pytest.raises(UserError) as e:
        read_floorplan(path, known_assets=asset_ids(), levels=LEVELS)
    assert e.value.file == str(path)
    assert obj in e.value.obj and message in e.value.message
    assert str(path) in str(e.value)


def test_missing_tag_is_derived_from_the_handle(tmp_path):
    path = make_dxf(tmp_path / "a.dxf", [insert("circuit_breaker", None)])
    handle = next(e for e in ezdxf.readfile(path).modelspace() if e.dxftype() == "INSERT").dxf.handle
    (p,) = read_floorplan(path).placements
    assert p.tag == f"insert_{handle}" and p.dxf_handles == (handle,)


def test_untagged_unknown_block_is_left_out_with_a_warning(tmp_path):
    path = make_dxf(tmp_path / "a.dxf", [insert("wave_trapp", None), insert("circuit_breaker", "52-1A")])
    fp = read_floorplan(path, known_assets=asset_ids(), levels=LEVELS)
    assert [p.tag for p in fp.placements] == ["52-1A"]
    (left_out,) = [w for w in fp.warnings if "left out" in w]
    assert "wave_trapp x1" in left_out and "did 'wave_trapp' mean asset 'wave_trap'?" in left_out


def test_bad_platforms(tmp_path):
    def open_outline(msp):
        msp.add_lwpolyline([(0, 0), (10, 0), (10, 10)], close=False, dxfattribs={"layer": "PLATFORM_L1"})

    def unknown_level(msp):
        msp.add_lwpolyline(SQUARE, close=True, dxfattribs={"layer": "PLATFORM_L7"})

    for extra, message in ((open_outline, "not closed"), (unknown_level, "'L7'")):
        path = make_dxf(tmp_path / f"{extra.__name__}.dxf", [], extra=extra)
        with pytest.raises(UserError) as e:
            read_floorplan(path, levels=LEVELS)
        assert e.value.file == str(path) and "LWPOLYLINE #" in e.value.obj and message in e.value.message


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.9, 0.999])
def test_truncated_dxf_is_a_user_error(tmp_path, fraction):
    raw = make_dxf(tmp_path / "full.dxf", SMALL).read_bytes()
    path = tmp_path / "cut.dxf"
    path.write_bytes(raw[: int(len(raw) * fraction)])
    with pytest.raises(UserError) as e:
        read_floorplan(path)
    assert e.value.file == str(path) and "DXF" in e.value.message


def test_garbage_and_missing_files(tmp_path):
    garbage = tmp_path / "g.dxf"
    garbage.write_bytes(b"\x00\x01 this is not a drawing\nEOF\n")
    with pytest.raises(UserError, match="not a readable DXF"):
        read_floorplan(garbage)
    with pytest.raises(UserError, match="file not found"):
        read_floorplan(tmp_path / "nope.dxf")


def test_points_in_polygon():
    inside = points_in_polygon([(0, 0), (49.9, 49.9), (50.1, 0), (0, -60)], SQUARE)
    assert inside.tolist() == [True, True, False, False]
    concave = [(0, 0), (10, 0), (10, 10), (5, 2), (0, 10)]
    assert points_in_polygon([(5, 1), (5, 5), (2, 5)], concave).tolist() == [True, False, True]


# --- the sample floor plan ------------------------------------------------------------


@pytest.fixture(scope="module")
def site():
    return load_site(SOURCES / "site.toml")


@pytest.fixture(scope="module")
def sample(site):
    # as the build reads it: the site's options name the conductor layers, not ignored
    return read_floorplan(SAMPLE_DXF, known_assets=asset_ids(), levels=set(site.level_names),
                          options=site.floorplan_options)


def test_sample_counts(sample):
    pl = sample.placements
    assert sample.units == "m"
    assert 800 <= len(pl) <= 900
    assert len({p.tag for p in pl}) == len(pl)
    per_level = Counter(p.level for p in pl)
    assert set(per_level) == LEVELS and min(per_level.values()) >= 50
    used = {p.asset_id for p in pl}
    assert used == asset_ids() - {"wave_trap"}
    assert dict(sample.ignored) == {"DIMENSION": 1, "LINE": 3, "TEXT": 4}
    assert {p.level for p in sample.platforms} == LEVELS
    assert {p.heading_deg for p in pl} == {0.0, 90.0, 180.0, 270.0}


def test_sample_states(sample):
    pl = sample.placements
    reactors = [p for p in pl if p.asset_id == "shunt_reactor"]
    assert sorted(p.state for p in reactors) == [f"reactor_{b}{i}" for b in "AB" for i in (1, 2, 3)]
    assert sorted(p.state for p in pl if p.asset_id == "power_transformer") == ["trafo_T1A", "trafo_T1B", "trafo_T1C"]
    for p in pl:
        if p.asset_id.startswith("disconnect_switch"):
            assert p.state == p.tag
        if p.asset_id == "ptz_camera_mast":
            assert p.state
    buses = [p for p in pl if p.asset_id == "rigid_busbar"]
    assert buses and all(p.z == 8.0 for p in buses)


def test_sample_placements_stand_on_their_platform(sample, site):
    """Every placement is inside a platform of its level, except fence panels crossing a
    slope between terraces: those lie on no platform, on the lower level, lifted to the
    slope's height (between 0 and the level difference)."""
    xy = np.array([(p.x, p.y) for p in sample.placements])
    on = {lv: np.zeros(len(xy), bool) for lv in LEVELS}
    for plat in sample.platforms:
        on[plat.level] |= points_in_polygon(xy, plat.outline)
    on_any = np.logical_or.reduce(list(on.values()))
    elev = {lv.name: lv.elevation for lv in site.levels}
    slope_panels = 0
    tags = {p.tag for p in sample.placements}
    for i, p in enumerate(sample.placements):
        if on[p.level][i]:
            # busbars ride on their supports, 500 kV equipment on its pedestal (SE-<tag>)
            raised = p.asset_id == "rigid_busbar" or (p.z == 2.5 and f"SE-{p.tag}" in tags)
            assert raised or p.z == 0.0, p.tag
            continue
        assert p.asset_id == "fence_segment" and not on_any[i], p.tag
        assert 0.0 < p.z < max(elev.values()) - elev[p.level], p.tag
        slope_panels += 1
    assert slope_panels <= 10


def _rectangles(placements) -> np.ndarray:
    """(n, 4, 2) footprint corners, sizes from ASSETS.md."""
    text = (SOURCES / "authoring" / "ASSETS.md").read_text()
    size = {m[0]: (float(m[1]), float(m[2])) for m in re.findall(r"^\| ([a-z_]+) \|.*?\| ([\d.]+) x ([\d.]+) x [\d.]+ \|", text, flags=re.M)}
    out = []
    for p in placements:
        sx, sy = size[p.asset_id]
        a = math.radians(p.heading_deg)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        local = np.array([(-sx, -sy), (sx, -sy), (sx, sy), (-sx, sy)]) / 2
        out.append(local @ rot.T + (p.x, p.y))
    return np.array(out)


def test_sample_footprints_do_not_overlap(sample):
    pl = [p for p in sample.placements if p.asset_id != "fence_segment"]
    rect = _rectangles(pl)
    centre = rect.mean(axis=1)
    radius = np.linalg.norm(rect - centre[:, None, :], axis=2).max(axis=1)
    i, j = np.nonzero(np.triu(np.linalg.norm(centre[:, None] - centre[None], axis=2) < radius[:, None] + radius[None], 1))
    clashes = []
    for a, b in zip(i, j):
        if {pl[a].asset_id, pl[b].asset_id} == {"rigid_busbar", "busbar_support"}:
            continue  # the busbar rides on its supports (z = 8 m)
        if {pl[a].tag, pl[b].tag} in ({pl[a].tag, "SE-" + pl[a].tag}, {pl[b].tag, "SE-" + pl[b].tag}):
            continue  # 500 kV equipment on its pedestal (z = 2.5 m)
        separated = False
        for poly in (rect[a], rect[b]):
            edges = np.roll(poly, -1, axis=0) - poly
            normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
            pa, pb = rect[a] @ normals.T, rect[b] @ normals.T
            if np.any((pa.max(0) <= pb.min(0) + 1e-6) | (pb.max(0) <= pa.min(0) + 1e-6)):
                separated = True
                break
        if not separated:
            clashes.append((pl[a].tag, pl[b].tag))
    assert len(i) > 50  # the prefilter does find neighbours to test
    assert clashes == []


def test_sample_inspection_points_face_the_reactor_gauges(sample, site):
    by_tag = {p.tag: p for p in sample.placements}
    reactors = {p.tag for p in sample.placements if p.asset_id == "shunt_reactor"}
    assert {ip.target for ip in site.inspection_points} == reactors
    for ip in site.inspection_points:
        r = by_tag[ip.target]
        a = math.radians(r.heading_deg)
        gx, gy = 0.0 * math.cos(a) + 5.8 * math.sin(a), 0.0 * math.sin(a) - 5.8 * math.cos(a)
        assert ip.level == r.level
        assert ip.position == pytest.approx((r.x + gx, r.y + gy, 1.6), abs=1e-9)


def test_sample_regenerates_byte_identical(tmp_path):
    """Two runs under different hash seeds (ezdxf iterates sets) give the committed bytes."""
    runs = []
    for seed in ("1", "2"):
        out = tmp_path / seed / "substation.dxf"
        env = {**os.environ, "PYTHONHASHSEED": seed}
        runs.append((out, subprocess.Popen([sys.executable, str(AUTHORING), "--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)))
    for out, proc in runs:
        stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr.decode()
        assert out.read_bytes() == SAMPLE_DXF.read_bytes()


def test_authoring_output_path():
    spec = importlib.util.spec_from_file_location("authoring_floorplan", AUTHORING)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    assert module.resolve_out(Path("x/assets")) == Path("x/floorplan/substation.dxf")  # make_all.py
    assert module.resolve_out(Path("x/plan.dxf")) == Path("x/plan.dxf")
    assert module.resolve_out(None) == SAMPLE_DXF
