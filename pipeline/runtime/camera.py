"""The study's device-agnostic camera: zoom -> field of view and clip planes
(PAPER_NOTES.md, "Camera"). z <= 10 is optical zoom, z > 10 digital."""

from __future__ import annotations

from dataclasses import dataclass

FOV_BASE = 1.047  # rad, horizontal FOV at 1x (phone main camera)
ZOOM_MIN, ZOOM_MAX = 1.0, 100.0
OPTICAL_MAX = 10.0


@dataclass(frozen=True)
class Lens:
    zoom: float
    hfov: float  # rad
    near: float  # m
    far: float  # m
    optical: bool


def lens(zoom: float, fov_base: float = FOV_BASE) -> Lens:
    """Lens state at zoom z in [1, 100]; ValueError outside (callers name the node)."""
    z = float(zoom)
    if not ZOOM_MIN <= z <= ZOOM_MAX:  # also rejects NaN
        raise ValueError(f"zoom {zoom!r} is outside [{ZOOM_MIN:g}, {ZOOM_MAX:g}]")
    if z > OPTICAL_MAX:
        near, far = 0.1 + 0.01 * (z - OPTICAL_MAX), 1000.0 - 10.0 * (z - OPTICAL_MAX)
    else:
        near, far = 0.1, 1000.0
    return Lens(z, fov_base / z, near, far, z <= OPTICAL_MAX)
