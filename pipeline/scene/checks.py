"""Placement checks with stable codes (DESIGN.md s.7, the placement group).

PLACE001 unknown asset          PLACE002 duplicate TAG
PLACE003 outside every platform of its level (warning: on a slope)
PLACE004 footprints overlap beyond tolerance
PLACE005 base not on the terrain (over 1 cm)
Each finding is a dict {code, severity, site, message}, sorted for stable reports.
"""

from __future__ import annotations

from collections import Counter

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


def footprint(pose: np.ndarray, bounds) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Oriented footprint: (4, 2) ENU corners, (2, 2) unit edge axes, z interval."""
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    r = pose[:2, :2]
    pts = corners @ r.T + pose[:2, 3]
    z = (pose[2, 3] + lo[2], pose[2, 3] + hi[2])
    return pts, r.T, z


def penetration(a, b) -> float:
    """Smallest overlap depth of two oriented boxes along the separating axes
    (2D edges of both footprints, and z); <= 0 when they do not overlap."""
    depth = min(a[2][1], b[2][1]) - max(a[2][0], b[2][0])
    for axes in (a[1], b[1]):
        for ax in axes:
            pa, pb = a[0] @ ax, b[0] @ ax
            depth = min(depth, min(pa.max(), pb.max()) - max(pa.min(), pb.min()))
    return float(depth)


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

    boxes = [footprint(pl.pose, manifests[pl.placement.asset_id]["bounds"]) for pl in placed
             if pl.placement.asset_id in manifests]
    kept = [pl for pl in placed if pl.placement.asset_id in manifests]
    if boxes:
        lo = np.array([b[0].min(axis=0) for b in boxes])
        hi = np.array([b[0].max(axis=0) for b in boxes])
        order = np.argsort(lo[:, 0])
        for ii, i in enumerate(order):  # sweep along east: only boxes whose x ranges meet
            for j in order[ii + 1:]:
                if lo[j, 0] > hi[i, 0]:
                    break
                if lo[j, 1] > hi[i, 1] or lo[i, 1] > hi[j, 1]:
                    continue
                d = penetration(boxes[i], boxes[j])
                if d > OVERLAP_TOLERANCE_M:
                    a, b = sorted((kept[i].placement.tag, kept[j].placement.tag))
                    out.append(finding("PLACE004", "warning", f"{a}|{b}",
                                       f"footprints of {a} and {b} overlap by {d:.2f} m"))
    return sorted(out, key=lambda f: (f["code"], f["site"]))
