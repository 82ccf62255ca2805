"""Placement checks with stable codes (DESIGN.md s.7, the placement group).

PLACE001 unknown asset          PLACE002 duplicate TAG
PLACE003 outside every platform of its level (warning: on a slope)
PLACE004 footprints overlap beyond tolerance
PLACE005 base not on the terrain (over 1 cm)
Each finding is a dict {code, severity, site, message}, sorted for stable reports.
"""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np

from .. import ir

OVERLAP_TOLERANCE_M = 0.10
BASE_TOLERANCE_M = 0.01


def finding(code: str, severity: str, site: str, message: str) -> dict:
    return {"code": code, "severity": severity, "site": site, "message": message}


def point_in_polygon(p: np.ndarray, poly: np.ndarray) -> bool:
    """Even-odd rule. p: (2,), poly: (k, 2); points on an edge count as inside."""
    return bool(points_in_polygon(np.asarray(p, dtype=np.float64).reshape(1, 2), poly)[0])


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule for many points at once. points: (n, 2), poly: (k, 2);
    returns (n,) bool, points on an edge inside."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    poly = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    x, y = points[:, 0:1], points[:, 1:2]  # (n, 1) against the (k,) edges
    x1, y1 = poly[:, 0], poly[:, 1]
    x2, y2 = np.roll(x1, -1), np.roll(y1, -1)
    within = ((np.minimum(y1, y2) <= y) & (y <= np.maximum(y1, y2))
              & (np.minimum(x1, x2) <= x) & (x <= np.maximum(x1, x2)))
    cross = (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)
    on_edge = (within & (np.abs(cross) < 1e-9 * np.maximum(1.0, np.abs(x2 - x1) + np.abs(y2 - y1)))).any(axis=1)
    straddles = (y1 > y) != (y2 > y)
    dy = np.where(y2 != y1, y2 - y1, 1.0)
    crossings = (straddles & (x < x1 + (y - y1) * (x2 - x1) / dy)).sum(axis=1)
    return on_edge | (crossings % 2 == 1)


class Footprints(NamedTuple):
    """Oriented footprints of n placements: corners (n, 4, 2) ENU, unit edge axes
    (n, 2, 2) (row k the k-th axis), z intervals (n, 2)."""

    corners: np.ndarray
    axes: np.ndarray
    z: np.ndarray

    def take(self, index: np.ndarray) -> Footprints:
        return Footprints(self.corners[index], self.axes[index], self.z[index])


def footprints(poses: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> Footprints:
    """poses: (n, 4, 4); lo, hi: (n, 3) model-frame bounds of each placement's model."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1, 3), np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    corners = np.stack([lo[:, :2], np.c_[hi[:, 0], lo[:, 1]], hi[:, :2], np.c_[lo[:, 0], hi[:, 1]]], axis=1)
    r = poses[:, :2, :2]
    axes = r.transpose(0, 2, 1)
    pts = corners @ axes + poses[:, None, :2, 3]
    z = poses[:, 2, 3:4] + np.c_[lo[:, 2], hi[:, 2]]
    return Footprints(pts, axes, z)


def penetrations(a: Footprints, b: Footprints) -> np.ndarray:
    """Smallest overlap depth of each pair of oriented boxes a[k], b[k] along the
    separating axes (2D edges of both footprints, and z); <= 0 where they do not
    overlap. Returns (n,)."""
    depth = np.minimum(a.z[:, 1], b.z[:, 1]) - np.maximum(a.z[:, 0], b.z[:, 0])
    for axes in (a.axes, b.axes):
        for k in range(2):
            ax = axes[:, k, None, :]  # (n, 1, 2) against the (n, 4, 2) corners
            pa, pb = (a.corners * ax).sum(axis=2), (b.corners * ax).sum(axis=2)
            overlap = np.minimum(pa.max(axis=1), pb.max(axis=1)) - np.maximum(pa.min(axis=1), pb.min(axis=1))
            depth = np.minimum(depth, overlap)
    return depth


def box_pairs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i != j each pair once, of the axis-aligned boxes lo, hi:
    (n, 2) that meet: a sweep along x (each box against those starting before it
    ends), then the y ranges."""
    order = np.argsort(lo[:, 0], kind="stable")
    starts = lo[order, 0]
    ends = np.searchsorted(starts, hi[order, 0], side="right")  # > its own position
    first = np.arange(1, len(order) + 1)
    counts = np.maximum(ends - first, 0)
    i = np.repeat(order, counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    j = order[np.repeat(first, counts) + offsets]
    meet = (lo[j, 1] <= hi[i, 1]) & (lo[i, 1] <= hi[j, 1])
    return i[meet], j[meet]


def check_placements(site, fp: ir.FloorPlan, placed, manifests: dict[str, dict], terrain_z: np.ndarray) -> list[dict]:
    out: list[dict] = []
    for tag, n in sorted(Counter(p.tag for p in fp.placements).items()):
        if n > 1:
            out.append(finding("PLACE002", "error", tag, f"TAG used by {n} placements"))
    for p in fp.placements:
        if p.asset_id not in manifests:
            out.append(finding("PLACE001", "error", p.tag, f"block {p.asset_id!r} is no known asset"))

    platforms: dict[str, list[np.ndarray]] = {}
    for pf in fp.platforms:
        platforms.setdefault(pf.level, []).append(np.asarray(pf.outline))
    on_platform = np.zeros(len(placed), dtype=bool)
    plan_xy = np.array([[pl.placement.x, pl.placement.y] for pl in placed]).reshape(-1, 2)
    levels = np.array([pl.placement.level for pl in placed], dtype=object)
    for level, outlines in platforms.items():
        on_level = np.nonzero(levels == level)[0]
        for poly in outlines:
            on_platform[on_level] |= points_in_polygon(plan_xy[on_level], poly)
    for pl, inside in zip(placed, on_platform):
        p = pl.placement
        if not inside:
            out.append(finding("PLACE003", "warning", p.tag,
                               f"at plan ({p.x:.3f}, {p.y:.3f}) outside every PLATFORM_{p.level} outline"
                               f" (standing {p.z:.3f} m above {p.level} on the slope or ground)"))

    for pl, tz, inside in zip(placed, terrain_z, on_platform):
        p = pl.placement
        # On its platform, INSERT z is a plinth or support height: the foot is at the
        # level. Off the platform (on a slope) INSERT z lifts the foot onto the terrain.
        base = pl.pose[2, 3] - p.z if inside else pl.pose[2, 3]
        if not np.isfinite(tz):
            out.append(finding("PLACE005", "error", p.tag, "no terrain under the placement"))
        elif abs(base - tz) > BASE_TOLERANCE_M:
            out.append(finding("PLACE005", "error", p.tag,
                               f"base at z={base:.4f} m, terrain at {tz:.4f} m ({abs(base - tz) * 1000:.1f} mm apart)"))

    kept = [pl for pl in placed if pl.placement.asset_id in manifests]
    if kept:
        bounds = np.array([manifests[pl.placement.asset_id]["bounds"] for pl in kept], dtype=np.float64)
        boxes = footprints(np.array([pl.pose for pl in kept]), bounds[:, 0], bounds[:, 1])
        i, j = box_pairs(boxes.corners.min(axis=1), boxes.corners.max(axis=1))
        depth = penetrations(boxes.take(i), boxes.take(j))
        for first, second, d in zip(i, j, depth):
            if d > OVERLAP_TOLERANCE_M:
                a, b = sorted((kept[first].placement.tag, kept[second].placement.tag))
                out.append(finding("PLACE004", "warning", f"{a}|{b}", f"footprints of {a} and {b} overlap by {d:.2f} m"))
    return sorted(out, key=lambda f: (f["code"], f["site"]))
