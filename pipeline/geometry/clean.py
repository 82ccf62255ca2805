"""Mesh cleaning: finite check, welding, degenerate/duplicate faces, consistent winding.

Pure numpy/scipy functions on arrays (`vertices: (n, 3) float64`, `faces: (m, 3) int`)
plus `clean(CleanOptions())`, the Asset -> Asset step. Everything works on coordinates
relative to the mesh's bounding-box centre, so a mesh placed 10^7 m from its origin
welds and orients as well as one at the origin.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .. import ir
from ..errors import UserError
from .edges import directed_edges, edge_keys, edge_vertices


@dataclass(frozen=True)
class CleanOptions:
    """relative_tolerance: weld distance as a fraction of the bounding-box diagonal;
    absolute_tolerance_m: added to it (metres), so tiny parts still weld float noise;
    uv_tolerance, normal_tolerance: vertices with attributes further apart stay split
    (a UV seam or a hard edge is kept);
    orient: make winding consistent per connected component and closed parts outward."""

    relative_tolerance: float = 1e-9
    absolute_tolerance_m: float = 1e-7
    uv_tolerance: float = 1e-6
    normal_tolerance: float = 1e-3
    orient: bool = True


def weld_tolerance(vertices: np.ndarray, options: CleanOptions = CleanOptions()) -> float:
    """Weld distance (m) for `vertices: (n, 3)`: relative part of the diagonal + absolute."""
    if len(vertices) == 0:
        return options.absolute_tolerance_m
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    return options.relative_tolerance * diag + options.absolute_tolerance_m


def check_finite(vertices: np.ndarray, file: str, obj: str) -> None:
    """Raise UserError(file, obj) when `vertices: (n, 3)` holds NaN or infinity."""
    bad = ~np.isfinite(np.asarray(vertices, dtype=np.float64)).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise UserError(file, obj, f"{int(bad.sum())} vertices have non-finite coordinates (first: vertex {first})")


def centred(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices - centre, centre): centre is the bounding-box centre (3,) float64."""
    if len(vertices) == 0:
        return vertices.astype(np.float64), np.zeros(3)
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0
    return vertices - centre, centre


def weld_map(
    vertices: np.ndarray,
    tolerance: float,
    attributes: list[tuple[np.ndarray, float]] = (),
) -> np.ndarray:
    """Index map (n,) int64 old -> representative old index (the smallest in its group).

    vertices: (n, 3) float64. Two vertices merge when they are within `tolerance` and
    each attribute array (n, k) in `attributes` is within its own tolerance too.
    Groups are the connected components of the "close" relation (a chain of close
    vertices merges, as a union-find weld does).
    """
    n = len(vertices)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    local, _ = centred(vertices)
    pairs = cKDTree(local).query_pairs(r=tolerance, output_type="ndarray")
    for values, tol in attributes:
        if len(pairs) == 0:
            break
        d = np.linalg.norm(values[pairs[:, 0]] - values[pairs[:, 1]], axis=1)
        pairs = pairs[d <= tol]
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    graph = sparse.coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    first = np.full(labels.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(n, dtype=np.int64))
    return first[labels]


def compact(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices. Returns (kept old indices (k,), faces remapped (m, 3)).

    Kept vertices stay in their original order, so welding never shuffles a mesh.
    """
    used = np.zeros(n_vertices, dtype=bool)
    used[faces.ravel()] = True
    kept = np.flatnonzero(used)
    new_index = np.full(n_vertices, -1, dtype=np.int64)
    new_index[kept] = np.arange(len(kept))
    return kept, new_index[faces].reshape(-1, 3)


def degenerate_faces(vertices: np.ndarray, faces: np.ndarray, tolerance: float) -> np.ndarray:
    """(m,) bool: faces with a repeated index or a height below `tolerance` (zero area,
    or a needle/cap so flat it is a line within the weld tolerance)."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    local, _ = centred(vertices)
    a, b, c = local[faces[:, 0]], local[faces[:, 1]], local[faces[:, 2]]
    double_area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)]), axis=0)
    # height over the longest edge = 2 area / longest; below the weld distance it is a line
    flat = double_area <= tolerance * longest
    return repeated | flat


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Like np.unique(rows, axis=0, return_index, return_inverse) for (k, c) int arrays,
    several times faster (a lexsort instead of sorting a structured view).
    Returns (first index of each unique row (u,), inverse (k,), counts (u,))."""
    k = len(rows)
    if k == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.lexsort(rows.T[::-1])
    srt = rows[order]
    new = np.r_[True, (srt[1:] != srt[:-1]).any(axis=1)]
    group = np.cumsum(new) - 1
    inverse = np.empty(k, dtype=np.int64)
    inverse[order] = group
    first = np.full(group[-1] + 1, k, dtype=np.int64)
    np.minimum.at(first, group, order)
    return first, inverse, np.bincount(group)


def duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces whose vertex set already appeared earlier (either winding)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    first, _, _ = unique_rows(np.sort(faces, axis=1))
    dup = np.ones(len(faces), dtype=bool)
    dup[first] = False
    return dup


def edge_face_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges (e, 2) int64 (sorted pairs, ascending) and how many faces use
    each (e,)."""
    n = int(np.max(faces, initial=-1)) + 1
    keys, counts = np.unique(edge_keys(faces, n), return_counts=True)
    return edge_vertices(keys, n), counts


def non_manifold_edge_count(faces: np.ndarray) -> int:
    """Number of edges used by more than two faces (`faces: (m, 3)` int)."""
    if len(faces) == 0:
        return 0
    return len(non_manifold_edge_keys(faces, int(np.max(faces)) + 1))


def non_manifold_edge_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """The edges used by more than two faces, each as one int64 key (lower vertex *
    n_vertices + higher), ascending: every undirected edge keyed and counted in one
    1-D sort."""
    key = np.sort(edge_keys(faces, n_vertices))
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, dtype=np.int64)
    counts = np.diff(np.r_[starts, len(key)])
    return key[starts[counts > 2]]


def _face_graph(faces: np.ndarray):
    """Adjacency of faces across manifold edges (exactly 2 faces), and whether each
    adjacent pair is inconsistently wound (traverses the shared edge the same way)."""
    m = len(faces)
    directed = directed_edges(faces)
    forward = directed[:, 0] < directed[:, 1]
    face_of = np.repeat(np.arange(m), 3)
    key = edge_keys(faces, int(directed.max(initial=0)) + 1)
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(key_sorted)])
    manifold = starts[counts == 2]
    h1, h2 = order[manifold], order[manifold + 1]
    f1, f2 = face_of[h1], face_of[h2]
    flip = (forward[h1] == forward[h2]).astype(np.int8)
    return f1, f2, flip


def _signed_volumes(local: np.ndarray, faces: np.ndarray, labels: np.ndarray, n_labels: int) -> np.ndarray:
    a, b, c = local[faces[:, 0]], local[faces[:, 1]], local[faces[:, 2]]
    v = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    return np.bincount(labels, weights=v, minlength=n_labels)


def orient_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (m, 3) with winding consistent within each edge-connected component and
    closed components outward (signed volume > 0).

    Propagation runs over manifold edges only (an edge shared by 3+ faces has no
    consistent answer). Open components keep the orientation most of their faces were
    authored with. Implementation: a BFS spanning forest of the face graph, then the
    flip parity of each face is the XOR of inconsistency flags along its tree path,
    computed by pointer jumping (log-depth vectorised steps, no Python loop per face).
    """
    faces = np.asarray(faces)
    m = len(faces)
    if m == 0:
        return faces.copy()
    f1, f2, flip = _face_graph(faces)
    # one flag per adjacent face pair (two faces may share two edges: keep the first)
    pair = np.stack([np.minimum(f1, f2), np.maximum(f1, f2)], axis=1)
    first, _, _ = unique_rows(pair)
    pair, flip = pair[first], flip[first]
    n_comp, labels = csgraph.connected_components(
        sparse.coo_matrix((np.ones(len(pair)), (pair[:, 0], pair[:, 1])), shape=(m, m)), directed=False
    )
    # a virtual node m joins every component's first face, so one BFS spans the forest
    roots = np.unique(labels, return_index=True)[1]
    rows = np.r_[pair[:, 0], pair[:, 1], np.full(len(roots), m)]
    cols = np.r_[pair[:, 1], pair[:, 0], roots]
    vals = np.r_[flip, flip, np.zeros(len(roots), dtype=np.int8)].astype(np.float64) + 1.0
    graph = sparse.csr_matrix((vals, (rows, cols)), shape=(m + 1, m + 1))
    _, pred = csgraph.breadth_first_order(graph, m, directed=True, return_predecessors=True)
    pred = pred[:m].astype(np.int64)
    parity = np.zeros(m + 1, dtype=np.int8)
    parity[:m] = np.asarray(graph[pred, np.arange(m)]).ravel() > 1.5  # stored flip + 1
    # pointer jumping: parity <- XOR of the flags along the path to the virtual root
    up = np.r_[pred, m]
    for _ in range(64):
        if (up == m).all():
            break
        parity = parity ^ parity[up]
        up = up[up]
    parity = parity[:m]
    out = faces.copy()
    out[parity == 1] = out[parity == 1][:, ::-1]
    # outward: closed components by signed volume; open ones keep the authored majority
    local, _ = centred(vertices)
    closed = _closed_components(out, labels, n_comp)
    vol = _signed_volumes(local, out, labels, n_comp)
    flipped_share = np.bincount(labels, weights=parity.astype(np.float64), minlength=n_comp) / np.bincount(labels, minlength=n_comp)
    reverse = np.where(closed, vol < 0, flipped_share > 0.5)
    sel = reverse[labels]
    out[sel] = out[sel][:, ::-1]
    return out


def _closed_components(faces: np.ndarray, labels: np.ndarray, n_comp: int) -> np.ndarray:
    """(n_comp,) bool: every edge of the component is used by exactly two faces."""
    comp = np.repeat(labels, 3)
    _, inverse, counts = np.unique(edge_keys(faces, int(np.max(faces)) + 1), return_inverse=True, return_counts=True)
    bad_edge = counts[inverse] != 2
    open_comp = np.bincount(comp, weights=bad_edge.astype(np.float64), minlength=n_comp) > 0
    return ~open_comp


def flip_winding_if_mirrored(faces: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """faces (m, 3) reversed when the (4, 4)/(3, 3) matrix mirrors (det < 0)."""
    if np.linalg.det(np.asarray(matrix, dtype=np.float64)[:3, :3]) < 0:
        return np.asarray(faces)[:, ::-1].copy()
    return np.asarray(faces).copy()


def apply_transform(vertices: np.ndarray, faces: np.ndarray, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transform `vertices: (n, 3)` by a (4, 4) matrix; `faces: (m, 3)` are reversed when
    det < 0 so outward stays outward (DESIGN.md: fix the faces, never export a mirror)."""
    m = np.asarray(matrix, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
    return v, flip_winding_if_mirrored(faces, m)


def clean_mesh(mesh: ir.Mesh, options: CleanOptions = CleanOptions(), file: str = "", obj: str = "") -> ir.Mesh:
    """Weld, drop degenerate and duplicate faces, orient; UserError(file, obj) on NaN.

    Vertices weld only when position, UVs, normals and every shape key agree, so the
    mesh looks the same and its shape keys stay valid (they are remapped with it).
    Unreferenced vertices are dropped; the rest keep their relative order.
    """
    check_finite(mesh.vertices, file, obj)
    for key in mesh.shape_keys:
        check_finite(key.vertices, file, f"{obj} (shape key {key.name})")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    n = len(mesh.vertices)
    if len(faces) and (faces.min() < 0 or faces.max() >= n):
        raise UserError(file, obj, f"face indices out of range (mesh has {n} vertices)")
    tol = weld_tolerance(mesh.vertices, options)
    attrs = []
    if mesh.uvs is not None:
        attrs.append((mesh.uvs, options.uv_tolerance))
    if mesh.normals is not None:
        attrs.append((mesh.normals, options.normal_tolerance))
    for key in mesh.shape_keys:
        attrs.append((key.vertices, tol))
    rep = weld_map(mesh.vertices, tol, attrs)
    faces = rep[faces] if len(faces) else faces.reshape(0, 3)
    keep = ~degenerate_faces(mesh.vertices, faces, tol) if len(faces) else np.zeros(0, dtype=bool)
    faces = faces[keep]
    faces = faces[~duplicate_faces(faces)]
    kept, faces = compact(faces, n)
    vertices = mesh.vertices[kept]
    if options.orient and len(faces):
        faces = orient_faces(vertices, faces)
    return ir.Mesh(
        vertices,
        faces,
        normals=None if mesh.normals is None else mesh.normals[kept],
        uvs=None if mesh.uvs is None else mesh.uvs[kept],
        shape_keys=tuple(ir.ShapeKey(k.name, k.vertices[kept]) for k in mesh.shape_keys),
    )


def clean(options: CleanOptions = CleanOptions()) -> Callable[[ir.Asset], ir.Asset]:
    """Step: clean every LOD of every visual and every collision mesh of the asset.

    A visual left with no triangles is a UserError (its author should delete it)."""

    def step(asset: ir.Asset) -> ir.Asset:
        links = []
        for link in asset.links:
            visuals = []
            for vis in link.visuals:
                lods = tuple(clean_mesh(m, options, asset.source, vis.name) for m in vis.lods)
                if lods[0].triangle_count == 0:
                    raise UserError(asset.source, vis.name, "mesh has no valid triangles after cleaning")
                visuals.append(replace(vis, lods=lods))
            collisions = tuple(replace(c, mesh=clean_mesh(c.mesh, options, asset.source, c.name)) for c in link.collisions)
            links.append(replace(link, visuals=tuple(visuals), collisions=collisions))
        return asset.with_(links=tuple(links))

    return step
