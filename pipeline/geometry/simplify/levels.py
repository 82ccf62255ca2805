"""A mesh's LOD levels: weld, split into pieces, recall what the memo holds, search
the rest, join the pieces, and give each new corner back its original vertex."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ... import ir
from .. import clean as _clean
from ..metrics import face_normals
from . import pieces as _pieces
from .backends import METHODS
from .judge import MEASURE_SAMPLES, Judge, Simplified
from .memo import Level, LevelKeys, Memo, ceiling_after, level_arrays, recall
from .search import ITERATIONS, Parallelism, search_count, search_levels

# Below this many triangles a level saves nothing worth a measurement.
MIN_FACES = 64


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


def simplify_checked(vertices: np.ndarray, faces: np.ndarray, budget_m: float, method: str = "meshoptimizer",
                     iterations: int = ITERATIONS, samples: int = MEASURE_SAMPLES, normals: np.ndarray | None = None,
                     parts: np.ndarray | None = None) -> Simplified:
    """The coarsest checked simplification of a CLEAN mesh within `budget_m` (metres):
    `simplify_levels` with one budget."""
    return simplify_levels(vertices, faces, (budget_m,), method, iterations, samples, normals, parts)[0]


def simplify_levels(vertices: np.ndarray, faces: np.ndarray, budgets_m, method: str = "meshoptimizer",
                    iterations: int = ITERATIONS, samples: int = MEASURE_SAMPLES, normals: np.ndarray | None = None,
                    parts: np.ndarray | None = None, memo: Memo | None = None,
                    workers: Parallelism = Parallelism()) -> list[Simplified]:
    """The coarsest checked simplification of a CLEAN mesh within each of the
    ascending `budgets_m` (metres), one per budget, each no finer than the one before.

    vertices: (n, 3) float64, faces: (m, 3) int. When nothing coarser passes, the finer
    level (at first the input itself, error 0) comes back: a level never exceeds its
    budget and never vanishes. meshoptimizer runs on the position-welded surface (CAD
    patches and UV/normal seams duplicate vertices; unwelded, every seam is a border
    the simplifier tears open), then each new corner goes back to the original vertex
    of the same place whose normal (`normals: (n, 3)`, optional) best matches the new
    face, so crisp edges and UVs survive. `parts: (n,)` ids keep separate parts from
    welding together. The mesh is welded and indexed once for all budgets.

    A welded mesh of more than 2 * pieces.PIECE_FACES faces is searched in pieces
    (pieces.split: whole parts where it has several), each with its share of the query
    points and its border locked, and the pieces' levels joined (pieces.joined_levels).

    `memo` (meshoptimizer only): each level's search result is kept there under the
    hash of everything it depends on (the welded piece, its locked border, samples,
    iterations, its budget and the finer level's face count, its ceiling), and the
    levels it holds are not searched again: an edit of the coarsest budget searches
    that level alone, a vertex moved in one place one piece. `workers`: the cores the
    caller gives the search and how it runs parts side by side (see run_searches).
    The results are the same with or without either.
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
        judge = Judge(local, faces, samples)
        for budget in budgets_m:
            best = search_count(judge, budget, iterations, method) if budget > 0 else None
            if best is not None and len(best.faces) < len(prev.faces):
                prev = replace(best, vertices=best.vertices + centre)
            out.append(prev)
        return out

    attrs = [] if parts is None else [(np.asarray(parts, dtype=np.float64)[:, None], 0.5)]
    rep = _clean.weld_map(local, _clean.weld_tolerance(local), attrs)
    first, welded_index = np.unique(rep, return_inverse=True)
    welded, welded_faces = local[first], welded_index[faces]
    welded_parts = None if parts is None else np.asarray(parts, dtype=np.int64)[first]
    pieces = _pieces.split(vertices[first], welded_faces, _pieces.PIECE_FACES)
    if len(pieces) == 1:
        searches = [PieceSearch(welded, welded_faces, welded_parts, None, len(faces), samples, iterations,
                                budgets_m, memo)]
    else:
        searches = piece_searches(vertices[first], welded_faces, welded_parts, pieces, samples, iterations,
                                  budgets_m, memo)
    run_searches(searches, iterations, workers)
    levels = searches[0].levels if len(pieces) == 1 else _pieces.joined_levels(
        welded, welded_faces, welded_parts, pieces, [s.levels for s in searches])
    for level in levels:
        if level is not None:
            corners = original_corners(level.corners, welded_index, local, normals)
            used, new_faces = _clean.compact(corners, len(vertices))
            prev = Simplified(vertices[used], new_faces, used, level.error_m, level.flipped, level.non_manifold_added)
        out.append(prev)
    return out


class PieceSearch:
    """One piece's levels: those the memo holds, then the search of the rest.
    `parts`: the piece's vertices' part ids (None: one part); `locked`: its border
    (None for a whole mesh); `ceiling`: the face count its first level must beat."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, locked: np.ndarray | None,
                 ceiling: int, samples: int, iterations: int, budgets, memo: Memo | None):
        self.vertices, self.faces, self.parts, self.locked = vertices, faces, parts, locked
        self.ceiling, self.samples, self.budgets, self.memo = ceiling, samples, tuple(budgets), memo
        self.keys = None if memo is None else LevelKeys(vertices, faces, parts, samples, iterations, budgets,
                                                        ceiling, locked)
        self.levels: list[Level | None] = [] if memo is None else recall(memo, self.keys, len(vertices))

    @property
    def done(self) -> bool:
        return len(self.levels) == len(self.budgets)

    def search(self, iterations: int, workers: Parallelism = Parallelism()) -> list[Level | None]:
        """The levels the memo lacks (not kept yet: see keep), side by side as `workers` allow."""
        judge = Judge(self.vertices, self.faces, self.samples, self.parts)
        found = search_levels(judge, self.budgets[len(self.levels):], iterations,
                              ceiling_after(self.levels, self.ceiling), self.locked, workers)
        return [None if b is None else Level(b.kept[b.faces], b.error_m, b.flipped, b.non_manifold_added)
                for b in found]

    def keep(self, searched: list[Level | None]) -> None:
        for level in searched:
            if self.memo is not None:
                self.memo.put(self.keys.next(self.levels), level_arrays(level))
            self.levels.append(level)


def run_searches(searches: list[PieceSearch], iterations: int, workers: Parallelism = Parallelism()) -> None:
    """Search what the memo lacks. A single piece to search (a whole mesh, or the one
    piece an edit touched) searches its levels side by side; several go to as many
    bins as `workers` has cores, largest first to the lightest bin, each bin's pieces
    one after the other in a part of its own. The memo is written here, so its
    counts are this process's."""
    todo = [s for s in searches if not s.done]
    if len(todo) <= 1:
        for search in todo:
            search.keep(search.search(iterations, workers))
        return
    bins: list[list[PieceSearch]] = [[] for _ in range(max(1, min(workers.cores, len(todo))))]
    load = [0] * len(bins)
    for search in sorted(todo, key=lambda s: -len(s.faces)):  # stable: ties keep the pieces' order
        k = load.index(min(load))
        bins[k].append(search)
        load[k] += len(search.faces)
    results = workers.spread([lambda b=b: [s.search(iterations) for s in b] for b in bins])
    for b, found in zip(bins, results):
        for search, levels in zip(b, found):
            search.keep(levels)


def piece_searches(vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, pieces: list[np.ndarray],
                   samples: int, iterations: int, budgets, memo: Memo | None) -> list[PieceSearch]:
    """A search per piece of a welded mesh (vertices (n, 3) as authored, faces (m, 3)):
    its own vertices, centred on themselves (its memo keys hold nothing of the
    others), the vertices it shares with another piece locked so that the pieces'
    levels still meet, and query points in proportion to its faces (about the
    whole's density, pieces.piece_density)."""
    density = _pieces.piece_density(len(faces), samples)
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
        searches.append(PieceSearch(local, local_faces, own_parts, shared[used] > 1, len(ids), share, iterations,
                                    budgets, memo))
    return searches


def original_corners(welded_faces: np.ndarray, welded_index: np.ndarray, vertices: np.ndarray,
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
