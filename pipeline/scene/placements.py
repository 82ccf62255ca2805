"""Placements on the globe: ENU poses, LOD choice from the inspection points.

Poses are float64 4x4 matrices in the scene frame (local ENU at the site origin).
A placement's position is the exact topocentric ENU of its geodetic point (height =
level elevation + INSERT z); its orientation is a yaw about the ENU up axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import ir
from ..config import Site


@dataclass(frozen=True, eq=False)
class Placed:
    """A placement with its world pose and chosen LOD.

    pose: (4, 4) float64, model frame -> ENU scene frame.
    """

    placement: ir.Placement
    pose: np.ndarray
    yaw: float
    lod: int = 0
    distance_m: float = float("inf")


def yaw_matrix(yaw: float, position) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = position
    return m


def place(site: Site, placements: list[ir.Placement], georef) -> list[Placed]:
    """ENU poses of every placement, vectorised through the georeferencer."""
    if not placements:
        return []
    xy = np.array([[p.x, p.y] for p in placements], dtype=np.float64)
    h = np.array([site.level(p.level).elevation + p.z for p in placements], dtype=np.float64)
    enu = georef.to_enu(xy, h)
    yaws = georef.headings(xy, np.array([p.heading_deg for p in placements], dtype=np.float64))
    return [Placed(p, yaw_matrix(float(y), e), float(y)) for p, e, y in zip(placements, enu, yaws)]


def inspection_points_enu(site: Site, georef) -> np.ndarray:
    """(k, 3) float64 ENU of the inspection points (z is above their level)."""
    pts = site.inspection_points
    if not pts:
        return np.zeros((0, 3))
    xy = np.array([p.position[:2] for p in pts], dtype=np.float64)
    h = np.array([site.level(p.level).elevation + p.position[2] for p in pts], dtype=np.float64)
    return georef.to_enu(xy, h)


def screen_error_px(error_m: float, distance_m: float, hfov_rad: float, width_px: int) -> float:
    """Projected size, in pixels, of a geometric error seen at a distance."""
    if distance_m <= 0:
        return float("inf") if error_m > 0 else 0.0
    return error_m / (2.0 * distance_m * np.tan(hfov_rad / 2.0)) * width_px


def choose_lods(placed: list[Placed], manifests: dict[str, dict], eyes: np.ndarray, site: Site) -> list[Placed]:
    """For each placement the coarsest LOD whose measured error, seen from the nearest
    inspection point (to the nearest point of the placement's bounding box), stays
    under the site's screen-space tolerance. No inspection point: LOD 0."""
    if not placed:
        return []
    if len(eyes) == 0:
        return [Placed(pl.placement, pl.pose, pl.yaw, 0, float("inf")) for pl in placed]
    inverse = np.linalg.inv(np.array([pl.pose for pl in placed]))  # (n, 4, 4)
    eyes_h = np.c_[eyes, np.ones(len(eyes))]
    out = []
    for pl, to_local in zip(placed, inverse):
        m = manifests[pl.placement.asset_id]
        lo, hi = np.array(m["bounds"][0]), np.array(m["bounds"][1])
        local = (eyes_h @ to_local.T)[:, :3]
        nearest = np.clip(local, lo, hi)
        d = float(np.min(np.linalg.norm(local - nearest, axis=1)))
        level = 0
        for lod in m["lods"]:
            px = screen_error_px(lod["error_m"], d, site.reference_hfov_rad, site.reference_width_px)
            if px <= site.screen_tolerance_px and lod["level"] < len(m["lod_models"]) + 1:
                level = lod["level"]
        out.append(Placed(pl.placement, pl.pose, pl.yaw, level, d))
    return out
