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

import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .. import ir
from ..errors import UserError
from . import clean as _clean
from .metrics import SurfaceDistance, face_normals, one_sided_hausdorff, query_points
from .transform import linear_scale

METHODS = ("meshoptimizer", "pymeshlab", "fast_simplification")
MEASURE_SAMPLES = 50_000


# --- raw simplifiers: (vertices (n, 3), faces (m, 3)) -> (vertices, faces) -------------


def _meshopt(vertices: np.ndarray, faces: np.ndarray, target_faces: int, target_error: float) -> tuple[np.ndarray, np.ndarray]:
    """meshoptimizer's simplify. target_error is ABSOLUTE (same units as vertices).
    Returns the ORIGINAL vertices and new faces (indices into them)."""
    import meshoptimizer

    idx = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    pos = np.ascontiguousarray(vertices, dtype=np.float32)
    dest = np.zeros(len(idx), dtype=np.uint32)
    count = meshoptimizer.simplify(
        dest, idx, pos, target_index_count=int(3 * max(target_faces, 0)), target_error=float(target_error),
        options=meshoptimizer.SIMPLIFY_ERROR_ABSOLUTE,
    )
    return vertices, dest[:count].reshape(-1, 3).astype(np.int64)


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
    """Faces of (vertices (n, 3), faces (m, 3)) that point against every nearby face of
    the reference surface (the candidates of its centroid within `tolerance` of the
    nearest one). Thin two-sided parts are never counted: either side agrees."""
    if len(faces) == 0:
        return 0
    normals = face_normals(vertices, faces)
    centroids = vertices[faces].mean(axis=1)
    cand, dist = reference.nearest_faces(centroids)
    ref_normals = face_normals(reference.vertices, reference.faces)
    near = dist <= dist.min(axis=1, keepdims=True) + tolerance
    dots = np.einsum("kcj,kj->kc", ref_normals[cand], normals)
    best = np.where(near, dots, -np.inf).max(axis=1)
    has_area = np.linalg.norm(normals, axis=1) > 0
    # below -0.2: clearly facing away, not a face standing across a crease
    return int(((best < -0.2) & has_area).sum())


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

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, samples: int):
        self.vertices, self.faces, self.samples = vertices, faces, samples
        self.reference = SurfaceDistance(vertices, faces, samples=samples)
        self.non_manifold = _clean.non_manifold_edge_count(_topology_faces(vertices, faces))
        self.queries = query_points(vertices, faces, samples)  # the original side, reused

    def __call__(self, v: np.ndarray, f: np.ndarray, kept: np.ndarray | None, tolerance: float) -> Simplified:
        f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
        if len(f):
            f = f[~_clean.degenerate_faces(v, f, 0.0)]
            f = f[~_clean.duplicate_faces(f)]
        if len(f) == 0:
            return Simplified(v, f, kept, math.inf, 0, 0)
        used, f = _clean.compact(f, len(v))
        v = v[used]
        kept = None if kept is None else kept[used]
        there = float(SurfaceDistance(v, f, samples=self.samples)(self.queries).max())
        back = one_sided_hausdorff(v, f, self.reference, self.samples)
        flips = flipped_face_count(self.reference, v, f, tolerance)
        added = _clean.non_manifold_edge_count(_topology_faces(v, f)) - self.non_manifold
        return Simplified(v, f, kept, max(there, back), flips, added)


def _search_meshopt(judge: _Judge, budget: float, iterations: int) -> Simplified | None:
    """Largest meshoptimizer error target whose result measures within budget."""
    # meshoptimizer's own error estimate runs 2-5x below the measured Hausdorff
    # distance: start at a third of the budget, step down by 3 until one passes
    best, lo, hi, s = None, 0.0, math.inf, budget / 3.0
    for _ in range(iterations):
        v, f = _meshopt(judge.vertices, judge.faces, 0, s)
        r = judge(v, f, np.arange(len(v)), budget)
        if r.valid and r.error_m <= budget:
            if best is None or len(r.faces) < len(best.faces):
                best = r
            lo = s
        else:
            hi = s
        s = s * 2.0 if hi == math.inf else (math.sqrt(lo * hi) if lo > 0 else hi / 3.0)
        if hi < math.inf and lo > 0 and hi / lo < 1.2:
            break
    return best


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
                     iterations: int = 6, samples: int = MEASURE_SAMPLES) -> Simplified:
    """The coarsest checked simplification of a CLEAN mesh within `budget_m` (metres).

    vertices: (n, 3) float64, faces: (m, 3) int. When nothing coarser passes, the input
    itself comes back (error 0): a level never exceeds its budget and never vanishes.
    """
    if method not in METHODS:
        raise ValueError(f"unknown simplifier {method!r}; one of {METHODS}")
    local, centre = _clean.centred(np.asarray(vertices, dtype=np.float64))
    faces = np.asarray(faces, dtype=np.int64)
    identity = Simplified(np.asarray(vertices, dtype=np.float64), faces, np.arange(len(vertices)), 0.0, 0, 0)
    if len(faces) <= 1 or budget_m <= 0:
        return identity
    judge = _Judge(local, faces, samples)
    if method == "meshoptimizer":
        best = _search_meshopt(judge, budget_m, iterations)
    else:
        best = _search_count(judge, budget_m, iterations, method)
    if best is None or len(best.faces) >= len(faces):
        return identity
    return replace(best, vertices=best.vertices + centre)


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
    iterations: int = 6
    samples: int = MEASURE_SAMPLES


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


def lod_chain(options: LodOptions = LodOptions()) -> Callable[[ir.Asset], ir.Asset]:
    """Step: Visual.lods = (authored, LOD1, ..., LODk) and Asset.lods = LodInfo for
    levels 0..k (level 0: the authored meshes, budget and error 0).

    A visual's budget is divided by the largest scale of its pose chain, so the error
    is met in the model frame. A level's error is the largest of its visuals' errors
    (the Hausdorff distance of a union is at most the largest part's). Frozen visuals
    (shape keys, state bindings) repeat their Mesh object at every level.
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
            visuals = []
            for vis in link.visuals:
                mesh = vis.mesh
                if vis.name in frozen or mesh.triangle_count == 0:
                    visuals.append(replace(vis, lods=(mesh,) * (len(budgets) + 1)))
                    continue
                _check_clean(asset, vis)
                scale = max(linear_scale(link.pose @ vis.pose), 1e-12)
                lods = [mesh]
                for i, b in enumerate(budgets):
                    r = simplify_checked(mesh.vertices, mesh.faces, b / scale, options.method,
                                         options.iterations, options.samples)
                    lods.append(mesh if r.faces is mesh.faces else _lod_mesh(mesh, r))
                    errors[i] = max(errors[i], r.error_m * scale)
                visuals.append(replace(vis, lods=tuple(lods)))
            links.append(replace(link, visuals=tuple(visuals)))
        out = asset.with_(links=tuple(links))
        infos = [ir.LodInfo(0, 0.0, 0.0, out.triangle_count(0))]
        infos += [ir.LodInfo(i + 1, b, float(errors[i]), out.triangle_count(i + 1)) for i, b in enumerate(budgets)]
        return out.with_(lods=tuple(infos))

    return step


def _check_clean(asset: ir.Asset, vis: ir.Visual) -> None:
    """Refuse what would crash a simplifier, naming the visual (run clean() first)."""
    f = vis.mesh.faces
    _clean.check_finite(vis.mesh.vertices, asset.source, vis.name)
    if len(f) and ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])).any():
        raise UserError(asset.source, vis.name, "mesh has faces with repeated vertices; run the clean step before LODs")


# --- benchmark ------------------------------------------------------------------


def insulator_mesh(sheds: int = 40, segments: int = 160, target_faces: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """A CAD-like post insulator: a long thin core (radius 4 cm, 2 m) carrying `sheds`
    thin sheds (2 mm thick, 12 cm overhang), as one closed surface of revolution.
    Returns vertices (n, 3), faces (m, 3), about target_faces triangles."""
    z, r = [0.0], [0.04]
    pitch = 2.0 / sheds
    for k in range(sheds):
        z0 = k * pitch + 0.3 * pitch
        z += [z0, z0 + 0.004, z0 + 0.006, z0 + 0.002 + 0.3 * pitch * 0.1]
        r += [0.04, 0.16, 0.16, 0.04]
    z += [2.0]
    r += [0.04]
    profile = np.stack([r, z], axis=1)
    # subdivide the profile so the face count lands near the target
    rings = max(2, target_faces // (2 * segments))
    t = np.linspace(0, 1, len(profile))
    ti = np.linspace(0, 1, max(rings, len(profile)))
    ti = np.unique(np.r_[t, ti])
    prof = np.stack([np.interp(ti, t, profile[:, 0]), np.interp(ti, t, profile[:, 1])], axis=1)
    return _revolve(prof, segments)


def _revolve(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface of revolution about Z of a (k, 2) (radius, z) profile, capped."""
    k = len(profile)
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    v = np.concatenate([
        np.column_stack([profile[i, 0] * ring, np.full(segments, profile[i, 1])]) for i in range(k)
    ] + [np.array([[0, 0, profile[0, 1]], [0, 0, profile[-1, 1]]])])
    i = np.arange(k - 1)[:, None] * segments
    j = np.arange(segments)[None, :]
    a0, a1 = i + j, i + (j + 1) % segments
    b0, b1 = a0 + segments, a1 + segments
    side = np.concatenate([np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)])
    bottom, top = k * segments, k * segments + 1
    jj = np.arange(segments)
    cap0 = np.stack([np.full(segments, bottom), (jj + 1) % segments, jj], axis=1)
    cap1 = np.stack([np.full(segments, top), (k - 1) * segments + jj, (k - 1) * segments + (jj + 1) % segments], axis=1)
    return v, np.concatenate([side, cap0, cap1]).astype(np.int64)


def noisy_sphere(subdivisions: int = 6, noise: float = 0.002, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere (20 * 4^s faces) with radial noise of `noise` m (std)."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    v = s.vertices * (1.0 + noise * rng.standard_normal(len(s.vertices)))[:, None]
    return v, np.asarray(s.faces, dtype=np.int64)


def sliver_mesh(n: int = 200, length: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A long thin open strip of needle triangles (aspect ratio ~ 1000) on a gentle
    wave: n x 2 vertices, 2 (n - 1) faces."""
    x = np.linspace(0, length, n)
    y = np.array([0.0, length / 1000.0])
    xx, yy = np.meshgrid(x, y, indexing="ij")
    zz = 0.01 * np.sin(6 * xx)
    v = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    i = np.arange(n - 1) * 2
    f = np.concatenate([np.stack([i, i + 2, i + 1], 1), np.stack([i + 1, i + 2, i + 3], 1)])
    return v, f.astype(np.int64)


def _isolated(method: str, v: np.ndarray, f: np.ndarray, target: int, timeout: float) -> dict:
    """Run one simplification in a child process (a crash kills only the child)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, v=v, f=f)
        cmd = [sys.executable, "-m", "pipeline.geometry.lod", method, str(src), str(dst), str(target)]
        try:
            proc = subprocess.run(cmd, capture_output=True, timeout=timeout, text=True)
        except subprocess.TimeoutExpired:
            return {"crashed": True, "why": f"timeout after {timeout} s"}
        if proc.returncode != 0 or not dst.exists():
            return {"crashed": True, "why": f"exit {proc.returncode}: {proc.stderr.strip()[-200:]}"}
        out = np.load(dst)
        return {"crashed": False, "v": out["v"], "f": out["f"], "seconds": float(out["seconds"])}


def bench_simplifiers(meshes: dict | None = None, ratios=(0.1, 0.02), methods=METHODS, timeout: float = 300.0) -> dict:
    """Each simplifier on each mesh at matched triangle counts (ratios of the input).

    meshes: {name: (vertices (n, 3), faces (m, 3))}; default: insulator (200k faces),
    noisy sphere (82k), slivers. Every run is in a child process. Returns
    {"runs": [{mesh, method, ratio, triangles, seconds, triangles_per_s, error_m,
    flipped, non_manifold_added, crashed}], "summary": {...per method vs pymeshlab}}.
    """
    if meshes is None:
        meshes = {"insulator": insulator_mesh(), "noisy_sphere": noisy_sphere(), "slivers": sliver_mesh()}
    runs = []
    for name, (v0, f0) in meshes.items():
        m = _clean.clean_mesh(ir.Mesh(v0, f0))
        v, f = m.vertices, np.asarray(m.faces, dtype=np.int64)
        local, _ = _clean.centred(v)
        judge = _Judge(local, f, MEASURE_SAMPLES)
        for ratio in ratios:
            target = max(4, int(len(f) * ratio))
            for method in methods:
                r = _isolated(method, v, f, target, timeout)
                row = {"mesh": name, "method": method, "ratio": ratio, "input_triangles": int(len(f)),
                       "target_triangles": target, "crashed": r["crashed"]}
                if r["crashed"]:
                    row["why"] = r["why"]
                else:
                    sv, sf = r["v"] - _clean.centred(v)[1], r["f"]
                    s = judge(sv, sf, None, 0.0)
                    row.update(triangles=int(len(sf)), seconds=r["seconds"],
                               triangles_per_s=float(len(f) / max(r["seconds"], 1e-9)), error_m=s.error_m,
                               flipped=s.flipped, non_manifold_added=s.non_manifold_added)
                runs.append(row)
    return {"runs": runs, "summary": _summary(runs)}


def _summary(runs: list[dict]) -> dict:
    """Per method: median error ratio and speed-up against pymeshlab at matched counts."""
    ref = {(r["mesh"], r["ratio"]): r for r in runs if r["method"] == "pymeshlab" and not r["crashed"]}
    out = {}
    for method in sorted({r["method"] for r in runs}):
        err, speed, crashes = [], [], 0
        for r in runs:
            if r["method"] != method:
                continue
            crashes += r["crashed"]
            p = ref.get((r["mesh"], r["ratio"]))
            if r["crashed"] or p is None:
                continue
            err.append(r["error_m"] / max(p["error_m"], 1e-12))
            speed.append(p["seconds"] / max(r["seconds"], 1e-9))
        out[method] = {"median_error_vs_pymeshlab": float(np.median(err)) if err else None,
                       "median_speedup_vs_pymeshlab": float(np.median(speed)) if speed else None,
                       "crashes": int(crashes)}
    return out


def _child(method: str, src: str, dst: str, target: str) -> None:
    data = np.load(src)
    t0 = time.perf_counter()
    v, f = simplify_to_count(data["v"], data["f"], int(target), method)
    seconds = time.perf_counter() - t0
    np.savez(dst, v=v, f=f, seconds=seconds)


if __name__ == "__main__":
    if len(sys.argv) == 5:
        _child(*sys.argv[1:])
    else:
        print(json.dumps(bench_simplifiers(), indent=1, default=float))
