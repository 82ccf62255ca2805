"""Pose helpers on 4x4 float64 homogeneous matrices.

Conventions (DESIGN.md s.3): right-handed, radians, SDF roll-pitch-yaw meaning fixed
axes X, then Y, then Z, i.e. R = Rz(yaw) @ Ry(pitch) @ Rx(roll). Quaternions are
(w, x, y, z) with w >= 0. Pure numpy, no I/O.
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


def quaternion_from_matrix(m) -> np.ndarray:
    """Unit quaternion (4,) = (w, x, y, z), w >= 0, of the rotation part of a (4, 4)/(3, 3).

    Shepperd's method: choose the largest of 4w^2, 4x^2, 4y^2, 4z^2 as the pivot so the
    square root and the division never work on a small number.
    """
    r = np.asarray(m, dtype=np.float64)[:3, :3]
    t = np.trace(r)
    diag = (t, r[0, 0], r[1, 1], r[2, 2])
    k = int(np.argmax(diag))
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + t, 0.0))
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0))
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 - r[0, 0] + r[1, 1] - r[2, 2], 0.0))
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(max(1.0 - r[0, 0] - r[1, 1] + r[2, 2], 0.0))
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quaternion(q, xyz=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64 pose from a quaternion (4,) = (w, x, y, z) (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return m


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
