"""Pinhole camera geometry in the site's ENU frame (Blender's camera convention: the
camera looks down its local -Z with +Y up), and what a camera can see."""

from __future__ import annotations

import math

import numpy as np

def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) camera-to-world pose, Blender convention: looks down local -Z, +Y up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(np.asarray(up, float), back)
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down: any right will do
        right = np.cross((0.0, 1.0, 0.0), back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def intrinsics(hfov: float, width: int, height: int) -> dict:
    """Pinhole intrinsics of a horizontal-fit camera, pixels; (0, 0) = top-left corner
    of the top-left pixel, so the image centre is (width / 2, height / 2)."""
    fx = (width / 2.0) / math.tan(hfov / 2.0)
    return {"fx": fx, "fy": fx, "cx": width / 2.0, "cy": height / 2.0, "width": width, "height": height,
            "hfov": hfov, "vfov": 2.0 * math.atan((height / 2.0) / fx)}


def project(points: np.ndarray, pose: np.ndarray, k: dict) -> np.ndarray:
    """(n, 3) world points -> (n, 2) pixel (u right, v down); NaN behind the camera."""
    p = (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]  # world -> camera axes
    depth = -p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.c_[k["cx"] + k["fx"] * p[:, 0] / depth, k["cy"] - k["fy"] * p[:, 1] / depth]
    uv[depth <= 0] = np.nan
    return uv



# --- what to load: frustum + shadow culling --------------------------------------------


def _frustum_planes(pose: np.ndarray, k: dict, near: float, far: float) -> list[tuple[np.ndarray, float]]:
    """Inward planes (n, d) with n.x + d >= 0 inside."""
    r, u, b, c = pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3]
    f = -b
    th, tv = math.tan(k["hfov"] / 2), math.tan(k["vfov"] / 2)
    normals = [f, -f, f * th + r, f * th - r, f * tv + u, f * tv - u]
    planes = []
    for i, n in enumerate(normals):
        n = n / np.linalg.norm(n)
        d = -float(n @ c) - (near if i == 0 else 0.0)
        if i == 1:
            d = float(f @ c) + far
            n = -f
        planes.append((n, d))
    return planes


def cull(items: list[dict], pose: np.ndarray, k: dict, near: float, far: float,
         sun_dir: np.ndarray | None, shadow_m: float = 60.0) -> list[dict]:
    """Items ({'centre', 'radius', ...}, world bounding spheres) that the camera sees or
    whose shadow can fall into what it sees: the sphere, swept `shadow_m` away from the
    sun, touches the frustum. Sampling the sweep every half radius (at least 1 m) is
    enough for a conservative sphere test. All spheres and sweep points are tested at
    once: a dataset plans hundreds of frames against the whole site."""
    if not items:
        return []
    planes = _frustum_planes(pose, k, near, far)
    normals = np.array([n for n, _ in planes])  # (6, 3)
    offsets = np.array([d for _, d in planes])  # (6,)
    centres = np.array([np.asarray(it["centre"], float) for it in items])  # (n, 3)
    radii = np.array([float(it["radius"]) for it in items])
    if sun_dir is not None and sun_dir[2] > 0:
        steps = np.maximum(1.0, radii / 2)
        counts = np.ceil((shadow_m + steps) / steps).astype(int)  # len(np.arange(0, shadow_m + step, step))
        j = np.arange(counts.max())
        t = j[None, :] * steps[:, None]  # (n, m) distances along the sweep
        valid = j[None, :] < counts[:, None]
        points = centres[:, None, :] - t[..., None] * np.asarray(sun_dir, float)
    else:
        valid = np.ones((len(items), 1), bool)
        points = centres[:, None, :]
    inside = ((points @ normals.T + offsets) >= -radii[:, None, None]).all(axis=-1) & valid
    return [it for it, hit in zip(items, inside.any(axis=1)) if hit]


# --- the scene as the runtime sees it -----------------------------------------------------
