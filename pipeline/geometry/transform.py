"""Pose helpers on 4x4 float64 homogeneous matrices.

Conventions (DESIGN.md s.3): right-handed, radians, SDF roll-pitch-yaw meaning fixed
axes X, then Y, then Z, i.e. R = Rz(yaw) @ Ry(pitch) @ Rx(roll). Pure numpy, no I/O.

Quaternions, everywhere in the pipeline: (w, x, y, z), the scalar w first, unit
length, w >= 0 where one is made from a matrix (q and -q are the same rotation; the
sign is fixed so equal rotations give equal numbers). The file formats' own orders are
converted only where a file is written or read: glTF stores (x, y, z, w)
(pipeline.glb.to_gltf_rotation / from_gltf_rotation), USD's Gf.Quat takes the real
part first, as here.
"""

from __future__ import annotations

import math

import numpy as np


def compose(*matrices) -> np.ndarray:
    """Product m0 @ m1 @ ... of (4, 4) float64 matrices; identity when none given."""
    out = np.eye(4)
    for m in matrices:
        out = out @ np.asarray(m, dtype=np.float64)
    return out


def invert_rigid(m) -> np.ndarray:
    """Inverse of a rigid (rotation + translation) (4, 4) matrix, exact: R^T, -R^T t.

    Cheaper and better conditioned than a general inverse; do not use on scaled poses.
    """
    m = np.asarray(m, dtype=np.float64)
    out = np.eye(4)
    rt = m[:3, :3].T
    out[:3, :3] = rt
    out[:3, 3] = -rt @ m[:3, 3]
    return out


def rotation_x(a: float) -> np.ndarray:
    """(3, 3) rotation by `a` rad about X."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(a: float) -> np.ndarray:
    """(3, 3) rotation by `a` rad about Y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(a: float) -> np.ndarray:
    """(3, 3) rotation by `a` rad about Z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def xyz_rpy_to_matrix(xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64 pose from translation xyz (3,) and SDF roll, pitch, yaw (3,) rad."""
    roll, pitch, yaw = (float(a) for a in rpy)
    m = np.eye(4)
    m[:3, :3] = rotation_z(yaw) @ rotation_y(pitch) @ rotation_x(roll)
    m[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return m


def matrix_to_xyz_rpy(m) -> tuple[np.ndarray, np.ndarray]:
    """Translation (3,) and SDF roll, pitch, yaw (3,) rad of a rigid (4, 4) or (3, 3) matrix.

    pitch = asin(-R[2,0]) is ill-conditioned near +-90 deg, so pitch uses atan2 of
    -R[2,0] against the norm of the first column's xy part (always finite). In gimbal
    lock (cos pitch ~ 0) roll and yaw are not separable: yaw is set to 0 and roll takes
    the whole rotation about the remaining axis, read from the second column, so the
    result round-trips to the matrix.
    """
    m = np.asarray(m, dtype=np.float64)
    r = m[:3, :3]
    xyz = m[:3, 3].copy() if m.shape == (4, 4) else np.zeros(3)
    cos_pitch = math.hypot(r[0, 0], r[1, 0])
    pitch = math.atan2(-r[2, 0], cos_pitch)
    if cos_pitch > 1e-9:
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    else:
        # R = Ry(+-90) Rx(roll): column 1 is (sp*sr, cr, cp*sr) -> (+-sr, cr, 0).
        yaw = 0.0
        sign = 1.0 if -r[2, 0] > 0 else -1.0
        roll = math.atan2(sign * r[0, 1], r[1, 1])
    return xyz, np.array([roll, pitch, yaw])


def quaternions_from_matrices(m) -> np.ndarray:
    """(k, 4) unit quaternions (w, x, y, z), w >= 0, of the rotation parts of
    m: (k, 4, 4) or (k, 3, 3).

    Shepperd's method: each matrix pivots on the largest of 4w^2, 4x^2, 4y^2, 4z^2
    (trace, then the diagonal), so the square root and the division never work on a
    small number, near 180 degrees included.
    """
    r = np.asarray(m, dtype=np.float64)[..., :3, :3].reshape(-1, 3, 3)
    d0, d1, d2 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    t = d0 + d1 + d2
    s_w = 2.0 * np.sqrt(np.maximum(1.0 + t, 0.0))
    s_x = 2.0 * np.sqrt(np.maximum(1.0 + d0 - d1 - d2, 0.0))
    s_y = 2.0 * np.sqrt(np.maximum(1.0 - d0 + d1 - d2, 0.0))
    s_z = 2.0 * np.sqrt(np.maximum(1.0 - d0 - d1 + d2, 0.0))
    w21, w02, w10 = r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]
    a01, a02, a12 = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    with np.errstate(invalid="ignore", divide="ignore"):  # the pivots not taken
        by_pivot = np.stack([
            np.stack([0.25 * s_w, w21 / s_w, w02 / s_w, w10 / s_w], axis=1),
            np.stack([w21 / s_x, 0.25 * s_x, a01 / s_x, a02 / s_x], axis=1),
            np.stack([w02 / s_y, a01 / s_y, 0.25 * s_y, a12 / s_y], axis=1),
            np.stack([w10 / s_z, a02 / s_z, a12 / s_z, 0.25 * s_z], axis=1)])
    pivot = np.argmax(np.stack([t, d0, d1, d2], axis=1), axis=1)
    q = by_pivot[pivot, np.arange(len(r))]
    q /= _lengths(q)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def _lengths(q: np.ndarray) -> np.ndarray:
    """(k, 1) lengths of the rows of q: (k, 4), each the dot product np.linalg.norm
    takes of one vector, so a quaternion gets the same bits in a batch as alone."""
    return np.sqrt(q[:, None, :] @ q[:, :, None])[:, 0]


def quaternion_from_matrix(m) -> np.ndarray:
    """Unit quaternion (4,) = (w, x, y, z), w >= 0, of the rotation part of a (4, 4)/(3, 3)."""
    return quaternions_from_matrices(np.asarray(m, dtype=np.float64)[None])[0]


def matrices_from_quaternions(q) -> np.ndarray:
    """(k, 3, 3) float64 rotations of quaternions q: (k, 4) = (w, x, y, z), each
    normalised here (q and -q give the same rotation)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    w, x, y, z = (q / _lengths(q)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)


def matrix_from_quaternion(q, xyz=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64 pose from a quaternion (4,) = (w, x, y, z) (normalised here) and
    a translation xyz (3,)."""
    m = np.eye(4)
    m[:3, :3] = matrices_from_quaternions(q)[0]
    m[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return m


def quaternion_from_axis_angle(axis, angle: float) -> np.ndarray:
    """(4,) = (w, x, y, z) of a rotation by `angle` rad about `axis` (3,) (normalised
    here; a zero axis means Z)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    a = a / n if n > 0 else np.array([0.0, 0.0, 1.0])
    return np.array([math.cos(angle / 2.0), *(a * math.sin(angle / 2.0))])


def continuous_quaternions(q) -> np.ndarray:
    """(k, 4) quaternions q: (k, 4) with signs flipped so each lies on the hemisphere of
    the one before: a slerp between neighbours then never takes the long way round
    (w >= 0 is given up for continuity)."""
    out = np.array(q, dtype=np.float64).reshape(-1, 4)
    for k in range(1, len(out)):
        if float(out[k] @ out[k - 1]) < 0:
            out[k] = -out[k]
    return out


def decompose(m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split a (4, 4) affine matrix into translation (3,), rotation (3, 3), scale (3,).

    m[:3, :3] = rotation @ diag(scale), rotation proper (det +1). A mirroring matrix
    (det < 0) gets exactly one negative scale, on the axis whose column is longest
    (deterministic choice; any axis is a valid decomposition). Shear is not supported:
    the rotation is orthonormalised by SVD.
    """
    m = np.asarray(m, dtype=np.float64)
    a = m[:3, :3]
    scale = np.linalg.norm(a, axis=0)
    if np.linalg.det(a) < 0:
        axis = int(np.argmax(scale))
        scale[axis] = -scale[axis]
    safe = np.where(scale == 0.0, 1.0, scale)
    rot = a / safe
    u, _, vt = np.linalg.svd(rot)
    rot = u @ vt
    if np.linalg.det(rot) < 0:  # only when a column was degenerate (zero scale)
        u[:, -1] = -u[:, -1]
        rot = u @ vt
    return m[:3, 3].copy(), rot, scale


def linear_scale(m) -> float:
    """Largest factor by which the (4, 4) matrix stretches a length (max singular value)."""
    return float(np.linalg.svd(np.asarray(m, dtype=np.float64)[:3, :3], compute_uv=False)[0])
