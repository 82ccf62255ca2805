"""The ray against many boxes (geometry/rays.py): rotated boxes, parallel rays, rays
that start inside, against points sampled along the ray."""

import numpy as np

from pipeline.geometry import rays, transform as T


def _first_inside(origin, direction, lo, hi, t_max=40.0, steps=400_001):
    """The first sampled t at which origin + t direction is in each box (inf: none)."""
    t = np.linspace(0.0, t_max, steps)
    points = origin + t[:, None] * direction
    out = []
    for a, b in zip(lo, hi):
        inside = np.all((points >= a) & (points <= b), axis=1)
        out.append(t[inside.argmax()] if inside.any() else np.inf)
    return np.array(out)


def test_entry_distances_match_sampling_the_ray():
    rng = np.random.default_rng(3)
    lo = rng.uniform(-10, 10, (60, 3))
    hi = lo + rng.uniform(0.2, 4.0, (60, 3))
    for _ in range(5):
        origin = rng.uniform(-12, 12, 3)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        got = rays.ray_box_entry(origin, direction, lo, hi)
        want = _first_inside(origin, direction, lo, hi)
        assert np.array_equal(np.isinf(got), np.isinf(want))
        assert np.allclose(got[np.isfinite(got)], want[np.isfinite(want)], atol=2e-4)


def test_a_ray_parallel_to_a_face_and_one_starting_inside():
    lo, hi = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    along_x = np.array([1.0, 0.0, 0.0])
    assert rays.ray_box_entry([-2.0, 0.5, 0.5], along_x, lo, hi).tolist() == [2.0, 2.0]
    assert rays.ray_box_entry([-2.0, 0.5, 1.5], along_x, lo, hi).tolist() == [np.inf, np.inf]  # above, parallel
    assert rays.ray_box_entry([-2.0, 1.0, 0.5], along_x, lo, hi).tolist() == [2.0, 2.0]  # on a face: inside
    assert rays.ray_box_entry([0.5, 0.5, 0.5], [0.0, 0.0, -1.0], lo, hi).tolist() == [0.0, 0.0]
    assert rays.ray_box_entry([2.0, 0.5, 0.5], along_x, lo, hi).tolist() == [np.inf, np.inf]  # behind


def test_world_boxes_hold_every_corner_of_rotated_objects():
    rng = np.random.default_rng(4)
    corners = np.array([[(x, y, z) for x in (-1.0, 2.0) for y in (0.0, 0.5) for z in (-0.2, 3.0)]] * 10)
    matrices = np.array([T.xyz_rpy_to_matrix(rng.uniform(-5, 5, 3), rng.uniform(-3, 3, 3)) for _ in range(10)])
    lo, hi = rays.world_boxes(matrices, corners)
    for m, c, a, b in zip(matrices, corners, lo, hi):
        world = np.array([(m @ np.append(p, 1.0))[:3] for p in c])
        assert np.allclose(a, world.min(axis=0)) and np.allclose(b, world.max(axis=0))
