"""Geometric error metrics: deterministic, sampled two-sided Hausdorff distance.

How it measures (and how accurate it is). For the direction A -> B the query points
are every vertex of A, every face centroid of A, and `samples` points drawn on A's
surface with probability proportional to area (fixed seed: the same meshes always
give the same number). For each query point the distance to B's *surface* is exact
point-triangle distance (Ericson's closest-point regions) to candidate triangles: the
triangles owning the `candidates` nearest of B's face centroids and area-weighted
samples (a cKDTree), then a greedy walk from the best of them across edge neighbours
while the distance decreases (slivers: the nearest sample may sit on a neighbour). Each per-point value is therefore >= the true distance of that
point (it is the exact distance to some triangle of B), and equal to it whenever the
nearest triangle is among the candidates (almost always: B's sample spacing h_B is
far below the distances that matter). The maximum over query points can miss a peak
between query points by at most their spacing: with n_A query points on area S_A the
spacing is about h_A = sqrt(S_A / n_A) (1 mm for a 10 m^2 asset and 10^7 samples,
3 mm at 10^6). Vertices are always included because simplification error peaks at
vertices and along creases, which is where the samples would be sparse otherwise.

Everything is computed relative to the common bounding-box centre in float64, so
coordinates of 10^7 m lose nothing.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

DEFAULT_SAMPLES = 100_000
DEFAULT_CANDIDATES = 2


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) float64 areas of `faces: (m, 3)` over `vertices: (n, 3)`."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) unit normals of `faces` (zero vectors for zero-area faces)."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit area-weighted vertex normals (zero for unused vertices)."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    n = np.cross(b - a, c - a)  # length = twice the area: the weight
    acc = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        np.add.at(acc, faces[:, k], n)
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, length, out=np.zeros_like(acc), where=length > 0)


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """`count` points on the surface, area-weighted, deterministic for a seed.

    Returns points (count, 3) float64 and the face index of each (count,) int64.
    """
    if count <= 0 or len(faces) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    area = triangle_areas(vertices, faces)
    total = area.sum()
    rng = np.random.default_rng(seed)
    if total <= 0:
        face = rng.integers(0, len(faces), count)
    else:
        cdf = np.cumsum(area) / total
        face = np.minimum(np.searchsorted(cdf, rng.random(count), side="right"), len(faces) - 1)
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    u, v, w = 1.0 - s, s * (1.0 - r2), s * r2  # uniform barycentrics
    tri = faces[face]
    pts = u[:, None] * vertices[tri[:, 0]] + v[:, None] * vertices[tri[:, 1]] + w[:, None] * vertices[tri[:, 2]]
    return pts, face.astype(np.int64)


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(k,) exact distances from points p (k, 3) to triangles (a, b, c), each (k, 3).

    Ericson, Real-Time Collision Detection 5.1.5: find the Voronoi region of the
    closest feature (vertex, edge, face) with dot products only, as barycentric
    weights (v, w) of the closest point a + v ab + w ac. Degenerate triangles fall
    back to the nearest of their vertices and edges handled by the same regions.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    ab_ab = np.einsum("ij,ij->i", ab, ab)
    ab_ac = np.einsum("ij,ij->i", ab, ac)
    ac_ac = np.einsum("ij,ij->i", ac, ac)
    # d3..d6 of Ericson from bp = ap - ab, cp = ap - ac
    d3, d4 = d1 - ab_ab, d2 - ab_ac
    d5, d6 = d1 - ab_ac, d2 - ac_ac
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        # later assignments win: go from the least to the most specific test
        e43, e56 = d4 - d3, d5 - d6
        t = np.nan_to_num(e43 / (e43 + e56))
        m = (va <= 0) & (e43 >= 0) & (e56 >= 0)
        v, w = np.where(m, 1.0 - t, v), np.where(m, t, w)
        t = np.nan_to_num(d2 / (d2 - d6))
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        v, w = np.where(m, 0.0, v), np.where(m, t, w)
        m = (d6 >= 0) & (d5 <= d6)
        v, w = np.where(m, 0.0, v), np.where(m, 1.0, w)
        t = np.nan_to_num(d1 / (d1 - d3))
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v, w = np.where(m, t, v), np.where(m, 0.0, w)
        m = (d3 >= 0) & (d4 <= d3)
        v, w = np.where(m, 1.0, v), np.where(m, 0.0, w)
        m = (d1 <= 0) & (d2 <= 0)
        v, w = np.where(m, 0.0, v), np.where(m, 0.0, w)
    diff = ap - ab * v[:, None] - ac * w[:, None]
    dist = np.sqrt(np.einsum("ij,ij->i", diff, diff))
    # a degenerate triangle can leave NaN: its vertices are still a valid upper bound
    bad = ~np.isfinite(dist)
    if bad.any():
        dist[bad] = np.min([np.linalg.norm(p[bad] - x[bad], axis=1) for x in (a, b, c)], axis=0)
    return dist


class SurfaceDistance:
    """Distance queries from points to the surface `vertices: (n, 3)`, `faces: (m, 3)`.

    Build once, query many times (the LOD search measures several candidates against
    the same original). Faces are indexed by size: one cKDTree of face centroids per
    class of circumradius R (powers of 4), so the nearest face's centroid, within
    d + R of a point at distance d, is near the top of its own class's answer however
    large the faces of other parts crowding the point are. `samples` extra
    area-weighted points (owned by their faces) add candidates on large faces.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray | None = None,
                 samples: int = DEFAULT_SAMPLES, seed: int = 1, candidates: int = DEFAULT_CANDIDATES):
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
        self.vertices = np.asarray(vertices, dtype=np.float64) - self.origin
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.candidates = candidates
        if len(self.faces) == 0:
            self.tree = None
            return
        tri = self.vertices[self.faces]
        centroids = tri.mean(axis=1)
        radius = np.linalg.norm(tri - centroids[:, None], axis=2).max(axis=1)
        self.radius = radius
        level = np.floor(np.log(np.maximum(radius, 1e-12)) / np.log(4.0)).astype(np.int64)
        self.classes = []  # (centroid tree, face ids, largest circumradius)
        for lv in np.unique(level):
            ids = np.flatnonzero(level == lv)
            self.classes.append((cKDTree(centroids[ids]), ids, float(radius[ids].max())))
        # samples only where faces are large: small faces are covered by their centroids
        big = radius > np.median(radius) * 4.0
        if samples > 0 and big.any():
            pts, owner = sample_surface(self.vertices, self.faces[big], samples, seed)
            self.points, self.owner = pts, np.flatnonzero(big)[owner]
            self.tree = cKDTree(self.points)
        else:
            self.points, self.owner = centroids[:1], np.zeros(1, dtype=np.int64)
            self.tree = cKDTree(self.points)
        self.neighbours = face_neighbours(self.faces)

    def _distances(self, p: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """(k, c) exact distances from p (k, 3) to candidate faces cand (k, c)."""
        c = cand.shape[1]
        t = self.faces[cand.ravel()]
        pp = np.repeat(p, c, axis=0)
        d = point_triangle_distance(pp, self.vertices[t[:, 0]], self.vertices[t[:, 1]], self.vertices[t[:, 2]])
        return d.reshape(len(p), c)

    def _candidates(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate faces (k, c) of p (k, 3) in the internal frame, the owners of the
        nearest centroids of every size class and of the nearest samples, and their
        exact distances (k, c) (inf where a face cannot be the nearest: its centroid
        is further than its circumradius beyond another candidate's farthest point)."""
        cols, lower, upper = [], [], []
        for tree, ids, _ in self.classes:
            kk = min(self.candidates, len(ids))
            dc, idx = tree.query(p, k=kk, workers=-1)
            f = ids[idx.reshape(len(p), kk)]
            r = self.radius[f]
            dc = dc.reshape(len(p), kk)
            cols.append(f), lower.append(dc - r), upper.append(dc + r)
        kk = min(self.candidates, len(self.points))
        ds, idx = self.tree.query(p, k=kk, workers=-1)
        f = self.owner[idx.reshape(len(p), kk)]
        ds = ds.reshape(len(p), kk)
        cols.append(f), lower.append(ds - 2.0 * self.radius[f]), upper.append(ds)
        cand, lower = np.concatenate(cols, axis=1), np.concatenate(lower, axis=1)
        bound = np.concatenate(upper, axis=1).min(axis=1, keepdims=True)
        test = lower <= bound
        d = np.full(cand.shape, np.inf)
        rows, cols_ = np.nonzero(test)
        t = self.faces[cand[rows, cols_]]
        d[rows, cols_] = point_triangle_distance(p[rows], self.vertices[t[:, 0]], self.vertices[t[:, 1]],
                                                 self.vertices[t[:, 2]])
        return cand, d

    def nearest_faces(self, points: np.ndarray, chunk: int = 100_000, walk: int = 16) -> tuple[np.ndarray, np.ndarray]:
        """Candidate faces (k, c) int64 of `points: (k, 3)` and their exact distances
        (k, c): the owners of the nearest index points, then a greedy walk across edge
        neighbours while that gets closer (at most `walk` steps). The walk finds the
        triangle really holding the closest point when the nearest centroids sit on
        neighbouring slivers; the last column holds the walk's best face."""
        points = np.asarray(points, dtype=np.float64) - self.origin
        cands, dists = [], []
        for start in range(0, len(points), chunk):
            p = points[start:start + chunk]
            cand, d = self._candidates(p)
            rows = np.arange(len(p))
            best = cand[rows, d.argmin(axis=1)]
            best_d = d.min(axis=1)
            active = rows
            for _ in range(walk):
                ring = self.neighbours[best[active]]
                ring = np.where(ring >= 0, ring, best[active][:, None])
                rd = self._distances(p[active], ring)
                j = rd.argmin(axis=1)
                new_d = rd[np.arange(len(active)), j]
                better = new_d < best_d[active] * (1.0 - 1e-12)
                best[active[better]] = ring[better, j[better]]
                best_d[active[better]] = new_d[better]
                active = active[better]
                if len(active) == 0:
                    break
            cands.append(np.concatenate([cand, best[:, None]], axis=1))
            dists.append(np.concatenate([d, best_d[:, None]], axis=1))
        if not cands:
            return np.zeros((0, 1), dtype=np.int64), np.zeros((0, 1))
        return np.concatenate(cands), np.concatenate(dists)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(k,) distances from `points: (k, 3)` (same frame as the constructor's
        vertices). Exact distances to candidate faces, so each value is an UPPER bound
        of the true distance (equal to it for nearly every point; `exact` and
        `max_distance` are exact)."""
        if self.tree is None:
            return np.full(len(points), np.inf)
        return self.nearest_faces(points)[1].min(axis=1)

    def exact(self, points: np.ndarray, upper: np.ndarray | None = None, pairs: int = 2_000_000) -> np.ndarray:
        """(k,) true distances from `points: (k, 3)`. From an upper bound u of a point
        (`upper`, else the candidates'), the nearest face (distance d <= u, circumradius
        R) has its centroid within u + R: every face of a size class whose centroid is
        within u + (the class's largest R) is tested. Classes go from small faces to
        large, each shrinking u for the next."""
        if self.tree is None:
            return np.full(len(points), np.inf)
        p_all = np.asarray(points, dtype=np.float64) - self.origin
        best = (self(points) if upper is None else np.asarray(upper, dtype=np.float64)).copy()
        if len(p_all) == 0:
            return best
        for tree, ids, rmax in self.classes:
            counts = tree.query_ball_point(p_all, best + rmax, workers=-1, return_length=True)
            todo = np.flatnonzero(counts > 0)
            # chunk so the (point, face) pairs stay within `pairs`
            bounds = np.searchsorted(np.cumsum(counts[todo]), np.arange(pairs, counts.sum() + pairs, pairs))
            start = 0
            for stop in np.unique(np.r_[bounds, len(todo)]):
                sel = todo[start:stop]
                start = stop
                if len(sel) == 0:
                    continue
                lists = tree.query_ball_point(p_all[sel], best[sel] + rmax, workers=-1, return_sorted=False)
                lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(sel))
                flat = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(lens.sum()))
                rows = np.repeat(sel, lens)
                t = self.faces[ids[flat]]
                d = point_triangle_distance(p_all[rows], self.vertices[t[:, 0]], self.vertices[t[:, 1]],
                                            self.vertices[t[:, 2]])
                np.minimum.at(best, rows, d)
        return best

    def distances_above(self, points: np.ndarray, threshold: float) -> np.ndarray:
        """(k,) distances from `points: (k, 3)`: exact wherever the true distance exceeds
        `threshold`, an upper bound <= threshold elsewhere (cheap: only points whose
        candidate bound exceeds the threshold are verified)."""
        upper = self(points)
        over = np.flatnonzero(upper > threshold)
        if len(over):
            upper[over] = self.exact(np.asarray(points)[over], upper[over])
        return upper

    def max_distance(self, points: np.ndarray, upper: np.ndarray | None = None) -> float:
        """The largest true distance from `points: (k, 3)` to the surface.

        Candidate distances bound each point from above; points are verified exactly
        in order of their bound until no remaining bound can beat the verified
        maximum. The bounds are nearly always exact, so few points need verifying.
        `upper: (k,)` upper bounds already known (`__call__`, `distances_above`)."""
        if len(points) == 0:
            return 0.0
        if self.tree is None:
            return float("inf")
        points = np.asarray(points, dtype=np.float64)
        upper = self(points) if upper is None else np.asarray(upper, dtype=np.float64)
        order = np.argsort(-upper, kind="stable")
        best, start, batch = 0.0, 0, 256
        while start < len(order) and upper[order[start]] > best:
            idx = order[start:start + batch]
            idx = idx[upper[idx] > best]
            best = max(best, float(self.exact(points[idx], upper[idx]).max()))
            start += batch
            batch *= 4
        return best


def query_points(vertices: np.ndarray, faces: np.ndarray, samples: int = DEFAULT_SAMPLES, seed: int = 0) -> np.ndarray:
    """The points (k, 3) at which a surface is measured: used vertices, area-weighted
    samples, and face centroids when there are fewer faces than samples (a coarse
    mesh deviates most in its face interiors; a fine one is covered by its vertices)."""
    if len(faces) == 0:
        return np.zeros((0, 3))
    used = np.unique(faces.ravel())
    pts, _ = sample_surface(vertices, faces, samples, seed)
    parts = [vertices[used], pts]
    if len(faces) <= samples:
        parts.append(vertices[faces].mean(axis=1))
    return np.concatenate(parts)


def face_neighbours(faces: np.ndarray) -> np.ndarray:
    """(m, 3) int64: the face across each edge (v0v1, v1v2, v2v0), -1 on a border.
    On a non-manifold edge one of the other faces is given."""
    m = len(faces)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    key = edges[:, 0] * (int(edges.max(initial=0)) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    out = np.full(3 * m, -1, dtype=np.int64)
    same = np.flatnonzero(ks[1:] == ks[:-1])  # consecutive half-edges of one edge
    out[order[same]] = order[same + 1] // 3
    out[order[same + 1]] = order[same] // 3
    return out.reshape(m, 3)


def one_sided_hausdorff(src_v: np.ndarray, src_f: np.ndarray, dst: SurfaceDistance,
                        samples: int = DEFAULT_SAMPLES, seed: int = 0) -> float:
    """max over the surface (src_v (n, 3), src_f (m, 3)) of the distance to `dst`."""
    pts = query_points(np.asarray(src_v, dtype=np.float64), np.asarray(src_f, dtype=np.int64), samples, seed)
    if len(pts) == 0:
        return 0.0
    return dst.max_distance(pts)


def hausdorff(va: np.ndarray, fa: np.ndarray, vb: np.ndarray, fb: np.ndarray,
              samples: int = DEFAULT_SAMPLES, seed: int = 0) -> float:
    """Two-sided Hausdorff distance (m) between mesh A (va (n, 3), fa (m, 3)) and B.

    Deterministic; accuracy as in the module docstring. inf when exactly one mesh has
    no faces, 0 when both are empty.
    """
    a_to_b, b_to_a = hausdorff_sides(va, fa, vb, fb, samples, seed)
    return max(a_to_b, b_to_a)


def hausdorff_sides(va, fa, vb, fb, samples: int = DEFAULT_SAMPLES, seed: int = 0) -> tuple[float, float]:
    """(max distance A -> B, max distance B -> A), see `hausdorff`."""
    va, vb = np.asarray(va, dtype=np.float64), np.asarray(vb, dtype=np.float64)
    fa, fb = np.asarray(fa, dtype=np.int64).reshape(-1, 3), np.asarray(fb, dtype=np.int64).reshape(-1, 3)
    if len(fa) == 0 and len(fb) == 0:
        return 0.0, 0.0
    if len(fa) == 0 or len(fb) == 0:
        return float("inf"), float("inf")
    both = np.concatenate([va[np.unique(fa)], vb[np.unique(fb)]])
    origin = (both.min(axis=0) + both.max(axis=0)) / 2.0
    da = SurfaceDistance(va, fa, origin, samples, seed + 1)
    db = SurfaceDistance(vb, fb, origin, samples, seed + 1)
    return one_sided_hausdorff(va, fa, db, samples, seed), one_sided_hausdorff(vb, fb, da, samples, seed)
