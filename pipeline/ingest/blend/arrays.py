"""Pure numpy for the .blend reader (no bpy): an object's matrix split into a rigid
pose and a baked rest, and an `ir.Mesh` built from Blender-style arrays."""

from __future__ import annotations

import numpy as np

from ... import ir

# A direction shorter than this is no direction (joint or binding axis).
MIN_AXIS_LENGTH = 1e-9


def split_rigid(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split an affine (4, 4) float64 matrix M into a rigid pose P and a linear rest S
    with M = P @ [S 0; 0 1].

    P's rotation is the orthogonal polar factor of M's 3x3 part, negated when that is a
    reflection (a 3x3 negation flips the determinant), so P is always a proper rotation
    and S carries scale, shear and any mirroring (det S < 0). For an unscaled object P
    is its matrix and S the identity. Returns (P (4, 4), S (3, 3)); raises ValueError
    for a singular (zero-scale) matrix."""
    m = np.asarray(matrix, dtype=np.float64)
    a = m[:3, :3]
    u, sigma, vt = np.linalg.svd(a)
    if not np.all(np.isfinite(sigma)) or sigma[-1] <= 1e-12 * max(sigma[0], 1e-300):
        raise ValueError("zero scale")
    q = u @ vt
    if np.linalg.det(q) < 0.0:
        q = -q
    s = q.T @ a
    p = np.eye(4)
    p[:3, :3] = q
    p[:3, 3] = m[:3, 3]
    return p, s


def rigid_inverse(p: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) pose."""
    inv = np.eye(4)
    inv[:3, :3] = p[:3, :3].T
    inv[:3, 3] = -p[:3, :3].T @ p[:3, 3]
    return inv


def build_mesh(
    co: np.ndarray,
    tris: np.ndarray,
    corner_uvs: np.ndarray | None,
    rest: np.ndarray,
    keys: tuple[tuple[str, np.ndarray], ...] = (),
) -> ir.Mesh:
    """An `ir.Mesh` from Blender-style arrays.

    co: (n, 3) float64 object-local vertices; tris: (m, 3) vertex indices;
    corner_uvs: (m, 3, 2) UV per triangle corner, or None; rest: (3, 3) linear part
    baked into the vertices (mirroring reverses the winding); keys: (name, (n, 3)
    absolute local positions). Unreferenced vertices are dropped; a vertex whose
    corners carry different UVs is split, so uvs are per vertex."""
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if corner_uvs is None:
        source, inverse = np.unique(tris.ravel(), return_inverse=True)
        uvs = None
    else:
        corners = np.column_stack([tris.ravel().astype(np.float64), corner_uvs.reshape(-1, 2)])
        rows, inverse = np.unique(corners, axis=0, return_inverse=True)
        source = rows[:, 0].astype(np.int64)
        uvs = rows[:, 1:]
    faces = inverse.reshape(-1, 3)
    if np.linalg.det(rest) < 0.0:
        faces = faces[:, ::-1]
    vertices = co[source] @ rest.T
    shape_keys = tuple(ir.ShapeKey(name, k[source] @ rest.T) for name, k in keys)
    return ir.Mesh(vertices=vertices, faces=faces, uvs=uvs, shape_keys=shape_keys)
