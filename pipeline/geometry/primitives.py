"""Which collision meshes are really a box or a cylinder.

A physics engine tests a box or a cylinder in closed form; the same shape as a triangle
mesh costs it a mesh-mesh test (and in dartsim a copy of the mesh per shape). Most of a
substation's collision hulls are boxes (cabinets, plinths) and cylinders (posts,
insulator columns, tanks). `fit_primitive` says when a closed mesh is one, within a
volume tolerance, and gives the shape's pose in the mesh's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .metrics import face_normals, triangle_areas

# The mesh must fill at least this share of the primitive around it. An inscribed
# 16-sided prism fills 97.4 % of its cylinder; a box fills 63.7 % of the cylinder
# around it, and a cylinder 78.5 % of its box, so neither passes for the other.
MIN_FILL = 0.97


@dataclass(frozen=True)
class Primitive:
    """kind "box": size (3,) edge lengths along the pose's x, y, z.
    kind "cylinder": size (radius, length), the axis along the pose's z.
    pose: (4, 4) float64, the shape's centre frame in the mesh's frame."""

    kind: str
    size: tuple[float, ...]
    pose: np.ndarray
    fill: float  # mesh volume / primitive volume


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed, outward-wound mesh (divergence theorem)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def _frame(axes: np.ndarray, centre: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = axes.T  # columns are the shape's axes
    pose[:3, 3] = centre
    return pose


def _orthonormal(z: np.ndarray) -> np.ndarray:
    """Rows x, y, z: a right-handed frame whose z is the given direction."""
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _candidate_axes(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Directions a box's faces or a cylinder's caps may be normal to: the normals of
    the mesh's largest flat regions, and the principal axes of its vertices."""
    normals = face_normals(vertices, faces)
    areas = triangle_areas(vertices, faces)
    keys = np.round(normals, 3)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    region = np.bincount(inverse.reshape(-1), weights=areas, minlength=len(unique))
    order = np.argsort(-region, kind="stable")[:6]
    axes = [normals[np.flatnonzero(inverse.reshape(-1) == k)[0]] for k in order]
    centred = vertices - vertices.mean(axis=0)
    _, _, principal = np.linalg.svd(centred, full_matrices=False)
    return axes + list(principal)


def _box(vertices: np.ndarray, first: np.ndarray, candidates: list[np.ndarray]):
    """The box around the vertices with one face normal to `first` and another normal
    to the first candidate perpendicular to it (else any perpendicular)."""
    second = next((c for c in candidates if abs(float(c @ first)) < 1e-3), None)
    if second is None:
        axes = _orthonormal(first)
    else:
        x = first / np.linalg.norm(first)
        y = second - (second @ x) * x
        y /= np.linalg.norm(y)
        axes = np.stack([x, y, np.cross(x, y)])
    axes = _nearest_to_identity(axes)
    local = vertices @ axes.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    return axes, lo, hi


def _nearest_to_identity(axes: np.ndarray) -> np.ndarray:
    """The same box frame with its axes ordered and signed to lie nearest the mesh's
    own x, y, z (a box aligned with its mesh gets no rotation at all)."""
    order = np.argmax(np.abs(axes), axis=0)  # which box axis is nearest each mesh axis
    if len(set(order.tolist())) < 3:
        return axes
    out = axes[order] * np.sign(np.diag(axes[order]))[:, None]
    if np.linalg.det(out) < 0:
        out[2] = -out[2]
    return out


def fit_primitive(vertices: np.ndarray, faces: np.ndarray, min_fill: float = MIN_FILL) -> Primitive | None:
    """The box or cylinder a closed mesh is, or None.

    vertices: (n, 3) float64; faces: (m, 3), closed and outward (as collision hulls
    are). The primitive encloses every vertex; it is accepted when the mesh fills at
    least `min_fill` of its volume, so the two surfaces are close everywhere.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) < 4:
        return None
    volume = signed_volume(vertices, faces)
    if not np.isfinite(volume) or volume <= 0:
        return None
    candidates = _candidate_axes(vertices, faces)
    best: Primitive | None = None
    for axis in candidates:
        axes, lo, hi = _box(vertices, axis, candidates)
        size = hi - lo
        box_volume = float(np.prod(size))
        if box_volume > 0 and volume / box_volume >= min_fill and (best is None or volume / box_volume > best.fill):
            best = Primitive("box", tuple(float(s) for s in size), _frame(axes, ((lo + hi) / 2) @ axes),
                             volume / box_volume)
    if best is not None:
        return best
    for axis in candidates:
        axes = _orthonormal(axis)
        local = vertices @ axes.T
        z_lo, z_hi = local[:, 2].min(), local[:, 2].max()
        centre_xy = (local[:, :2].min(axis=0) + local[:, :2].max(axis=0)) / 2
        radius = float(np.linalg.norm(local[:, :2] - centre_xy, axis=1).max())
        length = float(z_hi - z_lo)
        cylinder_volume = np.pi * radius**2 * length
        if cylinder_volume <= 0:
            continue
        fill = volume / cylinder_volume
        if fill >= min_fill and (best is None or fill > best.fill):
            centre = np.array([*centre_xy, (z_lo + z_hi) / 2]) @ axes
            best = Primitive("cylinder", (radius, length), _frame(axes, centre), fill)
    return best
