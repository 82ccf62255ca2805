"""The raw simplifiers: (vertices (n, 3), faces (m, 3)) -> (vertices, faces), no checks.

- "meshoptimizer" (default): error-driven (absolute error target); keeps the original
  vertex buffer, so UVs and normals of the kept vertices survive and attribute seams
  (UV seams, hard edges) are respected.
- "pymeshlab": quadric edge collapse with optimal placement, the accuracy reference.
  Count-driven. Crashes the whole process on a face with two equal indices, so its
  input is always cleaned first.
- "fast_simplification": fast quadrics (Fast-Quadric-Mesh-Simplification), count-driven.

Each library is imported where it is used: a build that never calls one never needs it.
"""

from __future__ import annotations

import numpy as np

from .. import clean as _clean

METHODS = ("meshoptimizer", "pymeshlab", "fast_simplification")


def meshopt(vertices: np.ndarray, faces: np.ndarray, target_faces: int, target_error: float,
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


def pymeshlab(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """pymeshlab's quadric edge collapse to about `target_faces` triangles (new vertices)."""
    import pymeshlab as _pymeshlab

    ms = _pymeshlab.MeshSet()
    ms.add_mesh(_pymeshlab.Mesh(vertex_matrix=np.asarray(vertices, dtype=np.float64),
                                face_matrix=np.asarray(faces, dtype=np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(max(target_faces, 1)), qualitythr=0.3, preservenormal=True, preservetopology=True,
        optimalplacement=True, planarquadric=True, autoclean=True,
    )
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def fast(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """fast_simplification's quadrics to about `target_faces` triangles (new vertices)."""
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
        v, f = meshopt(local, faces, target_faces, target_error=float("inf"))
    elif method == "pymeshlab":
        v, f = pymeshlab(local, faces, target_faces)
    elif method == "fast_simplification":
        v, f = fast(local, faces, target_faces)
    else:
        raise ValueError(f"unknown simplifier {method!r}; one of {METHODS}")
    kept, f = _clean.compact(f, len(v)) if len(f) else (np.zeros(0, dtype=np.int64), f.reshape(0, 3))
    return v[kept] + centre, f
