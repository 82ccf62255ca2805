"""A ray against many axis-aligned boxes at once: which objects a ray can meet, before
an exact test against their triangles. Pure numpy."""

from __future__ import annotations

import numpy as np


def world_boxes(matrices: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-axis boxes (lo, hi), each (n, 3), of n objects: `matrices` (n, 4, 4)
    world-from-object, `corners` (n, 8, 3) each object's box in its own frame."""
    m = np.asarray(matrices, float)
    world = np.einsum("nij,nkj->nki", m[:, :3, :3], np.asarray(corners, float)) + m[:, None, :3, 3]
    return world.min(axis=1), world.max(axis=1)


def ray_box_entry(origin, direction, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance along the ray (origin + t * direction, t >= 0) at which it enters each
    box, 0 for a box it starts in, inf for a box it misses (slab test; a box's faces
    count as inside)."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - o) / d, (hi - o) / d
    near, far = np.fmin(a, b), np.fmax(a, b)
    # an axis the ray runs parallel to: inside its slab for all t, or never
    parallel = d == 0.0
    if parallel.any():
        inside = (lo[:, parallel] <= o[parallel]) & (o[parallel] <= hi[:, parallel])
        near[:, parallel] = np.where(inside, -np.inf, np.inf)
        far[:, parallel] = np.where(inside, np.inf, -np.inf)
    enter, leave = np.maximum(near.max(axis=1), 0.0), far.min(axis=1)
    return np.where(enter <= leave, enter, np.inf)
