"""Terraced terrain from the PLATFORM_<level> outlines (DESIGN.md s.2).

Each platform is flat at its level's elevation inside its outline; from its edge a
slope runs outward and down at the site's ratio (horizontal run per metre of rise)
to natural ground, where a ground apron of `skirt_width` extends beyond every slope.
Geometry is built in plan coordinates, then every vertex goes through the exact
georeferencer, so the terrain and the placements share one frame to the millimetre.
"""

from __future__ import annotations

import numpy as np

from .. import ir
from ..config import Site
from ..geometry.edges import edge_keys, edge_vertices

MAX_EDGE_M = 20.0  # flat tops are subdivided so the ellipsoid's curvature stays < 1 mm


def signed_area(poly: np.ndarray) -> float:
    """poly: (k, 2). Positive when counter-clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple polygon. poly: (k, 2) counter-clockwise; returns (k-2, 3) int."""
    idx = list(range(len(poly)))
    tris = []

    def is_ear(i0, i1, i2):
        a, b, c = poly[i0], poly[i1], poly[i2]
        if np.cross(b - a, c - b) <= 1e-12:
            return False
        for j in idx:
            if j in (i0, i1, i2):
                continue
            p = poly[j]
            if (np.cross(b - a, p - a) >= 0 and np.cross(c - b, p - b) >= 0 and np.cross(a - c, p - c) >= 0):
                return False
        return True

    guard = 0
    while len(idx) > 3 and guard < 10 * len(poly) ** 2:
        guard += 1
        n = len(idx)
        for k in range(n):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % n]
            if is_ear(i0, i1, i2):
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:
            raise ValueError("polygon is not simple")
    tris.append(tuple(idx))
    return np.array(tris, dtype=np.int64)


def subdivide(points: np.ndarray, tris: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle in four until no edge exceeds max_edge. points: (n, 2)."""
    while True:
        e = points[tris[:, [1, 2, 0]]] - points[tris]
        if len(tris) == 0 or np.linalg.norm(e, axis=2).max() <= max_edge:
            return points, tris
        keys, inverse = np.unique(edge_keys(tris, len(points)), return_inverse=True)
        mids = points[edge_vertices(keys, len(points))].mean(axis=1)
        base = len(points)
        points = np.concatenate([points, mids])
        m = inverse.reshape(-1, 3) + base  # midpoints of edges 01, 12, 20
        a, b, c = tris.T
        m01, m12, m20 = m.T
        tris = np.concatenate([
            np.stack([a, m01, m20], 1), np.stack([m01, b, m12], 1),
            np.stack([m20, m12, c], 1), np.stack([m01, m12, m20], 1)])


def offset_outline(poly: np.ndarray, distance: float) -> np.ndarray:
    """Move each vertex of a counter-clockwise polygon outward by `distance` along
    its corner bisector (mitred), so straight edges move by exactly `distance`."""
    prev = poly - np.roll(poly, 1, axis=0)
    nxt = np.roll(poly, -1, axis=0) - poly
    n1 = np.stack([prev[:, 1], -prev[:, 0]], 1) / np.linalg.norm(prev, axis=1)[:, None]
    n2 = np.stack([nxt[:, 1], -nxt[:, 0]], 1) / np.linalg.norm(nxt, axis=1)[:, None]
    bis = n1 + n2
    bis /= np.linalg.norm(bis, axis=1)[:, None]
    cos_half = np.clip(np.sum(bis * n1, axis=1), 0.2, 1.0)
    return poly + bis * (distance / cos_half)[:, None]


def terrain_surfaces(site: Site, platforms: list[ir.Platform]) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """Plan-space surfaces: (name, xy (n, 2), heights (n,), faces (m, 3)) per piece:
    each platform's flat top, its slope, and the ground apron."""
    surfaces = []
    rings = []
    for i, pf in enumerate(sorted(platforms, key=lambda p: (p.level, p.handle))):
        poly = np.asarray(pf.outline, dtype=np.float64)
        if len(poly) > 1 and np.allclose(poly[0], poly[-1]):
            poly = poly[:-1]
        if signed_area(poly) < 0:
            poly = poly[::-1]
        elev = site.level(pf.level).elevation
        top_xy, top_f = subdivide(poly, ear_clip(poly), MAX_EDGE_M)
        surfaces.append((f"platform_{pf.level}_{i}", top_xy, np.full(len(top_xy), elev), top_f))
        drop = max(elev - site.natural_ground, 0.0)
        if drop > 0:
            outer = offset_outline(poly, drop * site.slope_ratio)
            k = len(poly)
            xy = np.concatenate([poly, outer])
            h = np.concatenate([np.full(k, elev), np.full(k, site.natural_ground)])
            j = np.arange(k)
            jn = (j + 1) % k
            faces = np.concatenate([np.stack([j, j + k, jn + k], 1), np.stack([j, jn + k, jn], 1)])
            surfaces.append((f"slope_{pf.level}_{i}", xy, h, faces))
            rings.append(outer)
        else:
            rings.append(poly)
    if rings:
        allpts = np.concatenate(rings)
        lo = allpts.min(axis=0) - site.skirt_width
        hi = allpts.max(axis=0) + site.skirt_width
        apron = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        xy, f = subdivide(apron, np.array([[0, 1, 2], [0, 2, 3]]), 4 * MAX_EDGE_M)
        # the apron sits 5 cm below natural ground so slopes meet it without z-fighting
        surfaces.append(("ground", xy, np.full(len(xy), site.natural_ground - 0.05), f))
    return surfaces


def terrain_asset(site: Site, platforms: list[ir.Platform], georef, name: str) -> ir.Asset:
    """The terrain as an ir.Asset in the scene frame (ENU), one visual per surface,
    collision = the same triangles (static)."""
    materials = (
        ir.Material("gravel", (0.42, 0.4, 0.37, 1.0), 0.0, 0.95),
        ir.Material("grass", (0.18, 0.26, 0.09, 1.0), 0.0, 0.95),
        ir.Material("soil", (0.3, 0.22, 0.14, 1.0), 0.0, 0.95),
    )
    visuals, collisions = [], []
    for sname, xy, h, faces in terrain_surfaces(site, platforms):
        enu = georef.to_enu(xy, h)
        mesh = ir.Mesh(enu, faces.astype(np.int32))
        mat = "gravel" if sname.startswith("platform") else ("grass" if sname == "ground" else "soil")
        visuals.append(ir.Visual(sname, mat, (mesh,)))
        collisions.append(ir.Collision(f"{sname}_collision", mesh))
    link = ir.Link("terrain", visuals=visuals, collisions=collisions, mass=1.0)
    return ir.Asset(id=name, category="terrain", links=(link,), materials=materials,
                    description=f"terraced terrain of {site.name}")


def height_at(asset: ir.Asset, en: np.ndarray) -> np.ndarray:
    """Terrain height (ENU z) under each point en: (n, 2), the highest surface hit;
    NaN where no surface lies under a point.

    Each surface's triangles are binned on a grid of about their own size, and a
    point is tested only against the triangles of its cell: the scene's thousands of
    placements against a terrain of thousands of triangles cost what their pairs
    that can meet cost, not every pair."""
    en = np.asarray(en, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(en), np.nan)
    for _, v in asset.visuals():
        point, tri = _candidate_pairs(v.mesh, en)
        if len(point) == 0:
            continue
        corners = v.mesh.vertices[v.mesh.faces[tri]]  # (pairs, 3, 3)
        a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        ok = np.abs(det) > 1e-12
        safe = np.where(ok, det, 1.0)
        px, py = en[point, 0], en[point, 1]
        l1 = ((px - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (py - a[:, 1])) / safe
        l2 = ((b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (px - a[:, 0]) * (b[:, 1] - a[:, 1])) / safe
        l0 = 1 - l1 - l2
        inside = ok & (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        z = np.full(len(en), -np.inf)
        np.maximum.at(z, point[inside], (l0 * a[:, 2] + l1 * b[:, 2] + l2 * c[:, 2])[inside])
        hit = np.isfinite(z)
        out[hit] = np.fmax(out[hit], z[hit])
    return out


def _candidate_pairs(mesh: ir.Mesh, en: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point index, triangle index) of every point and triangle sharing a grid cell:
    a superset of the pairs where the point lies in the triangle."""
    empty = np.zeros(0, dtype=np.int64)
    if len(mesh.faces) == 0 or len(en) == 0:
        return empty, empty
    xy = mesh.vertices[mesh.faces][:, :, :2]  # (t, 3, 2)
    lo, hi = xy.min(axis=1), xy.max(axis=1)
    # the inside test's tolerance reaches a hair beyond the triangle's box
    pad = 1e-6 * np.maximum(1.0, (hi - lo).max(axis=1, keepdims=True))
    lo, hi = lo - pad, hi + pad
    origin = lo.min(axis=0)
    # cells of about a triangle's size; coarser while a few large triangles among many
    # small ones would cover far more cells than there are triangles
    cell = max(float(np.median((hi - lo).max(axis=1))), 1e-6)
    while True:
        first = np.floor((lo - origin) / cell).astype(np.int64)
        last = np.floor((hi - origin) / cell).astype(np.int64)
        if ((last - first + 1).prod(axis=1).sum()) <= 16 * len(lo) + 1024:
            break
        cell *= 2.0
    top = last.max(axis=0)
    columns = int(top[1]) + 1
    with np.errstate(invalid="ignore"):
        point_cell = np.floor((en - origin) / cell)
    # a point beyond every triangle's box (or NaN) meets none: no key, no overflow
    on_grid = ((point_cell >= 0) & (point_cell <= top)).all(axis=1)
    point_cell = np.where(on_grid[:, None], point_cell, 0).astype(np.int64)
    # every (triangle, cell) of the triangle's box, as a sorted table of cell keys
    span = last - first + 1
    per_tri = span[:, 0] * span[:, 1]
    tri = np.repeat(np.arange(len(lo)), per_tri)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(per_tri) - per_tri, per_tri)
    cx = first[tri, 0] + k // span[tri, 1]
    cy = first[tri, 1] + k % span[tri, 1]
    keys = cx * columns + cy
    order = np.argsort(keys, kind="stable")
    keys, tri = keys[order], tri[order]
    # each point against the run of its cell's triangles
    pkey = np.where(on_grid, point_cell[:, 0] * columns + point_cell[:, 1], -1)
    start = np.searchsorted(keys, pkey, side="left")
    stop = np.where(on_grid, np.searchsorted(keys, pkey, side="right"), start)
    count = stop - start
    point = np.repeat(np.arange(len(en)), count)
    offset = np.arange(len(point)) - np.repeat(np.cumsum(count) - count, count)
    return point, tri[np.repeat(start, count) + offset]
