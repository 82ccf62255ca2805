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


def _height_by_every_triangle(asset: ir.Asset, en: np.ndarray) -> np.ndarray:
    """The highest surface under each point, testing it against every triangle."""
    out = np.full(len(en), np.nan)
    for _, v in asset.visuals():
        for a, b, c in v.mesh.vertices[v.mesh.faces]:
            det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
            if abs(det) <= 1e-12:
                continue
            for i, (x, y) in enumerate(en):
                l1 = ((x - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (y - a[1])) / det
                l2 = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det
                if min(l1, l2, 1 - l1 - l2) >= -1e-9:
                    out[i] = np.fmax(out[i], (1 - l1 - l2) * a[2] + l1 * b[2] + l2 * c[2])
    return out


def test_height_at_binned_matches_every_triangle_tested():
    """The grid only skips pairs that cannot meet: on random points and on the
    triangles' own corners and edge midpoints (the hard cases) the heights match
    a test of every point against every triangle."""
    pfs = [ir.Platform("L1", np.array([[0, 0], [50, 0], [50, 40], [0, 40]])),
           ir.Platform("L2", np.array([[0, 60], [30, 60], [50, 90], [0, 90]]))]
    t = terrain.terrain_asset(FlatSite(), pfs, IdentityGeoref(), "t")
    rng = np.random.default_rng(3)
    corners = np.concatenate([v.mesh.vertices[:, :2] for _, v in t.visuals()])
    mids = np.concatenate([(v.mesh.vertices[v.mesh.faces[:, 0], :2] + v.mesh.vertices[v.mesh.faces[:, 1], :2]) / 2
                           for _, v in t.visuals()])
    en = np.r_[rng.uniform(-40, 90, (300, 2)) + [0, 10], corners[::3], mids[::3], [[-500.0, -500.0]]]
    z = terrain.height_at(t, en)
    np.testing.assert_allclose(z, _height_by_every_triangle(t, en), rtol=0, atol=1e-9)
    assert np.isfinite(z[:-1]).sum() > 300 and np.isnan(z[-1])


def test_height_at_one_huge_triangle_among_tiny_ones_and_points_far_off():
    """A 2 km triangle among 0.1 m ones would cover 10^8 cells of the small ones' size:
    the grid coarsens instead. A point a million km off, or NaN, meets no triangle."""
    rng = np.random.default_rng(5)
    corner = rng.uniform(0, 50, (400, 1, 3))
    tiny = corner + np.array([[0, 0, 0], [0.1, 0, 0.01], [0, 0.1, 0.02]])
    huge = np.array([[[-1000.0, -1000.0, 0.0], [1000.0, -1000.0, 0.0], [0.0, 1000.0, 10.0]]])
    tris = np.concatenate([tiny, huge]).reshape(-1, 3)
    mesh = ir.Mesh(tris, np.arange(len(tris)).reshape(-1, 3).astype(np.int32))
    t = ir.Asset(id="t", category="terrain", links=(ir.Link("t", visuals=(ir.Visual("v", "x", (mesh,)),)),))
    en = np.r_[rng.uniform(-5, 55, (200, 2)), corner[:50, 0, :2] + 0.02, [[1e12, 0.0], [np.nan, 1.0]]]
    z = terrain.height_at(t, en)
    np.testing.assert_allclose(z, _height_by_every_triangle(t, en), rtol=0, atol=1e-9)
    assert np.isfinite(z[:-2]).all() and np.isnan(z[-2:]).all()


def test_points_in_polygon_concave_grid():
    """An L shape: inside the 10 m square and not in its 5 m upper-right notch; points
    on any edge (the notch's too) count as inside."""
    ell = np.array([[0, 0], [10, 0], [10, 5], [5, 5], [5, 10], [0, 10]], dtype=float)
    g = np.arange(-1.0, 11.01, 0.5)
    pts = np.array(np.meshgrid(g, g)).reshape(2, -1).T
    x, y = pts[:, 0], pts[:, 1]
    expected = (x >= 0) & (x <= 10) & (y >= 0) & (y <= 10) & ~((x > 5) & (y > 5))
    np.testing.assert_array_equal(checks.points_in_polygon(pts, ell), expected)
    assert [checks.point_in_polygon(p, ell) for p in pts[:40]] == list(expected[:40])


def test_point_in_polygon_edges_count_inside():
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
    assert checks.point_in_polygon(np.array([5.0, 5.0]), sq)
    assert checks.point_in_polygon(np.array([10.0, 5.0]), sq)
    assert not checks.point_in_polygon(np.array([10.5, 5.0]), sq)


def test_penetration_of_oriented_boxes():
    lo, hi = np.array([[-1.0, -1, 0]]), np.array([[1.0, 1, 2]])
    a = checks.footprints(np.eye(4), lo, hi)

    def depth(pose) -> float:
        return float(checks.penetrations(a, checks.footprints(pose, lo, hi))[0])

    shifted = np.eye(4)
    shifted[0, 3] = 1.5
    assert depth(shifted) == pytest.approx(0.5)
    rot = np.eye(4)
    rot[:2, :2] = [[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]]
    rot[0, 3] = 3.5
    assert depth(rot) < 0
    lifted = np.eye(4)
    lifted[2, 3] = 2.5
    assert depth(lifted) < 0