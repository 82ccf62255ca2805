"""clean, transform, metrics, collision, uv: hard cases on small hand-made meshes."""

import math

import numpy as np
import pytest
import trimesh

from fixtures_assets import box_arrays
from pipeline import ir
from pipeline.errors import UserError
from pipeline.geometry import clean as C
from pipeline.geometry import collision, metrics, transform as T


def box(offset=0.0):
    """A 1 x 2 x 3 box centred on (offset, offset, offset)."""
    return box_arrays((1, 2, 3), (offset,) * 3)


def volume(v, f):
    v = v - v.mean(axis=0)
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


def test_clean_soup_degenerate_duplicate_and_inward_at_1e7():
    v, f = box(1e7)
    soup = v[f[:, ::-1]].reshape(-1, 3)  # inward, unwelded
    faces = np.arange(len(soup)).reshape(-1, 3)
    faces = np.concatenate([faces, faces[:2], [[0, 0, 1]], [[0, 1, 1]]])  # duplicates, repeated index
    m = C.clean_mesh(ir.Mesh(soup, faces))
    assert len(m.vertices) == 8 and m.triangle_count == 12
    assert volume(m.vertices, m.faces) == pytest.approx(6.0, rel=1e-9)
    assert C.non_manifold_edge_count(m.faces) == 0


def test_zero_area_face_dropped_and_nan_rejected():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    m = C.clean_mesh(ir.Mesh(v, [[0, 1, 2], [0, 1, 3]]))
    assert m.triangle_count == 1
    v[1, 0] = np.nan
    with pytest.raises(UserError) as e:
        C.clean_mesh(ir.Mesh(v, [[0, 1, 3]]), file="a.stl", obj="gauge")
    assert "a.stl: gauge" in str(e.value)


def test_orientation_mixed_components_and_non_manifold_survives():
    v1, f1 = box()
    v2, f2 = box(5.0)
    f2 = f2[:, ::-1]  # second part inward
    rng = np.random.default_rng(1)
    f1 = np.where(rng.random(len(f1))[:, None] < 0.5, f1[:, ::-1], f1)  # random winding
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f2 + len(v1)])
    out = C.orient_faces(v, f)
    assert volume(v[:8], out[:12]) > 0 and volume(v[8:], out[12:] - 8) > 0
    # an extra fin on one edge: non-manifold, kept, no crash
    fin = np.concatenate([v, [[9.0, 9.0, 9.0]]])
    e = f[0, :2]
    out2 = C.clean_mesh(ir.Mesh(fin, np.concatenate([f, [[e[0], e[1], len(fin) - 1]]])))
    assert C.non_manifold_edge_count(out2.faces) == 1


def test_weld_respects_uvs_and_shape_keys():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 1, 0]], float)
    f = [[0, 1, 2], [3, 4, 1]]
    uvs = np.array([[0, 0], [1, 0], [0, 1], [0.5, 0.5], [1, 1]])
    assert len(C.clean_mesh(ir.Mesh(v, f, uvs=uvs)).vertices) == 5  # a UV seam stays split
    key = v.copy()
    key[3] += 0.1
    m = C.clean_mesh(ir.Mesh(v, f, shape_keys=(ir.ShapeKey("k", key),)))
    assert len(m.vertices) == 5 and len(m.shape_keys[0].vertices) == 5
    m2 = C.clean_mesh(ir.Mesh(v, f, shape_keys=(ir.ShapeKey("k", v * 2),)))
    assert len(m2.vertices) == 4
    np.testing.assert_allclose(m2.shape_keys[0].vertices, m2.vertices * 2)


def test_negative_scale_keeps_outward():
    v, f = box()
    mirror = np.diag([-1.0, 2.0, 1.0, 1.0])
    v2, f2 = C.apply_transform(v, f, mirror)
    assert volume(v2, f2) == pytest.approx(12.0)
    t, r, s = T.decompose(mirror @ T.xyz_rpy_to_matrix((1, 2, 3), (0.1, 0.2, 0.3)))
    assert (s < 0).sum() == 1 and np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, 0.3])
def test_rpy_round_trip_near_gimbal_lock(pitch):
    m = T.xyz_rpy_to_matrix((1e7, -2e6, 3.0), (0.7, pitch, -1.1))
    xyz, rpy = T.matrix_to_xyz_rpy(m)
    assert np.isfinite(rpy).all()
    back = T.xyz_rpy_to_matrix(xyz, rpy)
    assert np.abs(back[:3, :3] - m[:3, :3]).max() < 1e-12 * (1 if abs(abs(pitch) - math.pi / 2) < 1e-15 else 1e4)
    q = T.quaternion_from_matrix(m)
    assert np.abs(T.matrix_from_quaternion(q, xyz) - m).max() < 1e-9
    assert np.allclose(T.compose(m, T.invert_rigid(m)), np.eye(4), atol=1e-6)


def test_quaternion_180_degrees():
    m = T.xyz_rpy_to_matrix(rpy=(math.pi, 0, 0))
    q = T.quaternion_from_matrix(m)
    assert np.allclose(np.abs(q), [0, 1, 0, 0], atol=1e-12)


def test_surface_distance_matches_trimesh_far_from_origin():
    mesh = trimesh.creation.annulus(r_min=0.2, r_max=0.5, height=0.3, sections=24)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(3000, 3))
    _, expected, _ = trimesh.proximity.closest_point(mesh, p)
    offset = np.array([576000.0, 8595900.0, 48.0])  # UTM-sized coordinates
    sd = metrics.SurfaceDistance(mesh.vertices + offset, mesh.faces)
    d, face = sd.nearest(p + offset)
    np.testing.assert_allclose(d, expected, atol=1e-9)
    assert face.min() >= 0 and face.max() < len(mesh.faces)


def _on_segment(p, a, b):
    """Nearest points of segments a-b (k, 3) to p (k, 3), directly."""
    ab = b - a
    t = np.clip(np.einsum("kj,kj->k", p - a, ab) / np.einsum("kj,kj->k", ab, ab), 0.0, 1.0)
    return a + t[:, None] * ab


def test_closest_points_on_triangles_match_trimesh_and_hold_on_degenerate_ones():
    """The nearest point of each triangle: trimesh's on well-shaped triangles; on a
    collapsed, a collinear or a needle triangle the true one (trimesh's region tests
    were off by up to 0.19 m on needles in a check here), never nearer than the
    triangle allows."""
    from trimesh.triangles import closest_point

    rng = np.random.default_rng(3)
    k = 4000
    tri = rng.normal(size=(k, 3, 3))
    points = 2.0 * rng.normal(size=(k, 3))
    ours = metrics.closest_points_on_triangles(tri, points)
    np.testing.assert_allclose(ours, closest_point(tri, points), atol=1e-10)

    a, b = rng.normal(size=(k, 3)), rng.normal(size=(k, 3))
    collapsed = np.stack([a, a, a], axis=1)
    np.testing.assert_array_equal(metrics.closest_points_on_triangles(collapsed, points), a)
    collinear = np.stack([a, b, (a + b) / 2.0], axis=1)  # zero area: its segment a-b
    np.testing.assert_allclose(metrics.closest_points_on_triangles(collinear, points), _on_segment(points, a, b),
                               atol=1e-12)
    # a needle: c a nanometre off a, so the triangle is within 1e-9 of segment a-b
    needle = np.stack([a, b, a + 1e-9 * rng.normal(size=(k, 3))], axis=1)
    ours = metrics.closest_points_on_triangles(needle, points)
    d, d_segment = (np.linalg.norm(x - points, axis=1) for x in (ours, _on_segment(points, a, b)))
    assert np.all(np.abs(d - d_segment) < 1e-8)
    # every result is on its triangle: barycentric weights non-negative, summing to 1
    ab, ac, ap = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], metrics.closest_points_on_triangles(tri, points) - tri[:, 0]
    weights = np.linalg.solve(np.stack([ab, ac], axis=2).transpose(0, 2, 1) @ np.stack([ab, ac], axis=2),
                              (np.stack([ab, ac], axis=2).transpose(0, 2, 1) @ ap[:, :, None]))[:, :, 0]
    assert np.all(weights >= -1e-9) and np.all(weights.sum(axis=1) <= 1 + 1e-9)


def test_hausdorff_sphere_vs_coarse_and_offset():
    fine = trimesh.creation.icosphere(subdivisions=5)
    coarse = trimesh.creation.icosphere(subdivisions=2)
    expected = 1 - np.linalg.norm(coarse.triangles_center, axis=1).min()  # deepest face centre
    h = metrics.hausdorff(fine.vertices + 1e7, fine.faces, coarse.vertices + 1e7, coarse.faces, samples=20000)
    assert expected * 0.97 < h < expected * 1.05
    assert metrics.hausdorff(fine.vertices, fine.faces, fine.vertices, fine.faces, samples=5000) < 1e-9
    assert metrics.hausdorff(fine.vertices, fine.faces, fine.vertices, fine.faces[:0]) == math.inf


def _asset(*visuals):
    return ir.Asset("a", "c", (ir.Link("base", visuals=visuals),), source="a.blend")


@pytest.mark.parametrize("mode", ["hull_per_link", "hull_per_part", "box"])
def test_collision_modes_closed_outward(mode):
    v1, f1 = box()
    v2, f2 = box(10.0)
    flat = ir.Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])  # planar: hull must not fail
    a = _asset(ir.Visual("a", "m", (ir.Mesh(np.concatenate([v1, v2]), np.concatenate([f1, f2 + 8])),)),
               ir.Visual("flat", "m", (flat,), pose=T.xyz_rpy_to_matrix((0, 0, 20))))
    out = collision.collision_step(collision.CollisionOptions(mode=mode))(a)
    cols = out.links[0].collisions
    assert len(cols) == {"hull_per_link": 1, "hull_per_part": 3, "box": 1}[mode]
    for c in cols:
        tm = trimesh.Trimesh(c.mesh.vertices, c.mesh.faces, process=False)
        assert tm.is_watertight and volume(c.mesh.vertices, c.mesh.faces) > 0
    allv = np.concatenate([c.mesh.vertices for c in cols])
    assert allv[:, 2].max() >= 20.0 - 1e-9  # the flat visual's pose was applied


def test_hull_per_part_caps_count():
    parts = [box(3.0 * i) for i in range(20)]
    v = np.concatenate([p[0] for p in parts])
    f = np.concatenate([p[1] + 8 * i for i, p in enumerate(parts)])
    out = collision.collision_step(collision.CollisionOptions("hull_per_part", max_parts=16))(_asset(ir.Visual("a", "m", (ir.Mesh(v, f),))))
    assert len(out.links[0].collisions) == 16


def test_surface_distance_exact_beside_crowding_parts():
    # a sphere pierced by a long thin cylinder: the cylinder's 10 m faces crowd the
    # candidate index near the sphere; the distance must still be exact
    s = trimesh.creation.icosphere(subdivisions=3)
    c = trimesh.creation.cylinder(radius=0.01, height=10.0, sections=8)
    v = np.concatenate([s.vertices, c.vertices])
    f = np.concatenate([s.faces, c.faces + len(s.vertices)])
    assert metrics.hausdorff(v, f, v, f, samples=5000) < 1e-9
    sd = metrics.SurfaceDistance(v, f)
    rng = np.random.default_rng(3)
    p = rng.normal(size=(3000, 3)) * 0.7
    tris = v[f]
    brute = np.min([np.linalg.norm(p - trimesh.triangles.closest_point(np.repeat(t[None], len(p), 0), p), axis=1)
                    for t in tris], axis=0)
    np.testing.assert_allclose(sd(p), brute, atol=1e-12)
    assert sd.max_distance(p) == pytest.approx(brute.max(), abs=1e-12)


def test_surface_distance_exact_where_it_decides_on_slivers():
    # two side faces of the sample's rigid busbar tube between its end rings, 3.7 m
    # long and 9.8 mm wide: fcpw's float32 arithmetic picks the farther one for this
    # point, and the distance that decides must still be exact
    v = np.array([[-5.800000195022013, 0.01950903236865997, -0.09807827303043212],
                  [-2.0850000424341215, 0.01950903236865997, -0.09807843541824586],
                  [-2.0850000424970636, 0.00980171468108892, -0.09951837932789094],
                  [-5.800000195084955, 0.00980171468108892, -0.0995182169400772]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    p = np.array([[-4.617111412737789, 0.01698018142268529, -0.09758916737500006],
                  [-4.0, 0.5, 0.5]])  # far away: the maximum
    exact = np.min([np.linalg.norm(p - trimesh.triangles.closest_point(np.repeat(v[t][None], len(p), 0), p), axis=1)
                    for t in f], axis=0)
    sd = metrics.SurfaceDistance(v, f, np.zeros(3))
    rough, face = sd.nearest(p, exact_above=np.inf)  # only the maximum measured again
    assert rough[1] == pytest.approx(exact[1], abs=1e-12)
    assert rough[0] > exact[0] + 1e-4 and face[0] == 1  # the farther sliver, measured exactly
    decided, face = sd.nearest(p, exact_above=0.5e-3)  # over half a millimetre decides
    np.testing.assert_allclose(decided, exact, atol=1e-12)
    assert face[0] == 0
    np.testing.assert_allclose(sd(p), exact, atol=1e-12)  # the default: every distance exact
