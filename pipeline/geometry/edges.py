"""The edges of a triangle mesh, each undirected edge keyed as one int64.

Counting, grouping or looking up edges is then a 1-D sort of integers (np.unique,
np.searchsorted, np.isin), many times faster than sorting rows of pairs. A key is
`lower vertex * n_vertices + higher vertex`: keys sort as the (lower, higher) pairs
do, and `edge_vertices` reads a key back.
"""

from __future__ import annotations

import numpy as np


def _heads_tails(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    return corners.ravel(), corners[:, [1, 2, 0]].ravel()


def directed_edges(faces: np.ndarray) -> np.ndarray:
    """(3m, 2) int64: face k's edges (a, b), (b, c), (c, a) at rows 3k, 3k + 1, 3k + 2.
    faces: (m, 3) int."""
    return np.stack(_heads_tails(faces), axis=1)


def edge_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(3m,) int64: the undirected key of each of directed_edges(faces), in that order.
    n_vertices: more than the largest vertex id in faces (m, 3)."""
    heads, tails = _heads_tails(faces)
    return np.minimum(heads, tails) * int(n_vertices) + np.maximum(heads, tails)


def edge_vertices(keys: np.ndarray, n_vertices: int) -> np.ndarray:
    """(k, 2) int64 (lower, higher) vertex ids of edge keys (k,) made with n_vertices."""
    keys = np.asarray(keys, dtype=np.int64)
    return np.stack([keys // int(n_vertices), keys % int(n_vertices)], axis=1)
