"""Generated collision geometry: convex hulls or boxes of a link's visuals.

`collision_step(CollisionOptions(mode=...))` gives every link without authored
collisions hull(s) in its link frame; pure helpers `convex_hull`, `box_hull`,
`connected_parts` work on arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Literal

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import ConvexHull, QhullError

from .. import ir
from ..errors import UserError
from .clean import orient_faces

Mode = Literal["hull_per_link", "hull_per_part", "box"]


@dataclass(frozen=True)
class CollisionOptions:
    """mode: one hull per link, one per connected part, or one oriented-to-link box;
    max_parts: hull_per_part merges the smallest parts into one hull beyond this."""

    mode: Mode = "hull_per_link"
    max_parts: int = 16


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward convex hull of `points: (n, 3)`.

    Returns vertices (k, 3) float64 (hull vertices only) and faces (j, 3) int64.
    Flat or degenerate point sets (a planar gauge face, a line, one point) get a
    box of their bounds padded to 1 mm, so a hull always encloses a volume.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        raise ValueError("no points")
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0  # Qhull is happier near the origin
    try:
        hull = ConvexHull(pts - centre)
        faces = hull.simplices.astype(np.int64)
    except (QhullError, ValueError):
        return box_hull(pts, pad=1e-3)
    used = np.unique(faces)
    remap = np.full(len(pts), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    v, f = pts[used], remap[faces]
    return v, orient_faces(v, f)


def box_hull(points: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (8 vertices, 12 outward faces) around `points: (n, 3)`;
    each extent is at least `pad` (m)."""
    pts = np.asarray(points, dtype=np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    grow = np.maximum(pad - (hi - lo), 0.0) / 2.0
    lo, hi = lo - grow, hi + grow
    v = np.array([[(lo, hi)[x][0], (lo, hi)[y][1], (lo, hi)[z][2]] for z in (0, 1) for y in (0, 1) for x in (0, 1)])
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.int64)
    return v, f


def connected_parts(faces: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """Vertex index arrays of the vertex-connected parts of `faces: (m, 3)`."""
    f = np.asarray(faces, dtype=np.int64)
    rows = np.r_[f[:, 0], f[:, 1]]
    cols = np.r_[f[:, 1], f[:, 2]]
    g = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    n, labels = csgraph.connected_components(g, directed=False)
    used = np.zeros(n_vertices, dtype=bool)
    used[f.ravel()] = True
    return [idx for idx in (np.flatnonzero((labels == k) & used) for k in range(n)) if len(idx)]


def _link_points(link: ir.Link) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertices in the link frame (n, 3), faces) of each visual's authored mesh."""
    out = []
    for vis in link.visuals:
        m = vis.mesh
        if len(m.faces) == 0:
            continue
        v = m.vertices @ vis.pose[:3, :3].T + vis.pose[:3, 3]
        out.append((v, np.asarray(m.faces, dtype=np.int64)))
    return out


def _part_hulls(meshes: list[tuple[np.ndarray, np.ndarray]], max_parts: int) -> list[tuple[np.ndarray, np.ndarray]]:
    parts = []
    for v, f in meshes:
        parts += [v[idx] for idx in connected_parts(f, len(v))]
    # largest first (by bounding-box diagonal); the tail beyond the cap shares one hull
    parts.sort(key=lambda p: -float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))))
    if len(parts) > max_parts:
        parts = parts[: max_parts - 1] + [np.concatenate(parts[max_parts - 1:])]
    return [convex_hull(p) for p in parts]


def link_collisions(link: ir.Link, options: CollisionOptions = CollisionOptions()) -> tuple[ir.Collision, ...]:
    """Generated collisions of one link (empty when it has no visual geometry)."""
    meshes = _link_points(link)
    if not meshes:
        return ()
    if options.mode == "hull_per_part":
        hulls = _part_hulls(meshes, options.max_parts)
    elif options.mode == "box":
        hulls = [box_hull(np.concatenate([v for v, _ in meshes]), pad=1e-3)]
    else:
        hulls = [convex_hull(np.concatenate([v for v, _ in meshes]))]
    return tuple(ir.Collision(f"{link.name}_collision_{i}", ir.Mesh(v, f)) for i, (v, f) in enumerate(hulls))


def collision_step(options: CollisionOptions = CollisionOptions()) -> Callable[[ir.Asset], ir.Asset]:
    """Step: every link without authored collisions gets generated ones (link frame)."""
    if options.mode not in ("hull_per_link", "hull_per_part", "box"):
        raise UserError("asset.toml", "collision.mode", f"unknown collision mode {options.mode!r}")

    def step(asset: ir.Asset) -> ir.Asset:
        links = []
        for link in asset.links:
            if link.collisions:
                links.append(link)
                continue
            for _, vis in ((link, v) for v in link.visuals):
                if not np.isfinite(vis.mesh.vertices).all():
                    raise UserError(asset.source, vis.name, "non-finite vertex coordinates")
            links.append(replace(link, collisions=link_collisions(link, options)))
        return asset.with_(links=tuple(links))

    return step
