"""The Gazebo world's collision cells (scene.world_collisions) as Gazebo placed them,
and whether a placement's collision is in them where its own would be."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from pipeline.geometry.collision import connected_parts
from pipeline.scene.world_collisions import MODEL_NAME, read_collada_triangles

# what 4 decimals of a cell's coordinates and float text allow
TOLERANCE_M = 2e-4


def cell_parts(seen: dict) -> list[np.ndarray]:
    """(n, 3) world vertices of each connected part of the collision cells' meshes, as
    the probe's report (`seen`) says Gazebo placed the files it resolved."""
    cells = next(m for m in seen["models"] if m["name"] == MODEL_NAME)
    world_from_model = np.array(cells["world_from_model"]).reshape(4, 4)
    parts = []
    for use in cells["meshes"]:
        assert use["kind"] == "collision" and use["path"], use
        m = world_from_model @ np.array(use["model_from_mesh"]).reshape(4, 4)
        vertices, faces = read_collada_triangles(Path(use["path"]))
        vertices = vertices @ m[:3, :3].T + m[:3, 3]
        parts += [vertices[idx] for idx in connected_parts(faces, len(vertices))]
    return parts


def assert_in_cells(points: np.ndarray, parts: list[np.ndarray], exact: bool, what: str) -> None:
    """Each of `points` (a placement's collision vertices in the world) is a vertex of
    the cells' meshes (exact: a near placement's every triangle) or inside one of
    their boxes (a far placement's parts)."""
    if exact:
        gap, _ = cKDTree(np.concatenate(parts)).query(points)  # each point's nearest cell vertex
        assert gap.max() <= TOLERANCE_M, (what, gap.max())
        return
    inside = np.zeros(len(points), dtype=bool)
    for part in parts:
        if len(part) == 8:
            eq = ConvexHull(part).equations
            inside |= np.all(points @ eq[:, :3].T + eq[:, 3] <= TOLERANCE_M, axis=1)
    assert inside.all(), (what, points[~inside][:3])
