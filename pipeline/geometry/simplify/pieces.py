"""Pieces: a large welded mesh is searched in pieces of at most PIECE_FACES faces, each
with its border locked, and the pieces' levels joined back into levels of the whole.

A piece's search finds misses where they are: fewer rounds fix one piece's misses
than the whole's, and each piece has memo keys of its own, so an edit in one place
searches one piece again. The cuts (`split`) are placed so that a small edit moves
none of them.
"""

from __future__ import annotations

import math

import numpy as np

from .. import clean as _clean
from ..edges import edge_keys, edge_vertices
from .judge import SAMPLES_PER_FACE
from .memo import Level

# A welded mesh of more than twice this many faces is searched in pieces of at most
# this many. Up to twice: a piece judges non-manifold edges per part within it, where
# the whole lets one region of a visual pay for another, and a mesh of two pieces'
# worth loses more faces to that than it gains in speed.
PIECE_FACES = 16_384


def split(vertices: np.ndarray, faces: np.ndarray, limit: int) -> list[np.ndarray]:
    """The faces (ascending ids) of each piece of at most `limit` faces that a welded
    mesh (`vertices` in the link frame) is searched in: split in two along the
    longest axis of the face centroids, again and again, between connected parts where
    there are several (by their centroids) and through the one part otherwise. A mesh
    of up to 2 * `limit` faces is one piece.

    A split is at the median face centroid rounded to a grid (`cut`), not at an exact
    face count: a vertex moved, or a few faces more or less (a clean step keeping
    faces it dropped as degenerate before), in one place changes the piece there
    alone, and the other pieces' levels come from the memo."""
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
        at = cut(x)
        names, inverse, counts = np.unique(part[ids], return_inverse=True, return_counts=True)
        if len(names) > 1:
            centre = np.bincount(inverse, weights=x) / counts
            left = centre < at
            if left.all() or not left.any():  # one part holds the median: cut by count
                order = np.lexsort((names, centre))
                before = np.cumsum(counts[order])[:-1]  # faces left of each possible cut
                left = np.zeros(len(names), dtype=bool)
                left[order[:int(np.argmin(np.abs(before - len(ids) / 2.0))) + 1]] = True
            left = left[inverse]
        else:
            left = x < at
            if left.all() or not left.any():
                left = np.zeros(len(ids), dtype=bool)
                left[np.lexsort((ids, x))[:len(ids) // 2]] = True
        stack += [ids[~left], ids[left]]  # the left half is taken next: pieces in axis order
    return out


def cut(x: np.ndarray) -> float:
    """Where to split values `x` (face centroids along an axis): their median, rounded
    to a power-of-two grid of 1/16 to 1/32 of their extent, so that a few values more,
    fewer or moved move it only when the median crosses a grid line."""
    extent = float(x.max() - x.min())
    median = float(np.median(x))
    if extent <= 0.0:
        return median
    step = 2.0 ** math.floor(math.log2(extent / 16.0))
    return math.floor(median / step + 0.5) * step


def piece_density(faces: int, samples: int) -> float:
    """Query points per face for the pieces of a mesh of `faces` faces: the whole's
    (Judge: SAMPLES_PER_FACE, at most `samples` in all), rounded down to a quarter
    octave, so that a few faces more elsewhere leave a piece's count, and its memo
    keys, alone. Each piece gets its share, not the whole's count: measuring, not
    simplifying, is what a search spends its time on."""
    whole = min(float(SAMPLES_PER_FACE), samples / max(faces, 1))
    return 2.0 ** (math.floor(4.0 * math.log2(whole)) / 4.0)


def joined_levels(vertices: np.ndarray, faces: np.ndarray, parts: np.ndarray | None, pieces: list[np.ndarray],
                  piece_levels: list[list[Level | None]]) -> list[Level | None]:
    """The pieces' levels (`piece_levels[k]`: piece k's, one per budget, on its own
    vertices) as levels of the whole (on its vertex numbering): a piece with no level
    of its own at a budget keeps its finer one. A level's error is the largest
    piece's (each piece's simplification is within it of its original, so the whole
    is within it of the whole, both ways). Where a part was cut in two, each side may
    make a face on a border edge that is manifold on its own side: such a level gives
    those pieces their finer levels back until no part has more non-manifold edges
    than as authored. None: no piece has a coarser level there."""
    # `vertices` is simplify_levels' weld already (per part): welding it again, as the
    # judge does its unwelded inputs, would map every vertex to itself
    part = np.zeros(len(vertices), np.int64) if parts is None else np.unique(parts, return_inverse=True)[1]
    allowed = part_non_manifold(part, faces)[0]
    owners = [_clean.compact(faces[ids], len(vertices))[0] for ids in pieces]
    finer = [faces[ids] for ids in pieces]  # each piece's current level on the whole's vertices
    finer_error = [0.0] * len(pieces)
    out: list[Level | None] = []
    for i in range(len(piece_levels[0])):
        chosen = [(used[levels[i].corners], levels[i].error_m) if levels[i] is not None else None
                  for used, levels in zip(owners, piece_levels)]
        while True:
            corners = [c[0] if c is not None else f for c, f in zip(chosen, finer)]
            bad = added_non_manifold(part, np.concatenate(corners), allowed)
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
        flipped = sum(levels[i].flipped for levels, c in zip(piece_levels, chosen) if c is not None)
        out.append(Level(np.concatenate(finer), max(finer_error), flipped, 0))
    return out


def part_non_manifold(part: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(how many non-manifold edges each part has (parts,), their keys) of `faces` on
    welded vertices whose parts are `part: (n,)`, as the judge counts them."""
    n = len(part)
    keys = _clean.non_manifold_edge_keys(faces, n)
    return np.bincount(part[edge_vertices(keys, n)[:, 0]], minlength=int(part.max(initial=0)) + 1), keys


def added_non_manifold(part: np.ndarray, faces: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Ids of the faces on the non-manifold edges of the parts that have more such
    edges than `allowed` (per part) in `faces`."""
    counts, keys = part_non_manifold(part, faces)
    grown = counts - allowed
    if not (grown > 0).any():
        return np.zeros(0, dtype=np.int64)
    n = len(part)
    keys = keys[grown[part[edge_vertices(keys, n)[:, 0]]] > 0]
    on_bad = np.isin(edge_keys(faces, n), keys)
    return np.unique(np.nonzero(on_bad)[0] // 3)
