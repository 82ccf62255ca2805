"""The main-tank gauge's geometry: where its dial is in the model frame, its outline
and box as a camera sees them, and the pointer angle a tank level maps to."""

from __future__ import annotations

import math

import numpy as np

from ..geometry.pinhole import project

# The main-tank dial (sources/authoring/ASSETS.md): centre and facing in the model frame.
DIAL_CENTER = np.array([0.0, -1.80, 2.80])
DIAL_NORMAL = np.array([0.0, -1.0, 0.0])
DIAL_RADIUS = 0.15 * 1.12  # the bezel's outer radius
POINTER = "gauge_tank_pointer"


FACE_RADIUS = 0.15  # the dial face inside the bezel


def dial_outline(model_pose: np.ndarray, n: int = 32, radius: float = DIAL_RADIUS) -> np.ndarray:
    """(n, 3) world points on the bezel's rim (the dial lies in the model XZ plane)."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    local = DIAL_CENTER + radius * np.c_[np.cos(a), np.zeros(n), np.sin(a)]
    return local @ model_pose[:3, :3].T + model_pose[:3, 3]


def gauge_box(model_pose: np.ndarray, cam_pose: np.ndarray, k: dict) -> dict:
    """2D box of the dial projected from its 3D rim, clipped to the frame."""
    uv = project(dial_outline(model_pose), cam_pose, k)
    if np.isnan(uv).any():
        return {"box": None, "visible": False}
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    clipped = [max(0.0, lo[0]), max(0.0, lo[1]), min(k["width"], hi[0]), min(k["height"], hi[1])]
    inside = bool(lo[0] >= 0 and lo[1] >= 0 and hi[0] <= k["width"] and hi[1] <= k["height"])
    centre = project((model_pose @ np.r_[DIAL_CENTER, 1.0])[None, :3], cam_pose, k)[0]
    return {"box": [float(v) for v in clipped], "box_unclipped": [float(v) for v in (*lo, *hi)],
            "centre": [float(v) for v in centre], "inside_frame": inside,
            "visible": bool(clipped[2] > clipped[0] and clipped[3] > clipped[1])}


def dial_world(model_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return model_pose[:3, :3] @ DIAL_CENTER + model_pose[:3, 3], model_pose[:3, :3] @ DIAL_NORMAL


def pointer_angle(level: float, binding: dict) -> float:
    """The binding's linear map of the tank level to the pointer angle (rad)."""
    (d0, d1), (r0, r1) = binding["domain"], binding["range"]
    x = min(max(level, min(d0, d1)), max(d0, d1))
    return r0 + (r1 - r0) * (x - d0) / (d1 - d0)
