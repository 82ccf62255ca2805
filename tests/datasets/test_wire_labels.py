"""Conductor labels on synthetic frames (no Blender): a wire thinner than a pixel is
labelled on every pixel it covers, hidden where something in front covers it, and its
annotation's RLE decodes to its mask."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.datasets import labels, wire_labels
from pipeline.datasets.wire_labels import WireLabels, coverage
from pipeline.geometry import catenary as cat
from pipeline.geometry.pinhole import intrinsics, look_at, project
from pipeline.render.conductors import Wires

DIAMETER = 0.03
W, H = 320, 240
HFOV = math.radians(60.0)
EYE = np.array([0.0, 0.0, 10.0])
NEAR, FAR = 0.1, 1000.0


def span_record(sid: str, p0, p1, sag: float, terminals=("G-1.a", "G-2.b"), segments: int = 24) -> dict:
    """A span record as conductors.json holds it, from its sag at 25 deg C."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    curve = cat.from_sag(p0, p1, sag)
    w = 1.6 * 9.80665
    return {"id": sid, "type": "T", "from": {"terminal": terminals[0], "enu": p0.tolist()},
            "to": {"terminal": terminals[1], "enu": p1.tolist()}, "tension_n": curve.a * w, "weight_n_per_m": w,
            "temperature_c": 25.0, "lod": 0, "lods": [{"segments": segments}]}


TYPES = {"T": {"diameter_m": DIAMETER, "ea_n": 3.0e7, "alpha_per_k": 2.0e-5, "bundle_count": 1,
               "bundle_offsets_m": [[0.0, 0.0]]}}


def _wires(*spans) -> Wires:
    return Wires(Path("conductors.json"), sorted(spans, key=lambda s: s["id"]), TYPES)


def _camera():
    pose = look_at(EYE, EYE + [0.0, 100.0, 0.0])
    return pose, intrinsics(HFOV, W, H)


def _level_wire_at_row(row: float, distance: float = 100.0) -> dict:
    """A taut level span `distance` ahead, 40 m long across the view, whose centreline
    projects onto image row `row` (v = row + 0.5: the middle of the row)."""
    _, k = _camera()
    z = EYE[2] + (k["cy"] - (row + 0.5)) * distance / k["fy"]
    return span_record("G-1.a~G-2.b", (-20.0, distance, z), (20.0, distance, z), sag=1e-4 * 40.0)


def test_a_sub_pixel_wire_at_100_m_is_a_continuous_one_pixel_line_hidden_behind_what_is_in_front():
    pose, k = _camera()
    span = _level_wire_at_row(100)
    width_px = DIAMETER * k["fx"] / 100.0
    assert width_px < 0.1  # far thinner than a pixel
    # the label pass's picture: sky, a wall far behind the wire (id 9), a post in front of it (id 7)
    ids = np.zeros((H, W), np.uint16)
    depth = np.full((H, W), np.inf, np.float32)
    ids[80:120, 40:80], depth[80:120, 40:80] = 9, 150.0
    ids[60:200, 150:170], depth[60:200, 150:170] = 7, 50.0
    wl = WireLabels.of(_wires(span), {"G-1": 1, "G-2": 2, "P-7": 7, "W-9": 9})
    iid = wl.ids[span["id"]]
    assert iid == 10  # after the placements' ids
    out_ids, out_depth = wl.label(ids, depth, pose, HFOV, NEAR, FAR)
    u = project(np.array([span["from"]["enu"], span["to"]["enu"]]), pose, k)[:, 0]
    cols = np.arange(int(np.floor(u[0])), int(np.floor(u[1])) + 1)
    expected = np.zeros((H, W), bool)
    expected[100, cols] = True
    expected[100, 150:170] = False  # behind the post
    assert np.array_equal(out_ids == iid, expected)
    assert (out_ids[100, 150:170] == 7).all() and (out_ids[80:120, 40:80][out_ids[80:120, 40:80] != iid] == 9).all()
    # a labelled pixel's depth is the wire's (planar: 100 m), elsewhere unchanged
    assert np.allclose(out_depth[expected], 100.0, atol=1e-3)
    assert np.array_equal(out_depth[~expected], depth[~expected])
    assert (ids == np.where(expected, ids, out_ids)).all()  # the inputs are not written to
    # wholly behind a wall, or out of the frame: nothing changes
    wall = np.full((H, W), 20.0, np.float32)
    for depth_in in (wall, depth):
        pose_away = look_at(EYE, EYE - [0.0, 100.0, 0.0]) if depth_in is depth else pose
        hidden_ids, hidden_depth = wl.label(np.full((H, W), 3, np.uint16), depth_in, pose_away, HFOV, NEAR, FAR)
        assert (hidden_ids == 3).all() and np.array_equal(hidden_depth, depth_in)


def test_the_conductor_annotation_decodes_to_its_mask_and_names_its_span_and_ends():
    from pycocotools import mask as rle

    pose, _ = _camera()
    span = _level_wire_at_row(60)
    ids = np.zeros((H, W), np.uint16)
    depth = np.full((H, W), np.inf, np.float32)
    placement_ids = {"G-1": 1, "G-2": 2}
    wl = WireLabels.of(_wires(span), placement_ids)
    out_ids, _ = wl.label(ids, depth, pose, HFOV, NEAR, FAR)
    equipment = [{"id": 1, "name": "gantry", "supercategory": "equipment"}]
    cid = wire_labels.category(equipment)["id"]
    tag_of = {**{v: k for k, v in placement_ids.items()}, **wl.tags()}
    category_of = {"G-1": 1, "G-2": 1, **dict.fromkeys(wl.ids, cid)}
    [ann] = wl.describe(labels.annotations(out_ids, tag_of, category_of))
    mask = out_ids == wl.ids[span["id"]]
    assert np.array_equal(rle.decode(ann["segmentation"]).astype(bool), mask)
    assert ann["area"] == mask.sum() > 100 and ann["category_id"] == cid == 2
    assert (ann["tag"], ann["span"], ann["from"], ann["to"], ann["tags"]) == (
        span["id"], span["id"], "G-1.a", "G-2.b", ["G-1", "G-2"])
    record = wl.record(out_ids, None)
    assert (record["temperature_c"], record["temperature_from"]) == (25.0, "built scene")
    assert wl.record(out_ids, 60.0)["temperature_c"] == 60.0
    assert record["spans"] == [{"instance_id": wl.ids[span["id"]], "span": span["id"], "from": "G-1.a",
                                "to": "G-2.b", "tags": ["G-1", "G-2"], "pixels": int(mask.sum())}]


def _brute_margin(points: np.ndarray, radius: float, pose, k, cols, rows, per_segment: int = 500):
    """For each pixel square: the least (distance to the wire's centreline - the band's
    half-width there), from the 3D polyline sampled densely and each sample projected
    on its own (negative: the band meets the square), and the sampling step (px) that
    bounds its error."""
    from scipy.spatial import cKDTree

    t = np.linspace(0.0, 1.0, per_segment)[:, None]
    dense = np.concatenate([a + t * (b - a) for a, b in zip(points[:-1], points[1:])])
    depth = -((dense - pose[:3, 3]) @ pose[:3, :3])[:, 2]
    dense, depth = dense[depth > NEAR], depth[depth > NEAR]
    uv = project(dense, pose, k)
    half = k["fx"] * radius / depth
    step = np.linalg.norm(np.diff(uv, axis=0), axis=1).max()
    lo = np.c_[cols, rows].astype(float)
    near = cKDTree(uv).query_ball_point(lo + 0.5, r=half.max() + 1.0)
    out = np.full(len(cols), np.inf)
    for i, idx in enumerate(near):
        if idx:
            gap = np.maximum(0.0, np.maximum(lo[i] - uv[idx], uv[idx] - lo[i] - 1.0))
            out[i] = (np.sqrt((gap ** 2).sum(axis=1)) - half[idx]).min()
    return out, step


@pytest.mark.parametrize("distance", [100.0, 12.0, 4.0])
def test_coverage_is_every_pixel_the_projected_band_meets(distance):
    """A sagging, slanted span from far (sub-pixel) to near (many pixels wide): the
    rasterized pixels are those whose square the band meets (checked against the wire
    sampled densely, each sample projected), and they form one 8-connected line."""
    from scipy import ndimage

    pose, k = _camera()
    p0 = np.array([-0.45 * distance, distance * 1.1, 14.0])
    p1 = np.array([0.4 * distance, distance * 0.9, 9.0])
    curve = cat.from_sag(p0, p1, 0.04 * np.linalg.norm(p1 - p0))
    points = cat.points(curve, 24)
    radius = 0.5 * (DIAMETER if distance > 10 else 0.3)  # near: a thick bundle-sized tube
    cols, rows, dist = coverage(points, radius, pose, k, NEAR, FAR)
    got = np.zeros((H, W), bool)
    got[rows, cols] = True
    around = np.argwhere(ndimage.binary_dilation(got, iterations=3))
    margin, step = _brute_margin(points, radius, pose, k, around[:, 1], around[:, 0])
    inside = got[around[:, 0], around[:, 1]]
    sure = np.abs(margin) > step
    assert sure.mean() > 0.95
    assert np.array_equal(inside[sure], margin[sure] < 0)
    labelled, n = ndimage.label(got, structure=np.ones((3, 3)))
    assert n == 1 and got.sum() > 100
    depth = -((points - pose[:3, 3]) @ pose[:3, :3])[:, 2]
    assert dist.min() >= depth.min() - 1e-6 and dist.max() <= depth.max() + 1e-6


def test_the_near_plane_clips_a_wire_passing_behind_the_camera():
    pose, k = _camera()
    points = np.array([[-3.0, -20.0, 11.0], [-3.0, 30.0, 11.0]])  # from behind the camera to ahead
    cols, rows, dist = coverage(points, 0.015, pose, k, NEAR, FAR)
    assert len(cols) and (dist >= NEAR - 1e-9).all()
    assert (cols >= 0).all() and (cols < W).all() and (rows >= 0).all() and (rows < H).all()
    cols_far, _, _ = coverage(points, 0.015, pose, k, NEAR, 20.0)
    assert 0 < len(cols_far) < len(cols)  # the far plane cuts it too


def test_a_span_id_that_is_a_placement_tag_is_refused():
    from pipeline.errors import UserError

    span = _level_wire_at_row(10)
    with pytest.raises(UserError, match="placement's tag"):
        WireLabels.of(_wires({**span, "id": "G-1"}), {"G-1": 1})
    assert WireLabels.of(None, {"G-1": 1}) is None


def test_the_conductor_category_follows_the_equipments_only_when_the_site_has_spans(tmp_path):
    from types import SimpleNamespace

    from pipeline.errors import UserError

    equipment = [{"id": 1, "name": "breaker", "supercategory": "equipment"},
                 {"id": 2, "name": "reactor", "supercategory": "equipment"}]
    site = SimpleNamespace(build=tmp_path)
    assert wire_labels.categories(site, equipment) == equipment  # no conductors.json
    record = tmp_path / "scene" / "conductors.json"
    record.parent.mkdir()
    record.write_text(json.dumps({"temperature_c": 25.0, "types": {}, "spans": []}))
    assert wire_labels.categories(site, equipment) == equipment  # no span
    record.write_text(json.dumps({"temperature_c": 25.0, "types": TYPES, "spans": [_level_wire_at_row(5)]}))
    assert wire_labels.categories(site, equipment) == [*equipment, {"id": 3, "name": "conductor",
                                                                    "supercategory": "conductor"}]
    own = [*equipment, {"id": 3, "name": "conductor", "supercategory": "equipment"}]
    assert wire_labels.categories(site, own) == own and wire_labels.category(own)["id"] == 3
    record.write_text(json.dumps({"temperature_c": 25.0, "types": {}, "spans": [_level_wire_at_row(5)]}))
    with pytest.raises(UserError, match="G-1.a~G-2.b.*type 'T' is not in its types"):
        wire_labels.categories(site, equipment)
    record.write_text("{")
    with pytest.raises(UserError, match="conductors.json.*not a conductors record"):
        wire_labels.categories(site, equipment)


def test_spans_take_one_temperature_or_their_types_and_stay_as_built_without():
    """Wires.paths: a float moves every span, a dict each type's (twin serve's groups);
    a type missing or None, and no temperature, keep the span as conductors.json has it."""
    a = span_record("A", (-20.0, 100.0, 12.0), (20.0, 100.0, 12.0), sag=1.0)
    b = {**span_record("B", (-20.0, 120.0, 12.0), (20.0, 120.0, 12.0), sag=1.0), "type": "U"}
    wires = Wires(Path("conductors.json"), [a, b], {**TYPES, "U": TYPES["T"]})

    def lowest(temperature):
        return {sid: round(float(min(p[:, 2].min() for p in paths)), 9)
                for sid, paths in wires.paths(temperature).items()}

    built = lowest(None)
    assert built == pytest.approx({"A": 11.0, "B": 11.0}, abs=1e-6)  # the sag conductors.json records
    hot = lowest(80.0)
    assert hot["A"] == hot["B"] < built["A"] - 0.05
    assert lowest({"T": 80.0}) == {"A": hot["A"], "B": built["B"]}
    assert lowest({"T": 80.0, "U": None}) == {"A": hot["A"], "B": built["B"]}
    assert lowest({"U": 25.0}) == built  # the temperature it was built at


def test_a_wire_skipped_as_outside_the_view_covers_no_pixel():
    """wire_labels.outside_view only skips wires whose coverage is empty: random wires
    (catenary-like polylines, near and far, fat and thin) against random cameras, with
    wires grazing each edge of the image; and it skips most of them."""
    rng = np.random.default_rng(7)
    k = intrinsics(math.radians(20.0), 96, 72)
    skipped = covered = 0
    for _ in range(400):
        start = rng.uniform(-40, 40, 3)
        span = rng.normal(size=3) * rng.uniform(0.5, 30.0)
        # half the cameras aimed near the wire's middle, half anywhere
        aim = start + span / 2 + rng.normal(size=3) * 3.0 if rng.random() < 0.5 else rng.uniform(-20, 20, 3)
        pose = look_at(rng.uniform(-5, 5, 3) + [0, 0, 2], aim)
        t = np.linspace(0.0, 1.0, 12)[:, None]
        points = start + t * span - 4.0 * t * (1 - t) * [0, 0, rng.uniform(0, 2)]
        radius = float(rng.choice([0.005, 0.02, 0.3]))
        cols = coverage(points, radius, pose, k, 0.1, 60.0)[0]
        if wire_labels.outside_view(points, radius, pose, k, 0.1, 60.0):
            skipped += 1
            assert len(cols) == 0
        covered += len(cols) > 0
    assert covered > 50 and skipped > 150
    # just off each edge by less than the radius: kept; by more: skipped
    pose = look_at((0.0, 0.0, 0.0), (0.0, 10.0, 0.0))
    for axis, edge in ((0, k["hfov"] / 2), (2, k["vfov"] / 2)):
        for sign in (1.0, -1.0):
            direction = np.zeros(3)
            direction[1], direction[axis] = math.cos(edge), sign * math.sin(edge)
            normal = np.zeros(3)
            normal[1], normal[axis] = -math.sin(edge), sign * math.cos(edge)  # out of the view
            along = np.cross(direction, normal)
            line = 10.0 * direction + np.linspace(-1.0, 1.0, 5)[:, None] * along
            assert not wire_labels.outside_view(line + 0.009 * normal, 0.01, pose, k, 0.1, 60.0)
            assert len(coverage(line + 0.009 * normal, 0.01, pose, k, 0.1, 60.0)[0]) > 0
            assert wire_labels.outside_view(line + 0.011 * normal, 0.01, pose, k, 0.1, 60.0)
