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


def scaled_pose(pl: Placed) -> np.ndarray:
    """(4, 4) float64 model frame -> ENU with the placement's uniform scale applied
    (the pose itself stays rigid: distances and footprints scale the bounds instead)."""
    s = pl.placement.scale
    return pl.pose if s == 1.0 else pl.pose @ np.diag([s, s, s, 1.0])


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


def screen_error_px(error_m, distance_m, hfov_rad: float, width_px: int):
    """Projected size, in pixels, of a geometric error seen at a distance (scalars or
    arrays of one shape; an error seen from distance 0 or less is infinite unless 0)."""
    error_m, distance_m = np.asarray(error_m, dtype=np.float64), np.asarray(distance_m, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = error_m / (2.0 * distance_m * np.tan(hfov_rad / 2.0)) * width_px
    return np.where(distance_m > 0, px, np.where(error_m > 0, np.inf, 0.0))


def choose_lods(placed: list[Placed], manifests: dict[str, dict], eyes: np.ndarray, site: Site) -> list[Placed]:
    """For each placement the coarsest LOD whose measured error, seen from the nearest
    inspection point (to the nearest point of the placement's bounding box), stays
    under the site's screen-space tolerance. No inspection point: LOD 0."""
    if not placed:
        return []
    if len(eyes) == 0:
        return [Placed(pl.placement, pl.pose, pl.yaw, 0, float("inf")) for pl in placed]
    inverse = np.linalg.inv(np.array([pl.pose for pl in placed]))  # (n, 4, 4)
    local = (np.c_[eyes, np.ones(len(eyes))] @ inverse.transpose(0, 2, 1))[:, :, :3]  # (n, eyes, 3)
    assets = [pl.placement.asset_id for pl in placed]
    scale = np.array([pl.placement.scale for pl in placed], dtype=np.float64)
    lo = (np.array([manifests[a]["bounds"][0] for a in assets], dtype=np.float64) * scale[:, None])[:, None]
    hi = (np.array([manifests[a]["bounds"][1] for a in assets], dtype=np.float64) * scale[:, None])[:, None]
    distance = np.linalg.norm(local - np.clip(local, lo, hi), axis=2).min(axis=1)
    level = np.zeros(len(placed), dtype=int)
    names = np.array(assets, dtype=object)
    for asset_id in sorted(set(assets)):
        m = manifests[asset_id]
        of_asset = np.nonzero(names == asset_id)[0]
        for lod in m["lods"]:
            if lod["level"] < len(m["lod_models"]) + 1:
                px = screen_error_px(lod["error_m"] * scale[of_asset], distance[of_asset], site.reference_hfov_rad,
                                     site.reference_width_px)
                level[of_asset] = np.where(px <= site.screen_tolerance_px, lod["level"], level[of_asset])
    return [Placed(pl.placement, pl.pose, pl.yaw, int(k), float(d)) for pl, k, d in zip(placed, level, distance)]
