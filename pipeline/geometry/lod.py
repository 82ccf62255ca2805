"""Error-bounded mesh simplification and the LOD-chain step.

A LOD level has a budget in metres; it gets the coarsest mesh this module can find
whose MEASURED two-sided Hausdorff distance to the authored mesh (metrics.hausdorff)
is within the budget, that flips no face and adds no non-manifold edge. Each level is
simplified from the authored mesh, never from the previous level, so errors do not
accumulate. Three simplifiers:

- "meshoptimizer" (default): error-driven (absolute error target); keeps the original
  vertex buffer, so UVs and normals of the kept vertices survive and attribute seams
  (UV seams, hard edges) are respected. The search scales its error target.
- "pymeshlab": quadric edge collapse with optimal placement, the accuracy reference.
  Count-driven: the search bisects on the triangle count. Crashes the whole process on
  a face with two equal indices, so input is always cleaned first.
- "fast_simplification": fast quadrics (Fast-Quadric-Mesh-Simplification), count-driven.

Vertices are simplified relative to their bounding-box centre (meshoptimizer works in
float32: 10^7 m coordinates would otherwise lose everything below a metre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Protocol

import numpy as np

from .. import ir
from ..digest import sha256_arrays, sha256_json
from ..errors import UserError
from ..spare import core_share, cores_to_spare, spread
from . import clean as _clean
from .metrics import SurfaceDistance, face_normals, query_points_on, vertex_normals
from .transform import linear_scale

METHODS = ("meshoptimizer", "pymeshlab", "fast_simplification")
MEASURE_SAMPLES = 50_000
# Measuring costs more than simplifying: sample in proportion to the mesh, within bounds.
SAMPLES_PER_FACE = 4
MIN_SAMPLES = 1_000
# Below this many triangles a level saves nothing worth a measurement.
MIN_FACES = 64
# A result keeping this share of the faces is no simplification: stop searching.
NO_GAIN = 0.95
# Points measured further than this share of the budget get their vertices locked.
LOCK_SHARE = 0.8
# More misses than this share of the measured points: lower the target, lock nothing.
WIDESPREAD = 0.02
# simplify+measure rounds per level at most, and the widest lock around one miss
ITERATIONS = 10
LOCK_NEIGHBOURS = 64
# A welded mesh of more than twice this many faces is searched in pieces of at most
# this many (_pieces).
PIECE_FACES = 16_384


# --- raw simplifiers: (vertices (n, 3), faces (m, 3)) -> (vertices, faces) -------------


def _meshopt(vertices: np.ndarray, faces: np.ndarray, target_faces: int, target_error: float,
             lock: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """meshoptimizer's simplify. target_error is ABSOLUTE (same units as vertices);
    `lock: (n,) bool` vertices are never moved or removed.
    Returns the ORIGINAL vertices and new faces (indices into them)."""
    import meshoptimizer

    idx = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    pos = np.ascontiguousarray(vertices, dtype=np.float32)
    dest = np.zeros(len(idx), dtype=np.uint32)
    options = meshoptimizer.SIMPLIFY_ERROR_ABSOLUTE
    if lock is None or not lock.any():
        count = meshoptimizer.simplify(dest, idx, pos, target_index_count=int(3 * max(target_faces, 0)),
                                       target_error=float(target_error), options=options)
    else:
        count = _simplify_locked(dest, idx, pos, np.ascontiguousarray(lock, dtype=np.uint8),
                                 int(3 * max(target_faces, 0)), float(target_error), options)
    return vertices, dest[:count].reshape(-1, 3).astype(np.int64)


def _simplify_locked(dest, idx, pos, lock, target_index_count: int, target_error: float, options: int) -> int:
    """meshopt_simplifyWithAttributes with no attributes and a vertex lock, called
    through ctypes with its full signature (the binding declares no argument types,
    so its size_t arguments would pass as 32-bit ints)."""
    import ctypes

    from meshoptimizer._loader import lib

    fn = lib.meshopt_simplifyWithAttributes
    if fn.restype is not ctypes.c_size_t:
        f, u, s = ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t
        fn.argtypes = [u, u, s, f, s, s, f, s, f, s, ctypes.POINTER(ctypes.c_ubyte), s, ctypes.c_float, ctypes.c_uint, f]
        fn.restype = s
    attrs = np.zeros(len(pos), dtype=np.float32)
    weights = np.zeros(1, dtype=np.float32)
    return int(fn(dest.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)), idx.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)),
                  len(idx), pos.ctypes.data_as(ctypes.POINTER(ctypes.c_float)), len(pos), 12,
                  attrs.ctypes.data_as(ctypes.POINTER(ctypes.c_float)), 4,
                  weights.ctypes.data_as(ctypes.POINTER(ctypes.c_float)), 1,
                  lock.ctypes.data_as(ctypes.POINTER(ctypes.c_ubyte)), target_index_count, target_error, options, None))


def _pymeshlab(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(vertices, dtype=np.float64),
                               face_matrix=np.asarray(faces, dtype=np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(max(target_faces, 1)), qualitythr=0.3, preservenormal=True, preservetopology=True,
        optimalplacement=True, planarquadric=True, autoclean=True,
    )
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def _fast(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    import fast_simplification

    if target_faces >= len(faces):
        return vertices, faces
    v, f = fast_simplification.simplify(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int32),
                                        target_count=int(max(target_faces, 1)))
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64).reshape(-1, 3)


def simplify_to_count(vertices: np.ndarray, faces: np.ndarray, target_faces: int,
                      method: str = "meshoptimizer") -> tuple[np.ndarray, np.ndarray]:
    """Simplify `vertices: (n, 3)`, `faces: (m, 3)` to about `target_faces` triangles,
    no error bound and no checks (the benchmark's matched-count mode). The input must be
    clean (pymeshlab crashes on faces with repeated indices). Returns (vertices (k, 3)
    float64, faces (j, 3) int64), unused vertices dropped."""
    local, centre = _clean.centred(np.asarray(vertices, dtype=np.float64))
    faces = np.asarray(faces, dtype=np.int64)
    if method == "meshoptimizer":
        v, f = _meshopt(local, faces, target_faces, target_error=float("inf"))
    elif method == "pymeshlab":
        v, f = _pymeshlab(local, faces, target_faces)
    elif method == "fast_simplification":
        v, f = _fast(local, faces, target_faces)
    else:
        raise ValueError(f"unknown simplifier {method!r}; one of {METHODS}")
    kept, f = _clean.compact(f, len(v)) if len(f) else (np.zeros(0, dtype=np.int64), f.reshape(0, 3))
    return v[kept] + centre, f


# --- checks -----------------------------------------------------------------------


def flipped_face_count(reference: SurfaceDistance, vertices: np.ndarray, faces: np.ndarray, tolerance: float) -> int:
    """Faces of (vertices (n, 3), faces (m, 3)) that point against the reference
    surface's nearest face, seen from their centroid and from `tolerance` out along
    their own normal: a thin two-sided part (thinner than the tolerance) is never
    counted, as from one of the two points the nearest face agrees. Used for
    simplifiers that move vertices; see `flipped_by_fans` for the others."""
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
    # below -0.2: clearly facing away, not a face standing across a crease
    return int(((best < -0.2) & has_area).sum())


def _vertex_fans(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR of the faces around each vertex: (starts (n + 1,), unit normals of the
    incident faces in vertex order (3m, 3))."""
    corner_vertex = faces.ravel()
    order = np.argsort(corner_vertex, kind="stable")
    starts = np.searchsorted(corner_vertex[order], np.arange(len(vertices) + 1))
    return starts, face_normals(vertices, faces)[order // 3]


def flipped_by_fans(fans: tuple[np.ndarray, np.ndarray], kept: np.ndarray, vertices: np.ndarray,
                    faces: np.ndarray, where: list | None = None) -> int:
    """Faces (on `vertices`, original vertices `kept`) whose normal points against
    EVERY original face around each of its three corners (`fans` from _vertex_fans
    of the original). An original face always agrees with itself; a face that
    turned over in a collapse disagrees with the whole surface it came from, even on
    a thin part where a vertex's averaged normal points the other way."""
    if len(faces) == 0:
        return 0
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
    flipped = (best.reshape(-1, 3).max(axis=1) < -0.2) & has_area
    if where is not None:  # the flipped faces' centroids, to lock around them
        where.append(vertices[faces[flipped]].mean(axis=1))
    return int(flipped.sum())


def _topology_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """faces re-indexed on position-welded vertices (so UV/normal seams count as joined)."""
    rep = _clean.weld_map(vertices, _clean.weld_tolerance(vertices))
    return rep[faces]


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


class _Judge:
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
        self.part_non_manifold = self._per_part(self.part[self.non_manifold_keys // len(vertices)])
        # normals on the welded surface, so a UV seam does not split a corner's normal
        self.normals = vertex_normals(vertices, topo)[self.topology]
        self.fans = _vertex_fans(vertices, faces)
        # the original side's query points, reused: which vertex or face each lies on
        self.queries, self.query_vertex, self.query_face = query_points_on(vertices, faces, samples)
        self.face_keys = _face_keys(faces, len(vertices))
        # the original faces by their oriented key, sorted, for exact lookups: a
        # candidate face that IS an original face (same corners, same winding) needs no
        # flip or degeneracy test
        oriented = _oriented_keys(faces, len(vertices))
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
        return self.measure(v, f, kept, tolerance)[0]

    def measure(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None, tolerance: float,
                threshold: float | None = None) -> tuple[Simplified, np.ndarray]:
        """The checked result and the points (p, 3) where it fails: distances above
        `threshold` either way, flipped faces, new non-manifold edges (none when
        threshold is None)."""
        f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
        original = np.zeros(len(f), dtype=bool)  # same corners and winding as an original face
        cand_keys = None  # each kept face's vertex-set key, when vertices are the original ones
        if len(f) and kept is not None and self.oriented_sorted is not None:
            original, which = _lookup(self.oriented_sorted, _oriented_keys(kept[f], len(self.vertices)))
            degenerate = np.zeros(len(f), dtype=bool)
            degenerate[original] = self.degenerate[self.oriented_order[which[original]]]
            degenerate[~original] = _clean.degenerate_faces(v, f[~original], 0.0)
            keep = ~degenerate
            cand_keys = _face_keys(kept[f[keep]], len(self.vertices))
            first = _first_of_each(cand_keys)
            keep[keep] = first
            f, original, cand_keys = f[keep], original[keep], cand_keys[first]
        elif len(f):
            f = f[~_clean.degenerate_faces(v, f, 0.0)]
            f = f[~_clean.duplicate_faces(f)]
        if len(f) == 0:
            return Simplified(v, f, kept, math.inf, 0, 0), np.zeros((0, 3))
        bad, how_far = [], []
        if kept is not None:  # vertices are the original ones: judge flips at the corners
            # an original face agrees with itself: only the others can have turned over
            flips = flipped_by_fans(self.fans, kept, v, f[~original], bad)
            how_far.append(np.full(len(bad[0]), np.inf))
        else:
            flips = flipped_face_count(self.reference, v, f, tolerance)
        # vertices are the original ones (meshoptimizer): so are some faces
        if cand_keys is None and kept is not None:
            cand_keys = _face_keys(kept[f], len(self.vertices))
        # judged on the original's weld, in the original's vertex numbering
        topo = None if kept is None else self.topology[kept[f]]
        used, f = _clean.compact(f, len(v))
        v = v[used]
        kept = None if kept is None else kept[used]
        own, own_vertex, own_face = query_points_on(v, f, self.samples)
        if cand_keys is not None and self.face_keys is not None:
            # A point on a face both meshes share, or on an original vertex, is at
            # distance 0 from both surfaces: measuring it cannot change the maximum.
            shared = _lookup(np.sort(cand_keys), self.face_keys)[0]
            on_original = _lookup(self.sorted_face_keys, cand_keys)[0]
            is_kept = np.zeros(len(self.vertices) + 1, dtype=bool)
            is_kept[kept] = True
            skip = is_kept[self.query_vertex] | ((self.query_face >= 0) & shared[self.query_face])
            own = own[(own_vertex < 0) & ~((own_face >= 0) & on_original[own_face])]
        elif kept is not None:
            skip = np.isin(self.query_vertex, kept)
        else:
            skip = np.zeros(len(self.queries), dtype=bool)
        index = np.nonzero(~skip)[0]
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
        at = self.vertices if kept is not None else v  # topo's numbering
        if topo is None:  # new vertices: only the count of non-manifold edges compares
            topo = _topology_faces(v, f)
            new_edges = _clean.non_manifold_edge_keys(topo, len(at))
            added = len(new_edges) - self.non_manifold
        else:
            # counted per part, not over the union: one part's lost edges do not pay
            # for another's added ones (gantry's LOD2 lost 150 in its lattice and added
            # 1-4 to each of four members, which the per-visual check then refused).
            # Only the added edges are misses: locking around the original's own (a
            # lattice of welded members has hundreds) changes nothing, and once they
            # were all locked the search gave up
            keys = _clean.non_manifold_edge_keys(topo, len(at))
            edge_part = self.part[keys // len(at)]
            grown = self._per_part(edge_part) - self.part_non_manifold
            added = int(np.maximum(grown, 0).sum())
            new_edges = keys[~_lookup(self.non_manifold_keys, keys)[0] & (grown[edge_part] > 0)]
        if bounded.any() and there <= threshold and back <= tolerance and flips == 0 and added <= 0:
            d_there[bounded] = self._distances(target, index[bounded], cand_keys, decides)
            there = float(d_there.max(initial=0.0))
        else:
            d_there[bounded] = self.bound[index[bounded]]  # upper bounds, all <= threshold
        queries = self.queries[index]
        if threshold is not None:
            bad += [queries[d_there > threshold], own[d_back > threshold]]
            how_far += [d_there[d_there > threshold], d_back[d_back > threshold]]
        if added > 0 and threshold is not None:
            bad.append((at[new_edges // len(at)] + at[new_edges % len(at)]) / 2.0)
            how_far.append(np.full(len(new_edges), np.inf))
        where = np.concatenate(bad) if bad else np.zeros((0, 3))
        self.how_far = np.concatenate(how_far) if how_far else np.zeros(0)
        return Simplified(v, f, kept, max(there, back), flips, added), where

    def _distances(self, target: SurfaceDistance, index: np.ndarray, cand_keys: np.ndarray | None,
                   exact_above: float) -> np.ndarray:
        """Distances from the original query points `index` to `target` (exact above
        `exact_above` and at the maximum, see SurfaceDistance.nearest), kept with the
        face each was measured to (as bounds for later candidates)."""
        d, face = target.nearest(self.queries[index], exact_above)
        if cand_keys is not None and len(index):
            self.bound[index], self.bound_key[index] = d, cand_keys[face]
        return d


def _oriented_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """(m,) int64 key of each face's corners in winding order, rotated to start at the
    smallest (the same oriented face however it is rotated), or None past 63 bits."""
    if n_vertices >= 2_000_000:
        return None
    f = np.asarray(faces, dtype=np.int64)
    start = np.argmin(f, axis=1)
    rows = np.arange(len(f))
    a, b, c = f[rows, start], f[rows, (start + 1) % 3], f[rows, (start + 2) % 3]
    return (a * n_vertices + b) * n_vertices + c


def _lookup(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _face_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """(m,) int64 key of each face's vertex set (winding and rotation ignored: the same
    surface), or None when the keys would not fit in 63 bits."""
    if n_vertices >= 2_000_000:
        return None
    f = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (f[:, 0] * n_vertices + f[:, 1]) * n_vertices + f[:, 2]


def _search_meshopt(judge: _Judge, budget: float, iterations: int,
                    ceiling: Callable[[], int | None] = lambda: None,
                    locked: np.ndarray | None = None) -> tuple[Simplified | None, list[int]]:
    """Coarsest meshoptimizer result whose measurement is within budget (None if no
    round finds one), and the face count of every round's simplification.

    meshoptimizer's error is an area-weighted MEAN of squared distances to the planes
    around a vertex, so a vertex may slide off a narrow face (a bevel, a fin's rim, a
    shed's edge) at a cost the wide faces beside it average away: the measured
    Hausdorff distance runs far above the target there, and only there. So: simplify
    at the budget, measure, lock the original vertices around every point that
    misses (too far either way, a flipped face, a new non-manifold edge) and simplify
    again; each round keeps the reduction everywhere else. Every level starts with no
    lock: a finer level's trouble spots, locked for a coarser budget too, kept up to
    2.6 times the faces the coarser budget needs (12 of the 18 sample assets came out
    coarser at LOD2 or LOD3 without them, one finer).

    `ceiling()`: the finer level's face count, None while it is not known. A round
    that does not beat it ends the search with nothing (later rounds only lock more or
    lower the target). The result is the same as searching without it and applying
    `_under_ceiling` after, so a search side by side with the finer level's can learn
    it midway (`_Board`) and stop as early as it would have one after the other.
    `locked: (n,) bool`: vertices locked from the first round (a piece's border)."""
    n = len(judge.faces)
    lock = np.zeros(len(judge.vertices), dtype=bool) if locked is None else locked.copy()
    s = budget
    rounds: list[int] = []
    widespread = np.zeros((0, 3))  # misses left unlocked while a lower target was tried
    for round_ in range(iterations):
        v, f = _meshopt(judge.vertices, judge.faces, 0, s, lock)
        rounds.append(len(f))
        top = ceiling()
        if top is not None and len(f) >= top:
            return None, rounds
        if len(f) >= NO_GAIN * n:
            if len(widespread) == 0:
                break  # the mesh is as simple as this error allows: nothing to gain
            # a lower target gained nothing either (a wire mesh in one plane: its
            # quadrics see no error, so it goes all or nothing): lock the misses instead
            lock[judge.near_vertices(widespread, 4)] = True
            widespread, s = np.zeros((0, 3)), budget
            continue
        r, where = judge.measure(v, f, np.arange(len(v)), budget, threshold=LOCK_SHARE * budget)
        if r.valid and r.error_m <= budget:
            # the first pass is the coarsest: later rounds only lock more vertices or
            # lower the target, and both keep more faces
            return r, rounds
        if not np.isfinite(r.error_m):  # everything collapsed away
            s /= 4.0
            continue
        if len(where) > WIDESPREAD * len(judge.queries):
            # misses everywhere (a smooth surface): the target itself is too coarse;
            # lock only around what went badly wrong (a small part collapsed away).
            # When that too is everywhere (the whole mesh collapsed), a lock would
            # freeze most of the mesh at full detail (the test insulator at 5 cm kept
            # 6,284 of its 15,072 faces; a few hundred now): the lower target alone
            s /= 2.0
            widespread = where
            where = where[judge.how_far > 2.0 * budget]
            if len(where) == 0 or len(where) > WIDESPREAD * len(judge.queries):
                continue
        new = _lock_around(judge, lock, where, round_)
        if len(new) == 0 or lock[new].all():
            break
        lock[new] = True
    return None, rounds


def _lock_around(judge: _Judge, lock: np.ndarray, where: np.ndarray, round_: int) -> np.ndarray:
    """The original vertices to lock around the misses `where: (p, 3)`. Around a miss
    whose nearest vertex a lock already holds, a neighbourhood doubling each round (4,
    8, 16, ... up to LOCK_NEIGHBOURS); around one where nothing is locked yet, one
    doubling every third round. Widening around every miss by the round froze fresh
    misses' whole neighbourhoods (gantry's LOD2: 10,305 faces with 63 flips became
    37,662; 28,423 with 4 vertices around a fresh miss); 4 in every round made slow
    searches slower still (power_transformer's LOD3 ran out of rounds)."""
    if len(where) == 0:
        return np.zeros(0, dtype=np.int64)
    again = lock[judge.nearest_vertex(where)]
    return np.union1d(judge.near_vertices(where[~again], min(4 << (round_ // 3), LOCK_NEIGHBOURS)),
                      judge.near_vertices(where[again], min(4 << round_, LOCK_NEIGHBOURS)))


def _beats(found: int | None, top: int, ceiling: int) -> bool:
    """Whether a search that found `found` faces (None: nothing), its largest round
    having `top`, gives a level under `ceiling`: the one rule of `_search_levels`
    and the board (a round at or over the ceiling would have ended the search)."""
    return found is not None and top < ceiling and found < ceiling


def _under_ceiling(best: Simplified | None, rounds: list[int], ceiling: int) -> Simplified | None:
    """A search's result as `ceiling` would have cut it short (see _search_meshopt)."""
    found = None if best is None else len(best.faces)
    return best if _beats(found, max(rounds, default=0), ceiling) else None


def _search_levels(judge: _Judge, budgets, iterations: int, faces: int, locked: np.ndarray | None = None,
                   side_by_side: bool = True) -> list[Simplified | None]:
    """Each budget's search result (ascending budgets; None: no coarser mesh than the
    finer level's, whose face count is the ceiling). Alone, the levels are searched
    one after the other, each stopping at its ceiling; with cores to spare, side by
    side, each learning its ceiling from the board as soon as the finer levels are
    done, and the ceilings applied again after. The results are the same.
    `locked`: see _search_meshopt; `side_by_side=False`: one after the other here."""
    searched = [i for i, b in enumerate(budgets) if b > 0]
    outcomes: dict[int, tuple[Simplified | None, list[int]]] = {i: (None, []) for i, b in enumerate(budgets) if b <= 0}
    if len(searched) > 1 and side_by_side and cores_to_spare():
        board = _Board(len(budgets), faces)
        for i, outcome in outcomes.items():
            board.publish(i, *outcome)  # no budget, no search: it passes its ceiling on

        def search(i: int):
            outcome = _search_meshopt(judge, budgets[i], iterations, lambda: board.ceiling(i), locked)
            board.publish(i, *outcome)
            return outcome

        # every level in a process of its own, more processes than cores: a level that
        # waits on nothing keeps a core busy, where one after the other in a child the
        # coarser levels queued behind each other (circuit_breaker's geometry: 3.6 s
        # -> 3.0-3.4 s on 2 cores); a coarser level that cannot beat a finer one still
        # learns so at the finer one's end
        outcomes.update(zip(searched, spread([lambda i=i: search(i) for i in searched])))
    out, ceiling = [], faces
    for i, budget in enumerate(budgets):
        outcome = outcomes[i] if i in outcomes else _search_meshopt(judge, budget, iterations, lambda: ceiling,
                                                                     locked)
        best = _under_ceiling(*outcome, ceiling)
        if best is not None:
            ceiling = len(best.faces)
        out.append(best)
    return out


class _Board:
    """The levels' search outcomes as they finish, in memory shared with the forked
    processes searching the others. One int64 per level, UNFINISHED until published,
    then (largest round's face count << 32) | (result's face count + 1, 0 for none):
    one aligned word, so a reader never sees half an outcome."""

    UNFINISHED = -1

    def __init__(self, levels: int, faces: int):
        import mmap

        self.faces = faces
        self._memory = mmap.mmap(-1, 8 * levels)  # anonymous and shared: forks see one board
        self.table = np.frombuffer(self._memory, dtype=np.int64)
        self.table[:] = self.UNFINISHED

    def publish(self, level: int, best: Simplified | None, rounds: list[int]) -> None:
        found = 0 if best is None else len(best.faces) + 1
        self.table[level] = (max(rounds, default=0) << 32) | found

    def ceiling(self, level: int) -> int | None:
        """Level `level`'s ceiling as `_search_levels` will apply it, None while a finer
        searched level is unfinished."""
        ceiling = self.faces
        for word in self.table[:level].tolist():
            if word == self.UNFINISHED:
                return None
            top, found = word >> 32, (word & 0xFFFFFFFF) - 1
            if _beats(found if found >= 0 else None, top, ceiling):
                ceiling = found
        return ceiling


def _search_count(judge: _Judge, budget: float, iterations: int, method: str) -> Simplified | None:
    """Smallest triangle count (bisected in log space) whose result measures within budget."""
    run = _pymeshlab if method == "pymeshlab" else _fast
    best, lo, hi = None, 4, len(judge.faces)  # lo: too coarse (or unknown); hi: acceptable
    target = max(4, len(judge.faces) // 10)
    for _ in range(iterations):
        v, f = run(judge.vertices, judge.faces, target)
        r = judge(v, f, None, budget)
        if r.valid and r.error_m <= budget:
            if best is None or len(r.faces) < len(best.faces):
                best = r
            hi = target
        else:
            lo = target
        if hi <= lo * 1.15:
            break
        target = int(round(math.sqrt(lo * hi)))
    return best


def simplify_checked(vertices: np.ndarray, faces: np.ndarray, budget_m: float, method: str = "meshoptimizer",
                     iterations: int = ITERATIONS, samples: int = MEASURE_SAMPLES, normals: np.ndarray | None = None,
                     parts: np.ndarray | None = None) -> Simplified:
    """The coarsest checked simplification of a CLEAN mesh within `budget_m` (metres):
    `simplify_levels` with one budget."""
    return simplify_levels(vertices, faces, (budget_m,), method, iterations, samples, normals, parts)[0]


class Memo(Protocol):
    """Where results are kept between runs, by key (builder.memo.ArrayMemo): arrays
    in, the same arrays out, or None for a key it does not hold. The LOD search keeps
    its levels in one, the per-part checks their findings in another."""

    def get(self, key: str) -> dict[str, np.ndarray] | None: ...

    def put(self, key: str, arrays: dict[str, np.ndarray]) -> None: ...


def simplify_levels(vertices: np.ndarray, faces: np.ndarray, budgets_m, method: str = "meshoptimizer",
                    iterations: int = ITERATIONS, samples: int = MEASURE_SAMPLES, normals: np.ndarray | None = None,
                    parts: np.ndarray | None = None, memo: Memo | None = None) -> list[Simplified]:
    """The coarsest checked simplification of a CLEAN mesh within each of the
    ascending `budgets_m` (metres), one per budget, each no finer than the one before.

    vertices: (n, 3) float64, faces: (m, 3) int. When nothing coarser passes, the finer
    level (at first the input itself, error 0) comes back: a level never exceeds its
    budget and never vanishes. meshoptimizer runs on the position-welded surface (CAD
    patches and UV/normal seams duplicate vertices; unwelded, every seam is a border
    the simplifier tears open), then each new corner goes back to the original vertex
    of the same place whose normal (`normals: (n, 3)`, optional) best matches the new
    face, so crisp edges and UVs survive. `parts: (n,)` ids keep separate parts from
    welding together. The mesh is welded and indexed once for all budgets, which are
    searched side by side when the worker has cores to spare (`_search_levels`).

    A welded mesh of more than 2 * PIECE_FACES faces is searched in pieces of at most
    PIECE_FACES (`_pieces`: whole parts where it has several), each with its share of
    the query points and its border locked, and the pieces' levels joined
    (`_joined_levels`). Each piece has its own memo keys, so a vertex moved in one
    place searches one piece again. Against one search over every mesh (the 17 built
    sample assets, one core): 38.6 -> 32.5 s, and faces at LOD1, LOD2 and LOD3 -16 %,
    -4 % and -9 %: fewer rounds fix one piece's misses than the whole's, and a round
    measures as many points. Splitting every mesh over PIECE_FACES cost lightning_mast
    (30,608 faces) 9,316 -> 21,693 faces at every level: a piece judges non-manifold
    edges per part within it, where the whole let one region of a visual pay for
    another.

    `memo` (meshoptimizer only): each level's search result is kept there under the
    hash of everything it depends on (the welded piece, its locked border, samples,
    iterations, its budget and the finer level's face count, its ceiling), and the
    levels it holds are not searched again: an edit of the coarsest budget searches
    that level alone. The results are the same with or without it.
    """
    if method not in METHODS:
        raise ValueError(f"unknown simplifier {method!r}; one of {METHODS}")
    vertices = np.asarray(vertices, dtype=np.float64)
    local, centre = _clean.centred(vertices)
    faces = np.asarray(faces, dtype=np.int64)
    prev = Simplified(vertices, faces, np.arange(len(vertices)), 0.0, 0, 0)
    if len(faces) < MIN_FACES:
        return [prev] * len(budgets_m)
    out = []
    if method != "meshoptimizer":
        judge = _Judge(local, faces, samples)
        for budget in budgets_m:
            best = _search_count(judge, budget, iterations, method) if budget > 0 else None
            if best is not None and len(best.faces) < len(prev.faces):
                prev = replace(best, vertices=best.vertices + centre)
            out.append(prev)
        return out

    attrs = [] if parts is None else [(np.asarray(parts, dtype=np.float64)[:, None], 0.5)]
    rep = _clean.weld_map(local, _clean.weld_tolerance(local), attrs)
    first, welded_index = np.unique(rep, return_inverse=True)
    welded, welded_faces = local[first], welded_index[faces]
    welded_parts = None if parts is None else np.asarray(parts, dtype=np.int64)[first]
    pieces = _pieces(vertices[first], welded_faces, PIECE_FACES)
    if len(pieces) == 1:
        searches = [_PieceSearch(welded, welded_faces, welded_parts, None, len(faces), samples, iterations,
                                 budgets_m, memo)]
    else:
        searches = _piece_searches(vertices[first], welded_faces, welded_parts, pieces, samples, iterations,
                                   budgets_m, memo)
    _run_searches(searches, iterations)
    levels = searches[0].levels if len(pieces) == 1 else _joined_levels(welded, welded_faces, welded_parts,
                                                                         pieces, searches)
    for level in levels:
        if level is not None:
            corners = _original_corners(level.corners, welded_index, local, normals)
            used, new_faces = _clean.compact(corners, len(vertices))
            prev = Simplified(vertices[used], new_faces, used, level.error_m, level.flipped, level.non_manifold_added)
        out.append(prev)
    return out


@dataclass(frozen=True)
class _Level:
    """What a level's search leaves for simplify_levels: the faces on the welded
    vertices (j, 3), the measured error and the checks' counts."""

    corners: np.ndarray
    error_m: float
    flipped: int
    non_manifold_added: int


def _ceiling_after(levels: list[_Level | None], faces: int) -> int:
    """The face count a level after `levels` must beat (_search_levels' rule)."""
    for level in reversed(levels):
        if level is not None:
            return len(level.corners)
    return faces


class _LevelKeys:
    """Memo keys of a mesh's levels: one hash of the searched mesh (its parts and its
    locked vertices, if any) and the search's settings, then per level its budget and
    its ceiling (known once the finer levels are)."""

    def __init__(self, welded: np.ndarray, welded_faces: np.ndarray, parts: np.ndarray | None, samples: int,
                 iterations: int, budgets, faces: int, locked: np.ndarray | None = None):
        # the parts too: the checks count each part's non-manifold edges apart
        arrays = (welded, welded_faces, parts) if locked is None else (welded, welded_faces, parts, locked)
        self.mesh = sha256_arrays(*arrays)
        self.search = (int(samples), int(iterations))
        self.budgets, self.faces = [float(b) for b in budgets], faces

    def next(self, levels: list[_Level | None]) -> str:
        """The key of the level after `levels`."""
        budget = self.budgets[len(levels)]
        return sha256_json([self.mesh, self.search, repr(budget), _ceiling_after(levels, self.faces)])


def _level_arrays(level: _Level | None) -> dict[str, np.ndarray]:
    if level is None:
        return {"found": np.zeros(1, dtype=np.bool_)}
    return {"found": np.ones(1, dtype=np.bool_), "corners": np.asarray(level.corners, dtype=np.int64),
            "error_m": np.array([level.error_m], dtype=np.float64),
            "counts": np.array([level.flipped, level.non_manifold_added], dtype=np.int64)}


def _recall(memo: Memo, keys: _LevelKeys, n_welded: int) -> list[_Level | None]:
    """The leading levels the memo holds, in order; stops at the first it lacks (a
    damaged entry counts as lacking: it is searched again and replaced)."""
    levels: list[_Level | None] = []
    while len(levels) < len(keys.budgets):
        arrays = memo.get(keys.next(levels))
        if arrays is None:
            break
        try:
            if not bool(arrays["found"][0]):
                levels.append(None)
                continue
            corners = arrays["corners"]
            if corners.dtype != np.int64 or corners.ndim != 2 or corners.shape[1] != 3 or not len(corners) \
                    or corners.min() < 0 or corners.max() >= n_welded:
                break
            flipped, added = (int(c) for c in arrays["counts"][:2])
            levels.append(_Level(corners, float(arrays["error_m"][0]), flipped, added))
        except (TypeError, KeyError, IndexError, ValueError):
            break
    return levels


class _PieceSearch:
    """One piece's levels: those the memo holds, then the search of the rest.
    `parts`: the piece's vertices' part ids (None: one part); `locked`: its border
    (None for a whole mesh); `ceiling`: the face count its first level must beat."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, locked: np.ndarray | None,
                 ceiling: int, samples: int, iterations: int, budgets, memo: Memo | None):
        self.vertices, self.faces, self.parts, self.locked = vertices, faces, parts, locked
        self.ceiling, self.samples, self.budgets, self.memo = ceiling, samples, tuple(budgets), memo
        self.keys = None if memo is None else _LevelKeys(vertices, faces, parts, samples, iterations, budgets,
                                                         ceiling, locked)
        self.levels: list[_Level | None] = [] if memo is None else _recall(memo, self.keys, len(vertices))

    @property
    def done(self) -> bool:
        return len(self.levels) == len(self.budgets)

    def search(self, iterations: int, side_by_side: bool) -> list[_Level | None]:
        """The levels the memo lacks (not kept yet: see keep)."""
        judge = _Judge(self.vertices, self.faces, self.samples, self.parts)
        found = _search_levels(judge, self.budgets[len(self.levels):], iterations,
                               _ceiling_after(self.levels, self.ceiling), self.locked, side_by_side)
        return [None if b is None else _Level(b.kept[b.faces], b.error_m, b.flipped, b.non_manifold_added)
                for b in found]

    def keep(self, searched: list[_Level | None]) -> None:
        for level in searched:
            if self.memo is not None:
                self.memo.put(self.keys.next(self.levels), _level_arrays(level))
            self.levels.append(level)


def _run_searches(searches: list[_PieceSearch], iterations: int) -> None:
    """Search what the memo lacks. A single piece to search (a whole mesh, or the one
    piece an edit touched) searches its levels side by side; several go to as many
    bins as the worker has cores, largest first to the lightest bin, each bin's
    pieces one after the other in a process of its own. The memo is written here, so
    its counts are this process's."""
    todo = [s for s in searches if not s.done]
    if len(todo) <= 1:
        for search in todo:
            search.keep(search.search(iterations, side_by_side=True))
        return
    bins: list[list[_PieceSearch]] = [[] for _ in range(max(1, min(core_share(), len(todo))))]
    load = [0] * len(bins)
    for search in sorted(todo, key=lambda s: -len(s.faces)):  # stable: ties keep the pieces' order
        k = load.index(min(load))
        bins[k].append(search)
        load[k] += len(search.faces)
    results = spread([lambda b=b: [s.search(iterations, side_by_side=False) for s in b] for b in bins])
    for b, found in zip(bins, results):
        for search, levels in zip(b, found):
            search.keep(levels)


def _pieces(vertices: np.ndarray, faces: np.ndarray, limit: int) -> list[np.ndarray]:
    """The faces (ascending ids) of each piece of at most `limit` faces that a welded
    mesh (`vertices` in the link frame) is searched in: split in two along the
    longest axis of the face centroids, again and again, between connected parts where
    there are several (by their centroids) and through the one part otherwise.

    A split is at the median face centroid rounded to a grid (_cut), not at an exact
    face count: the benchmark's edit of circuit_breaker, one vertex moved 0.1 mm,
    makes 96 faces the clean step dropped as degenerate a surface again, and cuts at
    the middle count moved all four pieces of that part and four more (24 of 33
    levels searched again). Now a vertex moved, or a few faces more or less, in one
    place changes the piece there, and the other pieces' levels come from the memo.

    A mesh of up to two pieces' worth is not split: halving an edit's search was not
    worth lightning_mast's loss (see simplify_levels), even against post_insulator's
    and surge_arrester's gains of 984 and 3,070 faces at LOD1."""
    if len(faces) <= 2 * limit:
        return [np.arange(len(faces))]
    from scipy import sparse
    from scipy.sparse import csgraph

    n = len(vertices)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    graph = sparse.coo_matrix((np.ones(len(edges), dtype=np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    # parts are welded apart (simplify_levels), so no component spans two of them
    _, component = csgraph.connected_components(graph, directed=False)
    part = component[faces[:, 0]]
    centroids = vertices[faces].mean(axis=1)
    out: list[np.ndarray] = []
    stack = [np.arange(len(faces))]
    while stack:
        ids = stack.pop()
        if len(ids) <= limit:
            out.append(ids)
            continue
        c = centroids[ids]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        x = c[:, axis]
        cut = _cut(x)
        names, inverse, counts = np.unique(part[ids], return_inverse=True, return_counts=True)
        if len(names) > 1:
            centre = np.bincount(inverse, weights=x) / counts
            left = centre < cut
            if left.all() or not left.any():  # one part holds the median: cut by count
                order = np.lexsort((names, centre))
                before = np.cumsum(counts[order])[:-1]  # faces left of each possible cut
                left = np.zeros(len(names), dtype=bool)
                left[order[:int(np.argmin(np.abs(before - len(ids) / 2.0))) + 1]] = True
            left = left[inverse]
        else:
            left = x < cut
            if left.all() or not left.any():
                left = np.zeros(len(ids), dtype=bool)
                left[np.lexsort((ids, x))[:len(ids) // 2]] = True
        stack += [ids[~left], ids[left]]  # the left half is taken next: pieces in axis order
    return out


def _cut(x: np.ndarray) -> float:
    """Where to split values `x` (face centroids along an axis): their median, rounded
    to a power-of-two grid of 1/16 to 1/32 of their extent, so that a few values more,
    fewer or moved move it only when the median crosses a grid line."""
    extent = float(x.max() - x.min())
    median = float(np.median(x))
    if extent <= 0.0:
        return median
    step = 2.0 ** math.floor(math.log2(extent / 16.0))
    return math.floor(median / step + 0.5) * step


def _piece_searches(vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, pieces: list[np.ndarray],
                    samples: int, iterations: int, budgets, memo: Memo | None) -> list[_PieceSearch]:
    """A search per piece of a welded mesh (vertices (n, 3) as authored, faces (m, 3)):
    its own vertices, centred on themselves (its memo keys hold nothing of the
    others), the vertices it shares with another piece locked so that the pieces'
    levels still meet, and query points in proportion to its faces (about the
    whole's density, _piece_density: the whole's 20,000 for every piece made the
    search of the 18 sample assets 44 % slower)."""
    density = _piece_density(len(faces), samples)
    shared = np.zeros(len(vertices), dtype=np.int64)
    for ids in pieces:
        shared[np.unique(faces[ids])] += 1
    searches = []
    for ids in pieces:
        used, local_faces = _clean.compact(faces[ids], len(vertices))
        local, _ = _clean.centred(vertices[used])
        share = max(1, round(density * len(ids)))
        # the piece's own part numbering: a visual added elsewhere leaves its key alone
        own_parts = None if parts is None else np.unique(parts[used], return_inverse=True)[1]
        searches.append(_PieceSearch(local, local_faces, own_parts, shared[used] > 1, len(ids), share, iterations,
                                     budgets, memo))
    return searches


def _piece_density(faces: int, samples: int) -> float:
    """Query points per face for the pieces of a mesh of `faces` faces: the whole's
    (_Judge: SAMPLES_PER_FACE, at most `samples` in all), rounded down to a quarter
    octave, so that a few faces more elsewhere leave a piece's count, and its memo
    keys, alone."""
    whole = min(float(SAMPLES_PER_FACE), samples / max(faces, 1))
    return 2.0 ** (math.floor(4.0 * math.log2(whole)) / 4.0)


def _joined_levels(vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, pieces: list[np.ndarray],
                   searches: list[_PieceSearch]) -> list[_Level | None]:
    """The pieces' levels as levels of the whole (on its vertex numbering): a piece
    with no level of its own at a budget keeps its finer one. A level's error is the
    largest piece's (each piece's simplification is within it of its original, so
    the whole is within it of the whole, both ways). Where a part was cut in two, each
    side may make a face on a border edge that is manifold on its own side: such a
    level gives those pieces their finer levels back until no part has more
    non-manifold edges than as authored. None: no piece has a coarser level there."""
    # `vertices` is simplify_levels' weld already (per part): welding it again, as the
    # judge does its unwelded inputs, would map every vertex to itself
    part = np.zeros(len(vertices), np.int64) if parts is None else np.unique(parts, return_inverse=True)[1]
    allowed = _part_non_manifold(part, faces)[0]
    owners = [_clean.compact(faces[ids], len(vertices))[0] for ids in pieces]
    finer = [faces[ids] for ids in pieces]  # each piece's current level on the whole's vertices
    finer_error = [0.0] * len(pieces)
    out: list[_Level | None] = []
    for i in range(len(searches[0].budgets)):
        chosen = [(used[s.levels[i].corners], s.levels[i].error_m) if s.levels[i] is not None else None
                  for used, s in zip(owners, searches)]
        while True:
            corners = [c[0] if c is not None else f for c, f in zip(chosen, finer)]
            bad = _added_non_manifold(part, np.concatenate(corners), allowed)
            piece_of_face = np.repeat(np.arange(len(pieces)), [len(c) for c in corners])
            culprits = {int(k) for k in piece_of_face[bad]} & {k for k, c in enumerate(chosen) if c is not None}
            if not culprits:
                break  # none added, or only by the finer levels themselves: nothing coarser to give back
            for k in culprits:
                chosen[k] = None
        if all(c is None for c in chosen):
            out.append(None)
            continue
        for k, c in enumerate(chosen):
            if c is not None:
                finer[k], finer_error[k] = c
        flipped = sum(s.levels[i].flipped for s, c in zip(searches, chosen) if c is not None)
        out.append(_Level(np.concatenate(finer), max(finer_error), flipped, 0))
    return out


def _part_non_manifold(part: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(how many non-manifold edges each part has (parts,), their keys) of `faces` on
    welded vertices whose parts are `part: (n,)`, as _Judge counts them."""
    n = len(part)
    keys = _clean.non_manifold_edge_keys(faces, n)
    return np.bincount(part[keys // n], minlength=int(part.max(initial=0)) + 1), keys


def _added_non_manifold(part: np.ndarray, faces: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Ids of the faces on the non-manifold edges of the parts that have more such
    edges than `allowed` (per part) in `faces`."""
    counts, keys = _part_non_manifold(part, faces)
    grown = counts - allowed
    if not (grown > 0).any():
        return np.zeros(0, dtype=np.int64)
    n = len(part)
    keys = keys[grown[part[keys // n]] > 0]
    face_edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    on_bad = np.isin(face_edges[:, 0] * n + face_edges[:, 1], keys)
    return np.unique(np.nonzero(on_bad)[0] % len(faces))


def _original_corners(welded_faces: np.ndarray, welded_index: np.ndarray, vertices: np.ndarray,
                      normals: np.ndarray | None) -> np.ndarray:
    """(m, 3) faces on welded vertices -> faces on original vertices: per corner, the
    original vertex at that place whose normal agrees best with the new face's."""
    order = np.argsort(welded_index, kind="stable")
    starts = np.searchsorted(welded_index[order], np.arange(welded_index.max() + 1))
    counts = np.bincount(welded_index, minlength=len(starts))
    corners = order[starts[welded_faces]]  # the first original of each welded vertex
    if normals is None or counts.max() == 1:
        return corners
    face_n = face_normals(vertices, corners)
    best = np.einsum("kj,kcj->kc", face_n, normals[corners])
    for j in range(1, int(counts.max())):
        has = counts[welded_faces] > j
        cand = order[np.minimum(starts[welded_faces] + j, len(order) - 1)]
        score = np.einsum("kj,kcj->kc", face_n, normals[cand])
        better = has & (score > best)
        corners = np.where(better, cand, corners)
        best = np.where(better, score, best)
    return corners


def simplify(vertices: np.ndarray, faces: np.ndarray, target_error_m: float,
             method: str = "meshoptimizer", samples: int = MEASURE_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """Coarsest mesh within `target_error_m` measured two-sided Hausdorff distance.

    vertices: (n, 3) float64, faces: (m, 3) int. Welds and cleans first (pymeshlab
    would crash on degenerate faces; welding removes most meshoptimizer stalls).
    Returns (vertices (k, 3) float64, faces (j, 3) int64).
    """
    mesh = _clean.clean_mesh(ir.Mesh(vertices, faces))
    r = simplify_checked(mesh.vertices, mesh.faces, target_error_m, method, samples=samples)
    return r.vertices, r.faces


# --- the step -------------------------------------------------------------------


@dataclass(frozen=True)
class LodOptions:
    """budgets_m: two-sided Hausdorff budget per level (LOD1, LOD2, ...), ascending;
    method: one of METHODS; iterations: simplify+measure rounds per level at most;
    samples: area-weighted samples per measurement (see metrics for the accuracy)."""

    budgets_m: tuple[float, ...] = (0.005, 0.02, 0.08)
    method: str = "meshoptimizer"
    iterations: int = ITERATIONS
    samples: int = 20_000


def frozen_visuals(asset: ir.Asset) -> set[str]:
    """Names of visuals that keep their mesh at every LOD: shape keys or a state binding."""
    bound = {b.target for b in asset.bindings}
    return {v.name for _, v in asset.visuals() if v.name in bound or v.mesh.shape_keys}


def _lod_mesh(mesh: ir.Mesh, r: Simplified) -> ir.Mesh:
    if r.kept is None:  # new vertex positions: attributes are not transferred
        return ir.Mesh(r.vertices, r.faces)
    return ir.Mesh(
        r.vertices, r.faces,
        normals=None if mesh.normals is None else mesh.normals[r.kept],
        uvs=None if mesh.uvs is None else mesh.uvs[r.kept],
    )


def lod_chain(options: LodOptions = LodOptions(), memo: Memo | None = None,
              checked: Memo | None = None) -> Callable[[ir.Asset], ir.Asset]:
    """Step: Visual.lods = (authored, LOD1, ..., LODk) and Asset.lods = LodInfo for
    levels 0..k (level 0: the authored meshes, budget and error 0).

    With meshoptimizer the free visuals of a link are simplified together, in the link
    frame: CAD-like assets are hundreds of small parts, and one search over their union
    (over each piece of it, for a large one: see simplify_levels) costs one
    measurement instead of hundreds. meshoptimizer collapses only along edges and
    keeps the original vertices, so every new face belongs to one part and the result
    splits back per visual exactly. Other methods move vertices and run per visual. A
    level's error is the measured two-sided Hausdorff distance of the union (the
    largest piece's, for one searched in pieces). Frozen visuals (shape keys, state
    bindings) repeat their Mesh object at every level; a part that would vanish keeps
    its previous level's mesh, so nothing disappears. `memo`: see simplify_levels;
    `checked`: the memo of the per-part checks (validate.checks.mesh_findings).
    """
    budgets = tuple(float(b) for b in options.budgets_m)
    if list(budgets) != sorted(budgets) or any(b <= 0 for b in budgets):
        raise ValueError("LOD budgets must be positive and ascending")
    if options.method not in METHODS:
        raise ValueError(f"unknown simplifier {options.method!r}; one of {METHODS}")

    def step(asset: ir.Asset) -> ir.Asset:
        frozen = frozen_visuals(asset)
        errors = np.zeros(len(budgets))
        links = []
        for link in asset.links:
            chains: dict[str, list[ir.Mesh]] = {}
            free = []
            for vis in link.visuals:
                if vis.name in frozen or vis.mesh.triangle_count == 0:
                    chains[vis.name] = [vis.mesh] * (len(budgets) + 1)
                else:
                    _check_clean(asset, vis)
                    free.append(vis)
            groups = [free] if options.method == "meshoptimizer" else [[v] for v in free]
            for group in (g for g in groups if g):
                lods, errs = _group_chain(group, budgets, options, linear_scale(link.pose), memo, checked)
                chains.update(lods)
                errors = np.maximum(errors, errs)
            visuals = [replace(v, lods=tuple(chains[v.name])) for v in link.visuals]
            links.append(replace(link, visuals=tuple(visuals)))
        out = asset.with_(links=tuple(links))
        infos = [ir.LodInfo(0, 0.0, 0.0, out.triangle_count(0))]
        infos += [ir.LodInfo(i + 1, b, float(errors[i]), out.triangle_count(i + 1)) for i, b in enumerate(budgets)]
        return out.with_(lods=tuple(infos))

    return step


def _group_chain(group: list[ir.Visual], budgets, options: LodOptions, link_scale: float,
                 memo: Memo | None = None, checked: Memo | None = None):
    """LOD chains of visuals simplified as one mesh in their link's frame.
    Returns ({visual name: [mesh per level]}, errors per level in the model frame)."""
    poses = [v.pose for v in group]
    parts = [(np.c_[v.mesh.vertices, np.ones(len(v.mesh.vertices))] @ p.T)[:, :3] for v, p in zip(group, poses)]
    offsets = np.cumsum([0] + [len(p) for p in parts])
    vertices = np.concatenate(parts)
    faces = np.concatenate([v.mesh.faces.astype(np.int64) + o for v, o in zip(group, offsets[:-1])])
    rotations = [p[:3, :3] for p in poses]
    has_normals = all(v.mesh.normals is not None for v in group)
    normals = np.concatenate([v.mesh.normals @ r.T for v, r in zip(group, rotations)]) if has_normals else None
    parts_id = np.repeat(np.arange(len(group)), np.diff(offsets))
    scale = max(link_scale, 1e-12)
    chains = {v.name: [v.mesh] for v in group}
    errors = np.zeros(len(budgets))
    known: dict = {}  # id(mesh) -> (mesh, its validator error codes, its edge defect counts)
    levels = simplify_levels(vertices, faces, [b / scale for b in budgets], options.method, options.iterations,
                             options.samples, normals=normals, parts=parts_id, memo=memo)
    for i, r in enumerate(levels):
        errors[i] = r.error_m * scale
        if r.faces is faces:
            for v in group:
                chains[v.name].append(v.mesh)
            continue
        if len(group) == 1 and r.kept is None:
            per_visual = {group[0].name: _lod_mesh(group[0].mesh, r)}
        else:
            per_visual = _split(group, offsets, r)
        for v in group:
            finer = chains[v.name][-1]
            mesh = per_visual.get(v.name)
            if mesh is None or mesh.triangle_count >= finer.triangle_count or _adds_errors(finer, mesh, known, checked):
                # a part never vanishes, collapses flat, or grows at a coarser level: it
                # keeps its finer level, whose error is within the finer (smaller) budget
                mesh = finer
                errors[i] = max(errors[i], errors[i - 1] if i else 0.0)
            chains[v.name].append(mesh)
    return chains, errors


def _split(group: list[ir.Visual], offsets: np.ndarray, r: Simplified) -> dict[str, ir.Mesh]:
    """The union's simplification back per visual (meshoptimizer keeps original
    vertices, so every face has one owner); visuals left with no face are absent."""
    owner = np.searchsorted(offsets, r.kept, side="right") - 1
    face_owner = owner[r.faces[:, 0]]
    out = {}
    for k, v in enumerate(group):
        sel = r.faces[face_owner == k]
        if len(sel):
            used, local_faces = _clean.compact(sel, len(r.kept))
            kept = r.kept[used] - offsets[k]
            out[v.name] = _lod_mesh(v.mesh, Simplified(v.mesh.vertices[kept], local_faces, kept, r.error_m, 0, 0))
    return out


def _adds_errors(finer: ir.Mesh, coarser: ir.Mesh, known: dict, checked: Memo | None = None) -> bool:
    """Would the coarser mesh give the validator an error the finer one does not
    have (a cap thinner than the budget collapses into a closed part of no volume), or
    more non-manifold or inconsistently wound edges? The union of a link's visuals is
    judged as a whole while simplifying; this judges each visual on its own.
    `known` caches each mesh's verdict by id, holding the mesh so the id stays its own;
    `checked`: see mesh_findings."""
    from ..validate.checks import edge_defect_counts, mesh_findings

    def verdict(mesh):
        if id(mesh) not in known:
            found = mesh_findings(mesh, "", memo=checked)
            errors = {f.code for f in found if f.severity == "error"}
            edges = edge_defect_counts(mesh) if any(f.code in ("GEOM003", "GEOM004") for f in found) else (0, 0)
            known[id(mesh)] = (mesh, errors, edges)
        return known[id(mesh)][1:]

    (coarse_errors, coarse_edges), (fine_errors, fine_edges) = verdict(coarser), verdict(finer)
    return bool(coarse_errors - fine_errors) or any(c > f for c, f in zip(coarse_edges, fine_edges))


def _check_clean(asset: ir.Asset, vis: ir.Visual) -> None:
    """Refuse what would crash a simplifier, naming the visual (run clean() first)."""
    f = vis.mesh.faces
    _clean.check_finite(vis.mesh.vertices, asset.source, vis.name)
    if len(f) and ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])).any():
        raise UserError(asset.source, vis.name, "mesh has faces with repeated vertices; run the clean step before LODs")
