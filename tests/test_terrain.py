"""Terrain geometry from platform outlines, and the placement checks' geometry."""

import numpy as np
import pytest

from pipeline import ir
from pipeline.scene import checks, terrain


def test_ear_clip_concave_polygon_covers_its_area():
    poly = np.array([[0, 0], [10, 0], [10, 10], [5, 4], [0, 10]], dtype=float)  # a notch
    tris = terrain.ear_clip(poly)
    assert len(tris) == 3
    area = sum(abs(np.cross(poly[b] - poly[a], poly[c] - poly[a])) / 2 for a, b, c in tris)
    assert area == pytest.approx(terrain.signed_area(poly))


def test_subdivide_bounds_edges_and_keeps_area():
    pts = np.array([[0, 0], [100, 0], [100, 60], [0, 60]], dtype=float)
    p2, t2 = terrain.subdivide(pts, np.array([[0, 1, 2], [0, 2, 3]]), 20.0)
    e = p2[t2[:, [1, 2, 0]]] - p2[t2]
    assert np.linalg.norm(e, axis=2).max() <= 20.0
    area = np.abs(np.cross(p2[t2[:, 1]] - p2[t2[:, 0]], p2[t2[:, 2]] - p2[t2[:, 0]])).sum() / 2
    assert area == pytest.approx(6000.0)


def test_offset_moves_each_edge_by_the_distance():
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
    out = terrain.offset_outline(sq, 3.0)
    np.testing.assert_allclose(out, [[-3, -3], [13, -3], [13, 13], [-3, 13]], atol=1e-12)


class FlatSite:
    name = "flat"
    natural_ground = 40.0
    slope_ratio = 1.5
    skirt_width = 10.0

    def level(self, name):
        return type("L", (), {"elevation": {"L1": 48.0, "L2": 51.0}[name]})


class IdentityGeoref:
    def to_enu(self, xy, h):
        return np.c_[np.asarray(xy, float), np.asarray(h, float)]


def test_terrain_is_flat_at_levels_and_slopes_at_the_ratio():
    site = FlatSite()
    pfs = [ir.Platform("L1", np.array([[0, 0], [50, 0], [50, 40], [0, 40]])),
           ir.Platform("L2", np.array([[0, 60], [50, 60], [50, 90], [0, 90]]))]
    t = terrain.terrain_asset(site, pfs, IdentityGeoref(), "t")
    z = terrain.height_at(t, np.array([[25.0, 20.0], [25.0, 75.0], [25.0, -6.0], [-100.0, -100.0]]))
    assert z[0] == pytest.approx(48.0) and z[1] == pytest.approx(51.0)
    # 6 m out from L1's edge the slope has dropped 6 / 1.5 = 4 m
    assert z[2] == pytest.approx(44.0)
    assert np.isnan(z[3])
    names = [v.name for _, v in t.visuals()]
    assert names.count("ground") == 1 and sum(n.startswith("slope") for n in names) == 2


def test_point_in_polygon_edges_count_inside():
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
    assert checks.point_in_polygon(np.array([5.0, 5.0]), sq)
    assert checks.point_in_polygon(np.array([10.0, 5.0]), sq)
    assert not checks.point_in_polygon(np.array([10.5, 5.0]), sq)


def test_penetration_of_oriented_boxes():
    bounds = [[-1, -1, 0], [1, 1, 2]]
    a = checks.footprint(np.eye(4), bounds)
    shifted = np.eye(4)
    shifted[0, 3] = 1.5
    assert checks.penetration(a, checks.footprint(shifted, bounds)) == pytest.approx(0.5)
    rot = np.eye(4)
    rot[:2, :2] = [[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]]
    rot[0, 3] = 3.5
    assert checks.penetration(a, checks.footprint(rot, bounds)) < 0
    lifted = np.eye(4)
    lifted[2, 3] = 2.5
    assert checks.penetration(a, checks.footprint(lifted, bounds)) < 0
