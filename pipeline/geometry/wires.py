"""Meshes and distances of thin wires, pure numpy: a tube swept along a polyline, the
bundle's subconductor paths, and the distance between segments (crossing checks)."""

from __future__ import annotations

import numpy as np


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangents, normals, binormals (each (n, 3)) along `points: (n, 3)`, n >= 2: the
    tangent at a vertex bisects its two segments; the normal starts horizontal (across
    the wire, or east for a plumb one) and is carried along by parallel transport, so
    a tube does not twist."""
    seg = _unit(np.diff(points, axis=0))
    tangents = np.empty_like(points)
    tangents[0], tangents[-1] = seg[0], seg[-1]
    tangents[1:-1] = _unit(seg[:-1] + seg[1:])
    bad = np.linalg.norm(tangents, axis=1) < 0.5  # a hairpin: take the segment before
    tangents[1:-1][bad[1:-1]] = seg[:-1][bad[1:-1]]
    normals = np.empty_like(points)
    across = np.cross(tangents[0], [0.0, 0.0, 1.0])
    if np.linalg.norm(across) < 1e-9:
        across = np.array([1.0, 0.0, 0.0])
    normals[0] = _unit(across)
    for i in range(1, len(points)):
        n = normals[i - 1] - np.dot(normals[i - 1], tangents[i]) * tangents[i]
        normals[i] = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-12 else normals[i - 1]
    return tangents, normals, np.cross(tangents, normals)


def tube(points: np.ndarray, radius: float, sides: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tube of `radius` around the polyline `points: (n, 3)` float64 with `sides`
    vertices per ring. Returns vertices (n * sides, 3) float64, faces (2 sides (n-1),
    3) int32 counter-clockwise seen from outside, and unit radial normals (n * sides, 3).
    The ends are open: they sit inside a terminal's clamp."""
    points = np.asarray(points, dtype=np.float64)
    _, normals, binormals = frames(points)
    angle = 2.0 * np.pi * np.arange(sides) / sides
    radial = (np.cos(angle)[None, :, None] * normals[:, None, :]
              + np.sin(angle)[None, :, None] * binormals[:, None, :])  # (n, sides, 3)
    vertices = (points[:, None, :] + radius * radial).reshape(-1, 3)
    ring = np.arange(sides)
    a = (np.arange(len(points) - 1)[:, None] * sides + ring[None, :]).reshape(-1)
    b = (np.arange(len(points) - 1)[:, None] * sides + ((ring + 1) % sides)[None, :]).reshape(-1)
    c, d = a + sides, b + sides
    # normal x binormal = tangent: counter-clockwise rings; (a, b, d) faces outwards
    faces = np.stack([np.stack([a, b, d], 1), np.stack([a, d, c], 1)], axis=1).reshape(-1, 3).astype(np.int32)
    return vertices, faces, radial.reshape(-1, 3)


def bundle_paths(points: np.ndarray, direction: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    """Each subconductor's polyline: `points: (n, 3)` of the bundle's centre moved by
    `offsets: (k, 2)` (across the span's horizontal `direction: (2,)`, up)."""
    across = np.array([-direction[1], direction[0], 0.0])
    up = np.array([0.0, 0.0, 1.0])
    return [points + o[0] * across + o[1] * up for o in np.asarray(offsets, dtype=np.float64)]


def segment_distances(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """(k,) shortest distances between segments p0-p1 and q0-q1, each (k, 3) float64
    (degenerate segments are points). The clamped closest-point solution: s on p, then
    t on q for that s, then s again for the clamped t."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    tiny = 1e-18
    s = np.where(denom > tiny * np.maximum(a * e, tiny), np.clip((b * f - c * e) / np.where(denom > 0, denom, 1), 0, 1), 0.0)
    t = np.where(e > tiny, (b * s + f) / np.where(e > tiny, e, 1), 0.0)
    s = np.where(t < 0, np.where(a > tiny, np.clip(-c / np.where(a > tiny, a, 1), 0, 1), 0.0), s)
    s = np.where(t > 1, np.where(a > tiny, np.clip((b - c) / np.where(a > tiny, a, 1), 0, 1), 0.0), s)
    t = np.clip(t, 0, 1)
    return np.linalg.norm((p0 + s[:, None] * d1) - (q0 + t[:, None] * d2), axis=1)


def close_pairs(polylines: list[np.ndarray], reach: float) -> dict[tuple[int, int], float]:
    """Pairs of polylines (each (n_i, 3), n_i >= 2) that come within `reach` of each
    other: (i, j) with i < j -> their shortest distance. Segments are paired through a
    k-d tree of their midpoints (a pair further apart than reach plus both half
    lengths cannot meet), then measured exactly, all at once."""
    from scipy.spatial import cKDTree

    if len(polylines) < 2:
        return {}
    a = np.concatenate([p[:-1] for p in polylines])
    b = np.concatenate([p[1:] for p in polylines])
    owner = np.repeat(np.arange(len(polylines)), [len(p) - 1 for p in polylines])
    mid = (a + b) / 2.0
    half = np.linalg.norm(b - a, axis=1) / 2.0
    pairs = cKDTree(mid).query_pairs(reach + 2.0 * float(half.max()), output_type="ndarray")
    if len(pairs) == 0:
        return {}
    pairs = pairs[owner[pairs[:, 0]] != owner[pairs[:, 1]]]
    gap = np.linalg.norm(mid[pairs[:, 0]] - mid[pairs[:, 1]], axis=1) - half[pairs[:, 0]] - half[pairs[:, 1]]
    pairs = pairs[gap <= reach]
    if len(pairs) == 0:
        return {}
    d = segment_distances(a[pairs[:, 0]], b[pairs[:, 0]], a[pairs[:, 1]], b[pairs[:, 1]])
    i, j = owner[pairs[:, 0]], owner[pairs[:, 1]]
    i, j = np.minimum(i, j), np.maximum(i, j)
    keep = d <= reach
    i, j, d = i[keep], j[keep], d[keep]
    order = np.lexsort((d, j, i))
    i, j, d = i[order], j[order], d[order]
    first = np.ones(len(i), dtype=bool)
    first[1:] = (i[1:] != i[:-1]) | (j[1:] != j[:-1])
    return {(int(x), int(y)): float(z) for x, y, z in zip(i[first], j[first], d[first])}
