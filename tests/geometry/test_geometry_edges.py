"""geometry.edges: one int64 key per undirected edge, against edges written out as
sorted pairs here; and the places that key edges agree with a plain count."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import ir
from pipeline.findings import edge_defect_counts
from pipeline.geometry import clean as C
from pipeline.geometry.edges import directed_edges, edge_keys, edge_vertices


def _pairs(faces: np.ndarray) -> list[tuple[int, int]]:
    """Each face's edges (a, b), (b, c), (c, a), face by face, as Python pairs."""
    return [(int(f[i]), int(f[(i + 1) % 3])) for f in faces for i in range(3)]


def _random_faces(seed: int, n: int = 40, m: int = 200) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, n, (m, 3))


@pytest.mark.parametrize("seed", range(3))
def test_keys_order_and_read_back_as_sorted_pairs(seed):
    faces = _random_faces(seed)
    n = int(faces.max()) + 1
    assert directed_edges(faces).tolist() == [list(p) for p in _pairs(faces)]
    keys = edge_keys(faces, n)
    assert keys.dtype == np.int64 and keys.shape == (3 * len(faces),)
    assert edge_vertices(keys, n).tolist() == [sorted(p) for p in _pairs(faces)]
    # keys sort as the pairs do, whatever the multiplier above the largest vertex
    for multiplier in (n, n + 1, 10 * n):
        order = np.argsort(edge_keys(faces, multiplier), kind="stable")
        pairs = [tuple(sorted(p)) for p in _pairs(faces)]
        assert [pairs[i] for i in order] == sorted(pairs)


def test_int32_faces_and_vertex_ids_past_32_bits():
    faces = np.array([[0, 1, 2]], dtype=np.int32)
    assert edge_keys(faces, 3).tolist() == [1, 5, 2]
    big = 3_000_000_000
    keys = edge_keys(np.array([[big - 1, 0, 7]]), big)
    assert edge_vertices(keys, big).tolist() == [[0, big - 1], [0, 7], [7, big - 1]]


def test_empty():
    faces = np.zeros((0, 3), dtype=np.int64)
    assert directed_edges(faces).shape == (0, 2) and edge_keys(faces, 0).shape == (0,)
    assert edge_vertices(np.zeros(0, dtype=np.int64), 0).shape == (0, 2)


@pytest.mark.parametrize("seed", range(3))
def test_edge_counts_agree_with_a_plain_count(seed):
    faces = _random_faces(seed, n=12, m=60)
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    uses: dict[tuple[int, int], int] = {}
    runs: dict[tuple[int, int], int] = {}
    for a, b in _pairs(faces):
        uses[(min(a, b), max(a, b))] = uses.get((min(a, b), max(a, b)), 0) + 1
        runs[(a, b)] = runs.get((a, b), 0) + 1
    edges, counts = C.edge_face_counts(faces)
    assert [tuple(e) for e in edges.tolist()] == sorted(uses) and counts.tolist() == [uses[e] for e in sorted(uses)]
    non_manifold = sorted(e for e, k in uses.items() if k > 2)
    n = int(faces.max()) + 1
    assert edge_vertices(C.non_manifold_edge_keys(faces, n), n).tolist() == [list(e) for e in non_manifold]
    assert C.non_manifold_edge_count(faces) == len(non_manifold)
    wound = sum(1 for e, k in uses.items() if k == 2 and runs.get(e, 0) != 1)
    vertices = np.random.default_rng(seed).normal(size=(n, 3))  # distinct points: welding joins none
    assert edge_defect_counts(ir.Mesh(vertices, faces)) == (len(non_manifold), wound)
