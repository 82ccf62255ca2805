"""The scene's per-placement steps, batched over every placement: the overlap sweep
and separating-axis depths of the footprint check (PLACE004), and the LOD choice.
Each is compared with a plain per-pair or per-placement computation written here."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline import ir
from pipeline.scene import checks
from pipeline.scene.placements import Placed, choose_lods, screen_error_px, yaw_matrix


def _random_boxes(n: int, seed: int):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 60, (n, 2)).round(0)  # whole metres: many ties in x
    yaws = rng.uniform(-np.pi, np.pi, n)
    poses = np.array([yaw_matrix(y, (x, yy, rng.uniform(0, 0.5))) for (x, yy), y in zip(xy, yaws)])
    half = rng.uniform(0.2, 3.0, (n, 2))
    lo = np.c_[-half, np.zeros(n)]
    hi = np.c_[half, rng.uniform(0.5, 4.0, n)]
    return poses, lo, hi


def _separating_axis_depth(pose_a, lo_a, hi_a, pose_b, lo_b, hi_b) -> float:
    """One pair, written out: the least overlap over the z axis and the four edge
    normals of two rotated rectangles."""
    def corners(pose, lo, hi):
        local = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        return np.array([pose[:2, :2] @ c + pose[:2, 3] for c in local])

    ca, cb = corners(pose_a, lo_a, hi_a), corners(pose_b, lo_b, hi_b)
    depth = min(pose_a[2, 3] + hi_a[2], pose_b[2, 3] + hi_b[2]) - max(pose_a[2, 3] + lo_a[2], pose_b[2, 3] + lo_b[2])
    for pose in (pose_a, pose_b):
        for k in range(2):
            axis = pose[:2, k]
            pa, pb = ca @ axis, cb @ axis
            depth = min(depth, min(pa.max(), pb.max()) - max(pa.min(), pb.min()))
    return depth


def test_box_pairs_are_exactly_the_boxes_that_meet():
    rng = np.random.default_rng(3)
    lo = rng.uniform(0, 50, (400, 2)).round(0)  # ties in x, touching boxes
    hi = lo + rng.integers(0, 4, (400, 2))
    i, j = checks.box_pairs(lo, hi)
    found = {tuple(sorted(p)) for p in zip(i.tolist(), j.tolist())}
    assert len(found) == len(i)  # each pair once
    meet = ((lo[:, None, 0] <= hi[None, :, 0]) & (lo[None, :, 0] <= hi[:, None, 0])
            & (lo[:, None, 1] <= hi[None, :, 1]) & (lo[None, :, 1] <= hi[:, None, 1]))
    expected = {(a, b) for a, b in zip(*np.nonzero(np.triu(meet, k=1)))}
    assert found == expected and len(found) > 400


def test_box_pairs_of_none_and_one():
    assert [len(x) for x in checks.box_pairs(np.zeros((0, 2)), np.zeros((0, 2)))] == [0, 0]
    assert [len(x) for x in checks.box_pairs(np.zeros((1, 2)), np.ones((1, 2)))] == [0, 0]


def test_penetrations_match_the_pairwise_test():
    poses, lo, hi = _random_boxes(150, seed=5)
    boxes = checks.footprints(poses, lo, hi)
    i, j = checks.box_pairs(boxes.corners.min(axis=1), boxes.corners.max(axis=1))
    depth = checks.penetrations(boxes.take(i), boxes.take(j))
    expected = [_separating_axis_depth(poses[a], lo[a], hi[a], poses[b], lo[b], hi[b]) for a, b in zip(i, j)]
    np.testing.assert_allclose(depth, expected, rtol=0, atol=1e-12)
    assert (depth > 0).sum() > 20 and (depth <= 0).sum() > 20  # both kinds of pair were tested


def _placed(tag: str, asset: str, x: float, y: float, yaw: float = 0.0) -> Placed:
    return Placed(ir.Placement(tag, asset, "L1", x, y), yaw_matrix(yaw, (x, y, 0.0)), yaw)


def test_overlapping_footprints_are_one_warning_with_their_depth():
    bounds = [[-1.0, -1.0, 0.0], [1.0, 1.0, 2.0]]
    manifests = {"box": {"bounds": bounds}}
    placed = [_placed("A", "box", 0.0, 0.0), _placed("B", "box", 1.5, 0.0),  # 0.5 m deep
              _placed("C", "box", 1.5, 1.95), _placed("D", "box", 20.0, 0.0, yaw=0.7)]  # C-B 0.05 m: tolerated
    fp = ir.FloorPlan("plan.dxf", "m", tuple(p.placement for p in placed),
                      (ir.Platform("L1", np.array([[-50.0, -50.0], [50.0, -50.0], [50.0, 50.0], [-50.0, 50.0]])),))
    out = checks.check_placements(SimpleNamespace(), fp, placed, manifests, np.zeros(len(placed)))
    assert out == [checks.finding("PLACE004", "warning", "A|B", "footprints of A and B overlap by 0.50 m")]


def test_lod_choice_follows_the_distance_to_the_nearest_eye():
    """A 2 x 2 x 2 m box at 10, 100 and 1000 m east of the one eye (its near face
    1 m closer), levels with errors of 2 mm, 2 cm and 20 cm."""
    site = SimpleNamespace(screen_tolerance_px=1.0, reference_hfov_rad=1.0, reference_width_px=1000)
    manifest = {"bounds": [[-1.0, -1.0, 0.0], [1.0, 1.0, 2.0]], "lod_models": ["a", "b", "c"],
                "lods": [{"level": k, "error_m": e} for k, e in ((1, 0.002), (2, 0.02), (3, 0.2))]}
    placed = [_placed(f"P{d}", "box", float(d), 0.0, yaw=0.3 * k) for k, d in enumerate((10, 100, 1000))]
    eyes = np.array([[0.0, 0.0, 1.0]])
    chosen = choose_lods(placed, {"box": manifest}, eyes, site)
    # the near face turns with the yaw: the distance is to the rotated box's nearest point
    for pl, got in zip(placed, chosen):
        local = np.linalg.inv(pl.pose) @ np.r_[eyes[0], 1.0]
        expected = np.linalg.norm(local[:3] - np.clip(local[:3], [-1, -1, 0], [1, 1, 2]))
        assert got.distance_m == pytest.approx(expected, rel=1e-12)
        px = [screen_error_px(lod["error_m"], expected, 1.0, 1000) for lod in manifest["lods"]]
        assert got.lod == max([0] + [lod["level"] for lod, p in zip(manifest["lods"], px) if p <= 1.0])
    assert [p.lod for p in chosen] == [1, 2, 3]


def test_no_lod_is_coarser_than_the_package_has():
    """A manifest whose lods list a level its package does not have (no lod_models
    entry): never chosen, however far."""
    site = SimpleNamespace(screen_tolerance_px=1.0, reference_hfov_rad=1.0, reference_width_px=1000)
    manifest = {"bounds": [[-1.0, -1.0, 0.0], [1.0, 1.0, 2.0]], "lod_models": ["a"],
                "lods": [{"level": 1, "error_m": 0.001}, {"level": 2, "error_m": 0.002}]}
    chosen = choose_lods([_placed("far", "box", 5000.0, 0.0)], {"box": manifest}, np.zeros((1, 3)), site)
    assert chosen[0].lod == 1


def test_screen_error_at_or_behind_the_eye():
    assert screen_error_px(0.01, 0.0, 1.0, 1000) == np.inf
    assert screen_error_px(0.0, 0.0, 1.0, 1000) == 0.0
    np.testing.assert_allclose(screen_error_px([0.01, 0.01], [10.0, -1.0], 1.0, 1000),
                               [0.01 / (20 * np.tan(0.5)) * 1000, np.inf])
