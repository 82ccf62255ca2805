"""The judge: how far a candidate simplification is from the authored mesh, and
whether it flips a face or adds a non-manifold edge.

A candidate's error is the MEASURED two-sided Hausdorff distance (metrics.hausdorff's
sampling) to the original it was made from. A judge indexes one original once and
measures many candidates against it; `Judge.measure` returns the checked result and
the points where it fails, which the search locks vertices around.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import clean as _clean
from ..edges import edge_vertices
from ..metrics import SurfaceDistance, face_normals, query_points_on, vertex_normals

MEASURE_SAMPLES = 50_000
# Measuring costs more than simplifying: sample in proportion to the mesh, within bounds.
SAMPLES_PER_FACE = 4
MIN_SAMPLES = 1_000
# Face keys pack three vertex ids in an int64: meshes with more vertices go without.
KEYED_VERTICES = 2_000_000
# A face whose normal agrees with its reference by less than this (a cosine) points
# clearly away, rather than standing across a crease.
FLIP_COSINE = -0.2


@dataclass(frozen=True)
class Simplified:
    """A checked simplification: vertices (k, 3), faces (j, 3), `kept` (k,) original
    vertex indices when the vertex buffer is a subset of the input's (meshoptimizer),
    else None; measured two-sided Hausdorff error (m); flips; non-manifold edges added."""

    vertices: np.ndarray
    faces: np.ndarray
    kept: np.ndarray | None
    error_m: float
    flipped: int
    non_manifold_added: int

    @property
    def valid(self) -> bool:
        return len(self.faces) > 0 and self.flipped == 0 and self.non_manifold_added <= 0


@dataclass(frozen=True)
class Measurement:
    """What `Judge.measure` finds of a candidate: the checked `result`, and where it
    fails: `misses: (p, 3)` points (flipped faces' centroids; with a threshold, also
    points measured further than it either way and the middles of added non-manifold
    edges) and `how_far: (p,)` the distance measured at each (inf for a flip or an
    added edge)."""

    result: Simplified
    misses: np.ndarray
    how_far: np.ndarray


def flipped_face_count(reference: SurfaceDistance, vertices: np.ndarray, faces: np.ndarray, tolerance: float) -> int:
    """Faces of (vertices (n, 3), faces (m, 3)) that point against the reference
    surface's nearest face, seen from their centroid and from `tolerance` out along
    their own normal: a thin two-sided part (thinner than the tolerance) is never
    counted, as from one of the two points the nearest face agrees. Used for
    simplifiers that move vertices; see `fan_flips` for the others."""
    if len(faces) == 0:
        return 0
    normals = face_normals(vertices, faces)
    centroids = vertices[faces].mean(axis=1)
    ref_normals = face_normals(reference.vertices, reference.faces)
    best = np.full(len(faces), -np.inf)
    for points in (centroids, centroids + tolerance * normals):
        _, nearest = reference.nearest(points)
        best = np.maximum(best, np.einsum("kj,kj->k", ref_normals[nearest], normals))
    has_area = np.linalg.norm(normals, axis=1) > 0
    return int(((best < FLIP_COSINE) & has_area).sum())


def vertex_fans(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR of the faces around each vertex: (starts (n + 1,), unit normals of the
    incident faces in vertex order (3m, 3))."""
    corner_vertex = faces.ravel()
    order = np.argsort(corner_vertex, kind="stable")
    starts = np.searchsorted(corner_vertex[order], np.arange(len(vertices) + 1))
    return starts, face_normals(vertices, faces)[order // 3]


def fan_flips(fans: tuple[np.ndarray, np.ndarray], kept: np.ndarray, vertices: np.ndarray,
              faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces (on `vertices`, original vertices `kept`) whose normal points
    against EVERY original face around each of its three corners (`fans` from
    vertex_fans of the original). An original face always agrees with itself; a face
    that turned over in a collapse disagrees with the whole surface it came from, even
    on a thin part where a vertex's averaged normal points the other way."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    starts, fan_normals = fans
    n = face_normals(vertices, faces)
    corner = kept[faces].ravel()
    deg = starts[corner + 1] - starts[corner]
    rows = np.repeat(np.arange(len(corner)), deg)
    pos = np.arange(len(rows)) - np.repeat(np.cumsum(deg) - deg, deg) + np.repeat(starts[corner], deg)
    dots = np.einsum("kj,kj->k", fan_normals[pos], n[rows // 3])
    best = np.full(len(corner), -np.inf)
    np.maximum.at(best, rows, dots)
    has_area = np.linalg.norm(n, axis=1) > 0
    return (best.reshape(-1, 3).max(axis=1) < FLIP_COSINE) & has_area


def topology_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """faces re-indexed on position-welded vertices (so UV/normal seams count as joined)."""
    rep = _clean.weld_map(vertices, _clean.weld_tolerance(vertices))
    return rep[faces]


def oriented_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """(m,) int64 key of each face's corners in winding order, rotated to start at the
    smallest (the same oriented face however it is rotated), or None past 63 bits."""
    if n_vertices >= KEYED_VERTICES:
        return None
    f = np.asarray(faces, dtype=np.int64)
    start = np.argmin(f, axis=1)
    rows = np.arange(len(f))
    a, b, c = f[rows, start], f[rows, (start + 1) % 3], f[rows, (start + 2) % 3]
    return (a * n_vertices + b) * n_vertices + c


def face_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """(m,) int64 key of each face's vertex set (winding and rotation ignored: the same
    surface), or None when the keys would not fit in 63 bits."""
    if n_vertices >= KEYED_VERTICES:
        return None
    f = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (f[:, 0] * n_vertices + f[:, 1]) * n_vertices + f[:, 2]


def lookup(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of `keys: (k,)` are in `sorted_keys: (s,)` (ascending), and where: (found
    (k,) bool, position (k,) int64, meaningful where found)."""
    pos = np.searchsorted(sorted_keys, keys)
    found = np.zeros(len(keys), dtype=bool)
    inside = pos < len(sorted_keys)
    found[inside] = sorted_keys[pos[inside]] == keys[inside]
    return found, pos


def _first_of_each(keys: np.ndarray) -> np.ndarray:
    """(k,) bool: True at the first occurrence of each key (duplicate_faces' rule)."""
    first = np.zeros(len(keys), dtype=bool)
    first[np.unique(keys, return_index=True)[1]] = True
    return first


class Judge:
    """Measures candidates against one original mesh (indices built once)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, samples: int, parts: np.ndarray | None = None):
        samples = int(np.clip(SAMPLES_PER_FACE * len(faces), MIN_SAMPLES, samples))
        self.vertices, self.faces, self.samples = vertices, faces, samples
        self.reference = SurfaceDistance(vertices, faces)
        # a candidate's topology is judged on the original's weld: its vertices are a
        # subset of the original's, so welding them again would only repeat this. Each
        # part (`parts: (n,)` ids) apart, as the validator judges each visual: two
        # members that touch share no edge
        attrs = [] if parts is None else [(np.asarray(parts, dtype=np.float64)[:, None], 0.5)]
        self.topology = _clean.weld_map(vertices, _clean.weld_tolerance(vertices), attrs)
        topo = self.topology[faces]
        # the original's own non-manifold edges, and how many each part has: a part
        # may trade some for others (a lattice's joints move as it simplifies), as the
        # validator's per-visual check allows, but not have more
        self.part = np.zeros(len(vertices), np.int64) if parts is None else np.unique(parts, return_inverse=True)[1]
        self.non_manifold_keys = _clean.non_manifold_edge_keys(topo, len(vertices))
        self.non_manifold = len(self.non_manifold_keys)
        self.part_non_manifold = self._per_part(self.part[edge_vertices(self.non_manifold_keys, len(vertices))[:, 0]])
        # normals on the welded surface, so a UV seam does not split a corner's normal
        self.normals = vertex_normals(vertices, topo)[self.topology]
        self.fans = vertex_fans(vertices, faces)
        # the original side's query points, reused: which vertex or face each lies on
        self.queries, self.query_vertex, self.query_face = query_points_on(vertices, faces, samples)
        self.face_keys = face_keys(faces, len(vertices))
        # the original faces by their oriented key, sorted, for exact lookups: a
        # candidate face that IS an original face (same corners, same winding) needs no
        # flip or degeneracy test
        oriented = oriented_keys(faces, len(vertices))
        self.oriented_order = None if oriented is None else np.argsort(oriented, kind="stable")
        self.oriented_sorted = None if oriented is None else oriented[self.oriented_order]
        self.sorted_face_keys = None if self.face_keys is None else np.sort(self.face_keys)
        self.degenerate = _clean.degenerate_faces(vertices, faces, 0.0) if len(faces) else np.zeros(0, dtype=bool)
        self._vertex_tree = None
        # Per original query point, the last exact distance measured and the face it
        # was measured to (key, -1: none). A later candidate that still has that face is
        # at most that far from the point: a bound that spares most re-measurements.
        self.bound_key = np.full(len(self.queries), -1, dtype=np.int64)
        self.bound = np.full(len(self.queries), np.inf)

    def _per_part(self, edge_parts: np.ndarray) -> np.ndarray:
        """How many edges each part has, given each edge's part."""
        return np.bincount(edge_parts, minlength=int(self.part.max(initial=0)) + 1)

    def near_vertices(self, points: np.ndarray, k: int = 4) -> np.ndarray:
        """Original vertex ids nearest to `points: (p, 3)` (k each), unique."""
        if len(points) == 0:
            return np.zeros(0, dtype=np.int64)
        _, idx = self._tree().query(points, k=min(k, len(self.vertices)), workers=-1)
        return np.unique(idx)

    def nearest_vertex(self, points: np.ndarray) -> np.ndarray:
        """The original vertex id nearest to each of `points: (p, 3)`."""
        return self._tree().query(points, k=1, workers=-1)[1] if len(points) else np.zeros(0, dtype=np.int64)

    def _tree(self):
        from scipy.spatial import cKDTree

        if self._vertex_tree is None:
            self._vertex_tree = cKDTree(self.vertices)
        return self._vertex_tree

    def __call__(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None, tolerance: float) -> Simplified:
        return self.measure(v, f, kept, tolerance).result

    def measure(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None, tolerance: float,
                threshold: float | None = None) -> Measurement:
        """The candidate (vertices `v: (k, 3)`, faces `f: (j, 3)` on them, `kept: (k,)`
        their original ids or None for new vertices) checked within `tolerance`, and
        where it misses `threshold` (see Measurement)."""
        f, original, cand_keys = self._candidate_faces(v, f, kept)
        if len(f) == 0:
            return Measurement(Simplified(v, f, kept, math.inf, 0, 0), np.zeros((0, 3)), np.zeros(0))
        misses, how_far = [], []
        if kept is not None:  # vertices are the original ones: judge flips at the corners
            # an original face agrees with itself: only the others can have turned over
            turned = f[~original][fan_flips(self.fans, kept, v, f[~original])]
            flips = len(turned)
            misses.append(v[turned].mean(axis=1))
            how_far.append(np.full(flips, np.inf))
        else:
            flips = flipped_face_count(self.reference, v, f, tolerance)
        # vertices are the original ones (meshoptimizer): so are some faces
        if cand_keys is None and kept is not None:
            cand_keys = face_keys(kept[f], len(self.vertices))
        # judged on the original's weld, in the original's vertex numbering
        topo = None if kept is None else self.topology[kept[f]]
        used, f = _clean.compact(f, len(v))
        v = v[used]
        kept = None if kept is None else kept[used]
        own, index = self._query_points(v, f, kept, cand_keys)
        target = SurfaceDistance(v, f, self.reference.origin)
        # exact where a distance decides: a miss (over the threshold) or over the budget
        decides = min(threshold, tolerance) if threshold is not None else tolerance
        d_back = self.reference(own, decides)
        back = float(d_back.max(initial=0.0))
        # Points whose bound (an earlier exact distance to a face this candidate still
        # has) is under the threshold can neither miss nor be the maximum of a failing
        # candidate; a passing one measures them too, so its recorded error is exact.
        bounded = np.zeros(len(index), dtype=bool)
        if cand_keys is not None and threshold is not None:
            near = self.bound[index] <= threshold
            near[near] = np.isin(self.bound_key[index[near]], cand_keys)
            bounded = near
        d_there = np.zeros(len(index))
        d_there[~bounded] = self._distances(target, index[~bounded], cand_keys, decides)
        there = float(d_there.max(initial=0.0))
        added, new_edges, at = self._added_edges(v, f, kept, topo)
        if bounded.any() and there <= threshold and back <= tolerance and flips == 0 and added <= 0:
            d_there[bounded] = self._distances(target, index[bounded], cand_keys, decides)
            there = float(d_there.max(initial=0.0))
        else:
            d_there[bounded] = self.bound[index[bounded]]  # upper bounds, all <= threshold
        if threshold is not None:
            queries = self.queries[index]
            misses += [queries[d_there > threshold], own[d_back > threshold]]
            how_far += [d_there[d_there > threshold], d_back[d_back > threshold]]
            if added > 0:
                ends = edge_vertices(new_edges, len(at))
                misses.append((at[ends[:, 0]] + at[ends[:, 1]]) / 2.0)
                how_far.append(np.full(len(new_edges), np.inf))
        result = Simplified(v, f, kept, max(there, back), flips, added)
        return Measurement(result, np.concatenate(misses) if misses else np.zeros((0, 3)),
                           np.concatenate(how_far) if how_far else np.zeros(0))

    def _candidate_faces(self, v: np.ndarray, f: np.ndarray,
                         kept: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """A candidate's faces without degenerate or repeated ones: (faces (j, 3), (j,)
        bool which are original faces (same corners and winding), each face's
        vertex-set key (j,) when its vertices are the original ones, else None)."""
        f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
        if len(f) and kept is not None and self.oriented_sorted is not None:
            original, which = lookup(self.oriented_sorted, oriented_keys(kept[f], len(self.vertices)))
            degenerate = np.zeros(len(f), dtype=bool)
            degenerate[original] = self.degenerate[self.oriented_order[which[original]]]
            degenerate[~original] = _clean.degenerate_faces(v, f[~original], 0.0)
            keep = ~degenerate
            cand_keys = face_keys(kept[f[keep]], len(self.vertices))
            first = _first_of_each(cand_keys)
            keep[keep] = first
            return f[keep], original[keep], cand_keys[first]
        if len(f):
            f = f[~_clean.degenerate_faces(v, f, 0.0)]
            f = f[~_clean.duplicate_faces(f)]
        return f, np.zeros(len(f), dtype=bool), None

    def _query_points(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None,
                      cand_keys: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The candidate's own query points (p, 3) and the ids of the original's query
        points to measure. A point on a face both meshes share, or on an original
        vertex, is at distance 0 from both surfaces: measuring it cannot change the
        maximum."""
        own, own_vertex, own_face = query_points_on(v, f, self.samples)
        if cand_keys is not None and self.face_keys is not None:
            shared = lookup(np.sort(cand_keys), self.face_keys)[0]
            on_original = lookup(self.sorted_face_keys, cand_keys)[0]
            is_kept = np.zeros(len(self.vertices) + 1, dtype=bool)
            is_kept[kept] = True
            skip = is_kept[self.query_vertex] | ((self.query_face >= 0) & shared[self.query_face])
            own = own[(own_vertex < 0) & ~((own_face >= 0) & on_original[own_face])]
        elif kept is not None:
            skip = np.isin(self.query_vertex, kept)
        else:
            skip = np.zeros(len(self.queries), dtype=bool)
        return own, np.nonzero(~skip)[0]

    def _added_edges(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None,
                     topo: np.ndarray | None) -> tuple[int, np.ndarray, np.ndarray]:
        """(how many non-manifold edges the candidate adds, the keys of the edges that
        count as misses, the vertices those keys index). `topo`: its faces on the
        original's weld, None for new vertices (then only the counts compare)."""
        at = self.vertices if kept is not None else v  # topo's numbering
        if topo is None:
            new_edges = _clean.non_manifold_edge_keys(topology_faces(v, f), len(at))
            return len(new_edges) - self.non_manifold, new_edges, at
        # counted per part, not over the union: one part's lost edges do not pay for
        # another's added ones, which the per-visual check would then refuse. Only the
        # added edges are misses: locking around the original's own (a lattice of
        # welded members has hundreds) changes nothing, and would use up the rounds
        keys = _clean.non_manifold_edge_keys(topo, len(at))
        edge_part = self.part[edge_vertices(keys, len(at))[:, 0]]
        grown = self._per_part(edge_part) - self.part_non_manifold
        added = int(np.maximum(grown, 0).sum())
        return added, keys[~lookup(self.non_manifold_keys, keys)[0] & (grown[edge_part] > 0)], at

    def _distances(self, target: SurfaceDistance, index: np.ndarray, cand_keys: np.ndarray | None,
                   exact_above: float) -> np.ndarray:
        """Distances from the original query points `index` to `target` (exact above
        `exact_above` and at the maximum, see SurfaceDistance.nearest), kept with the
        face each was measured to (as bounds for later candidates)."""
        d, face = target.nearest(self.queries[index], exact_above)
        if cand_keys is not None and len(index):
            self.bound[index], self.bound_key[index] = d, cand_keys[face]
        return d
