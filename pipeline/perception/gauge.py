"""The one dial model: a gauge's dial as its placement's manifest binds it. The pointer
binding (the visual POINTER turned about an axis) says where the dial is and which way
it faces, in any asset (the shunt reactor's and the power transformer's main tanks
alike), and how a tank level turns the pointer (ir.StateBinding.output, the mapping the
runtime and the renderer pose it with). The radii are the authored part's
(sources/authoring/_parts.py). Render, the datasets and the reader all take their dial
from `dial_of`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import ir
from ..geometry.pinhole import project

POINTER = "gauge_tank_pointer"  # the visual a main-tank gauge's binding turns
FACE_RADIUS = 0.15  # the dial face inside the bezel
DIAL_RADIUS = FACE_RADIUS * 1.12  # the bezel's outer radius


def pointer_binding(manifest: dict) -> dict | None:
    """The manifest's binding that turns POINTER (a rotation), or None."""
    return next((b for b in manifest.get("bindings", []) if b["target"] == POINTER and b["effect"] == "rotate"), None)


def pointer_angle(level: float, binding: dict) -> float:
    """The pointer's angle (rad) at a tank level: the binding's own clamped linear map
    (ir.StateBinding.output) of its domain onto its range."""
    mapping = ir.StateBinding(binding.get("variable", ""), "rotate", POINTER, tuple(binding["domain"]),
                              tuple(binding["range"]))
    return float(mapping.output(level))


@dataclass(frozen=True)
class Dial:
    """A dial in the world: the pointer's pivot, the plane it turns in and its binding.
    up: the pointer's direction at angle 0; left = axis x up, its direction at +90 deg
    (the binding turns it about `axis`, right-handed; `axis` is the dial's outward
    normal). centre, axis, up, left: (3,)."""

    centre: np.ndarray
    axis: np.ndarray
    up: np.ndarray
    left: np.ndarray
    binding: dict
    face_radius: float = FACE_RADIUS
    rim_radius: float = DIAL_RADIUS

    def direction(self, angle: float) -> np.ndarray:
        return math.cos(angle) * self.up + math.sin(angle) * self.left

    def angle(self, level: float) -> float:
        """The pointer's angle (rad) at a tank level."""
        return pointer_angle(level, self.binding)

    def circle(self, radius: float, n: int = 64) -> np.ndarray:
        """(n, 3) world points on a circle of `radius` about the pivot in the dial's plane."""
        a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
        return self.centre + radius * (np.cos(a)[:, None] * self.up + np.sin(a)[:, None] * self.left)

    def box(self, cam_pose: np.ndarray, k: dict) -> dict:
        """The frame's 2D box of the dial, projected from its rim and clipped to the frame."""
        uv = project(self.circle(self.rim_radius, 32), cam_pose, k)
        if np.isnan(uv).any():
            return {"box": None, "visible": False}
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        clipped = [max(0.0, lo[0]), max(0.0, lo[1]), min(k["width"], hi[0]), min(k["height"], hi[1])]
        inside = bool(lo[0] >= 0 and lo[1] >= 0 and hi[0] <= k["width"] and hi[1] <= k["height"])
        centre = project(self.centre[None, :], cam_pose, k)[0]
        return {"box": [float(v) for v in clipped], "box_unclipped": [float(v) for v in (*lo, *hi)],
                "centre": [float(v) for v in centre], "inside_frame": inside,
                "visible": bool(clipped[2] > clipped[0] and clipped[3] > clipped[1])}


def dial_of(placement_pose: np.ndarray, manifest: dict) -> Dial | None:
    """The dial of a placement whose manifest binds POINTER to a rotation, or None."""
    b = pointer_binding(manifest)
    if b is None:
        return None
    link = next((np.array(r["pose"], float).reshape(4, 4) for r in manifest.get("links", [])
                 if r["name"] == b.get("link")), np.eye(4))
    rest = np.array(b.get("rest_pose") or np.eye(4).reshape(16), float).reshape(4, 4)
    world = placement_pose @ link @ rest
    a = np.asarray(b["axis"], float)
    a /= np.linalg.norm(a)
    y0 = np.array([0.0, 1.0, 0.0]) - a[1] * a  # the pointer's rest direction, in the turning plane
    y0 /= np.linalg.norm(y0)
    r = world[:3, :3]
    axis, up = r @ a, r @ y0
    return Dial(world[:3, 3].copy(), axis, up, np.cross(axis, up), b)


def placed_dial(site, tag: str) -> Dial | None:
    """The dial of placement `tag` of a built site (runtime.site.BuiltSite), or None."""
    p = site.placement(tag)
    return dial_of(site.pose(p), site.manifests.get(p["asset"], {}))
