"""The scene's per-placement steps, batched over every placement: the overlap grid,
separating-axis depths and clusters of the footprint check (PLACE004), and the LOD choice.
Each is compared with a plain per-pair or per-placement computation written here."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pipeline import ir
from pipeline.findings import Finding
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


def box_pairs(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    chunks = list(checks.box_pair_chunks(lo, hi))
    if not chunks:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks])


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
    i, j = box_pairs(lo, hi)
    found = {tuple(sorted(p)) for p in zip(i.tolist(), j.tolist())}
    assert len(found) == len(i)  # each pair once
    meet = ((lo[:, None, 0] <= hi[None, :, 0]) & (lo[None, :, 0] <= hi[:, None, 0])
            & (lo[:, None, 1] <= hi[None, :, 1]) & (lo[None, :, 1] <= hi[:, None, 1]))
    expected = {(a, b) for a, b in zip(*np.nonzero(np.triu(meet, k=1)))}
    assert found == expected and len(found) > 400


def test_box_pairs_of_none_and_one():
    assert [len(x) for x in box_pairs(np.zeros((0, 2)), np.zeros((0, 2)))] == [0, 0]
    assert [len(x) for x in box_pairs(np.zeros((1, 2)), np.ones((1, 2)))] == [0, 0]


def test_penetrations_match_the_pairwise_test():
    poses, lo, hi = _random_boxes(150, seed=5)
    boxes = checks.footprints(poses, lo, hi)
    i, j = box_pairs(boxes.corners.min(axis=1), boxes.corners.max(axis=1))
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
    assert out == [Finding("PLACE004", "warning", "A|B", "footprints of A and B overlap by 0.50 m").as_dict()]


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


def _brute_pairs(lo, hi) -> set[tuple[int, int]]:
    meet = ((lo[:, None, 0] <= hi[None, :, 0]) & (lo[None, :, 0] <= hi[:, None, 0])
            & (lo[:, None, 1] <= hi[None, :, 1]) & (lo[None, :, 1] <= hi[:, None, 1]))
    return {(int(a), int(b)) for a, b in zip(*np.nonzero(np.triu(meet, k=1)))}


@pytest.mark.parametrize("case", ["piles", "rows", "points", "one_huge", "far_apart"])
def test_grid_pairs_are_the_boxes_that_meet_in_any_chunking(case):
    """Piles of boxes on one point, long rows along y (many boxes in one x range), zero-size
    boxes, one box over everything, and boxes 10^7 m apart: the grid's pairs are the
    brute-force set, each once, however small the chunks."""
    rng = np.random.default_rng(11)
    n = 300
    lo = rng.uniform(-50, 50, (n, 2)).round(0)
    size = rng.uniform(0.0, 3.0, (n, 2))
    if case == "piles":
        lo[:120] = (5.0, 5.0)
        lo[120:160] = (-20.0, 7.5)
    elif case == "rows":
        lo[:, 0] = rng.integers(0, 4, n) * 10.0
    elif case == "points":
        size[:] = 0.0
        lo[: n // 2] = lo[n // 2:]
    elif case == "one_huge":
        size[0] = (500.0, 500.0)
        lo[0] = (-250.0, -250.0)
    else:
        lo[n // 2:] += 1e7
    hi = lo + size
    expected = _brute_pairs(lo, hi)
    for chunk in (1, 7, checks.PAIR_CHUNK):
        pairs = [tuple(sorted(p)) for i, j in checks.box_pair_chunks(lo, hi, chunk) for p in zip(i.tolist(), j.tolist())]
        assert len(pairs) == len(set(pairs)) and set(pairs) == expected
    assert len(expected) > 10


def _cluster_site(placed, half=1.0):
    bounds = [[-half, -half, 0.0], [half, half, 2.0]]
    fp = ir.FloorPlan("plan.dxf", "m", tuple(p.placement for p in placed),
                      (ir.Platform("L1", np.array([[-1e3, -1e3], [1e3, -1e3], [1e3, 1e3], [-1e3, 1e3]])),))
    return checks.check_placements(SimpleNamespace(), fp, placed, {"box": {"bounds": bounds}}, np.zeros(len(placed)))


def test_overlaps_are_one_warning_per_cluster():
    """A pile of 40 on one point (with one more 1 m beside it), a chain A-B-C in which
    A and C do not touch, a pair, and a pair that overlaps within tolerance only."""
    placed = [_placed(f"PILE-{k:02d}", "box", 100.0, 100.0, yaw=0.1 * k) for k in range(40)]
    placed.append(_placed("PILE-NEXT", "box", 101.0, 100.0))
    placed += [_placed("A", "box", 0.0, 0.0), _placed("B", "box", 1.5, 0.0), _placed("C", "box", 3.0, 0.0)]
    placed += [_placed("P", "box", 0.0, 50.0), _placed("Q", "box", 0.0, 51.7)]  # 0.30 m deep
    placed += [_placed("T", "box", 50.0, 0.0), _placed("U", "box", 51.95, 0.0)]  # 0.05 m: tolerated
    out = _cluster_site(placed)
    assert [f["code"] for f in out] == ["PLACE004"] * 3
    chain, pile, pair = sorted(out, key=lambda f: f["site"])
    assert chain == Finding("PLACE004", "warning", "A|B|C", "footprints of 3 placements overlap, each by "
                            "more than 0.10 m with one or more of the others: A, B, C").as_dict()
    assert pile["site"] == "PILE-00|PILE-01|PILE-02|and 38 more"
    assert pile["message"] == ("footprints of 41 placements overlap, each by more than 0.10 m with one or more of the "
                               "others; 40 of them at one point: PILE-00, PILE-01, PILE-02, PILE-03, PILE-04 and 36 more")
    assert pair == Finding("PLACE004", "warning", "P|Q", "footprints of P and Q overlap by 0.30 m").as_dict()


def test_clusters_match_the_components_of_every_pair():
    """Random footprints: the clusters are the connected components of the graph of all
    pairs overlapping beyond tolerance, worked out pair by pair."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    poses, lo, hi = _random_boxes(400, seed=8)
    boxes = checks.footprints(poses, lo, hi)
    label, depth = checks.overlap_clusters(boxes, 0.1)
    n = len(poses)
    edges = [(a, b) for a in range(n) for b in range(a + 1, n)
             if _separating_axis_depth(poses[a], lo[a], hi[a], poses[b], lo[b], hi[b]) > 0.1]
    a, b = np.array(edges).T
    _, truth = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    assert len(set(zip(label.tolist(), truth.tolist()))) == len(set(truth.tolist())) == len(set(label.tolist()))
    sizes = np.bincount(truth)
    assert (sizes > 2).any() and (sizes == 2).any() and (sizes == 1).any()
    for x, y in edges:
        if sizes[truth[x]] == 2:  # a pair's depth is its one overlap's
            assert depth[x] == pytest.approx(_separating_axis_depth(poses[x], lo[x], hi[x], poses[y], lo[y], hi[y]))


def test_a_pile_of_2000_is_one_finding():
    placed = [_placed(f"T{k:04d}", "box", 7.0, 7.0) for k in range(2000)]
    [f] = _cluster_site(placed)
    assert f["site"] == "T0000|T0001|T0002|and 1997 more"
    assert "footprints of 2000 placements overlap" in f["message"] and "2000 of them at one point" in f["message"]
    assert f["message"].endswith("T0004 and 1995 more")
