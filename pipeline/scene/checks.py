"""Placement checks with stable codes (DESIGN.md s.7, the placement group).

PLACE001 unknown asset          PLACE002 duplicate TAG
PLACE003 outside every platform of its level (warning: on a slope)
PLACE004 footprints overlap beyond tolerance: one finding per cluster of placements
         that overlap one another (a connected component of the overlap graph)
PLACE005 base not on the terrain (over 1 cm)
The findings are findings.Finding records (severities from findings.RULES), handed on
as dicts sorted for stable reports.
"""

from __future__ import annotations

from collections import Counter
from typing import NamedTuple

import numpy as np

from .. import ir
from ..findings import Finding, finding

OVERLAP_TOLERANCE_M = 0.10
BASE_TOLERANCE_M = 0.01
# A cluster's finding names this many of its placements, then says how many more.
LISTED_TAGS = 5
# Candidate pairs handed on at a time: a pile of placements has as many pairs as the
# square of its size, so they are tested in chunks and the ones already joined skipped.
PAIR_CHUNK = 1 << 16


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


def _grid(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell index ranges (n, 2) int64, first and last, of each box in a uniform grid
    whose cells are the boxes' median size, but at least 1/32 of the largest (no box
    covers more than about 33 x 33 cells) and 2^-20 of the whole span (cell keys stay
    far inside int64)."""
    extent = (hi - lo).max(axis=1)
    span = float((hi.max(axis=0) - lo.min(axis=0)).max())
    size = max(float(np.median(extent)), float(extent.max()) / 32.0, span / 2.0**20)
    if not size > 0.0:
        size = 1.0  # points only: any cell size holds them
    origin = lo.min(axis=0)
    return np.floor((lo - origin) / size).astype(np.int64), np.floor((hi - origin) / size).astype(np.int64)


def box_pair_chunks(lo: np.ndarray, hi: np.ndarray, chunk: int = PAIR_CHUNK):
    """Index pairs (i, j), i != j each pair once, of the axis-aligned boxes lo, hi:
    (n, 2) that meet, as a run of (i, j) arrays from about `chunk` candidates each.

    A uniform grid (_grid) holds each box in every cell it covers; the boxes sharing
    a cell are the candidates, and a pair is kept in one cell only: the cell of its
    overlap's lower corner (the larger of the two boxes' first cells)."""
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1, 2), np.asarray(hi, dtype=np.float64).reshape(-1, 2)
    if len(lo) < 2:
        return
    first, last = _grid(lo, hi)
    wide = last - first + 1
    covered = wide[:, 0] * wide[:, 1]
    box = np.repeat(np.arange(len(lo)), covered)
    k = np.arange(len(box)) - np.repeat(np.cumsum(covered) - covered, covered)
    cell = first[box] + np.c_[k % wide[box, 0], k // wide[box, 0]]
    key = cell[:, 0] * (int(last[:, 1].max()) + 1) + cell[:, 1]
    order = np.argsort(key, kind="stable")
    box, cell, key = box[order], cell[order], key[order]
    ends = np.searchsorted(key, key, side="right")  # one past each entry's cell group
    after = ends - np.arange(len(key)) - 1  # the entries after each one in its cell
    bounds = np.searchsorted(np.cumsum(after), np.arange(chunk, int(after.sum()) + chunk, chunk), side="right")
    start = 0
    for stop in np.minimum(np.r_[bounds, len(key)], len(key)):
        if stop <= start:
            continue
        p = np.repeat(np.arange(start, stop), after[start:stop])
        q = p + 1 + np.arange(len(p)) - np.repeat(np.cumsum(after[start:stop]) - after[start:stop], after[start:stop])
        i, j = box[p], box[q]
        keep = ((lo[j] <= hi[i]) & (lo[i] <= hi[j])).all(axis=1)
        keep &= (np.maximum(first[i], first[j]) == cell[p]).all(axis=1)
        yield i[keep], j[keep]
        start = stop


def overlap_clusters(boxes: Footprints, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The connected components of the overlap graph of n footprints (an edge where two
    overlap by more than `tolerance`): a label (n,) int per footprint, shared by the
    members of a component, and the depth (n,) of the deepest overlap tested within
    each label's component (0 where none). A pair whose footprints are already joined
    is not tested, so a component of two has its depth and a larger one a lower bound."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(boxes.corners)
    label = np.arange(n)
    deepest = np.zeros(n)
    for i, j in box_pair_chunks(boxes.corners.min(axis=1), boxes.corners.max(axis=1)):
        apart = label[i] != label[j]
        i, j = i[apart], j[apart]
        depth = penetrations(boxes.take(i), boxes.take(j))
        hit = depth > tolerance
        if not hit.any():
            continue
        edges = coo_matrix((np.ones(int(hit.sum())), (label[i[hit]], label[j[hit]])), shape=(n, n))
        joined = connected_components(edges, directed=False)[1]
        merged = np.zeros(n)
        np.maximum.at(merged, joined, deepest)
        np.maximum.at(merged, joined[label[i[hit]]], depth[hit])
        label, deepest = joined[label], merged
    return label, deepest[label]


def check_placements(site, fp: ir.FloorPlan, placed, manifests: dict[str, dict], terrain_z: np.ndarray) -> list[dict]:
    """The placement findings as placements.json holds them (Finding.as_dict), sorted
    by code, then site."""
    out: list[Finding] = []
    for tag, n in sorted(Counter(p.tag for p in fp.placements).items()):
        if n > 1:
            out.append(finding("PLACE002", tag, f"TAG used by {n} placements"))
    for p in fp.placements:
        if p.asset_id not in manifests:
            out.append(finding("PLACE001", p.tag, f"block {p.asset_id!r} is no known asset"))

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
            out.append(finding("PLACE003", p.tag,
                               f"at plan ({p.x:.3f}, {p.y:.3f}) outside every PLATFORM_{p.level} outline"
                               f" (standing {p.z:.3f} m above {p.level} on the slope or ground)"))

    for pl, tz, inside in zip(placed, terrain_z, on_platform):
        p = pl.placement
        # On its platform, INSERT z is a plinth or support height: the foot is at the
        # level. Off the platform (on a slope) INSERT z lifts the foot onto the terrain.
        base = pl.pose[2, 3] - p.z if inside else pl.pose[2, 3]
        if not np.isfinite(tz):
            out.append(finding("PLACE005", p.tag, "no terrain under the placement"))
        elif abs(base - tz) > BASE_TOLERANCE_M:
            out.append(finding("PLACE005", p.tag,
                               f"base at z={base:.4f} m, terrain at {tz:.4f} m ({abs(base - tz) * 1000:.1f} mm apart)"))

    kept = [pl for pl in placed if pl.placement.asset_id in manifests]
    if kept:
        bounds = np.array([manifests[pl.placement.asset_id]["bounds"] for pl in kept], dtype=np.float64)
        bounds *= np.array([pl.placement.scale for pl in kept], dtype=np.float64)[:, None, None]
        poses = np.array([pl.pose for pl in kept])
        label, depth = overlap_clusters(footprints(poses, bounds[:, 0], bounds[:, 1]), OVERLAP_TOLERANCE_M)
        out += _overlap_findings([pl.placement.tag for pl in kept], poses[:, :3, 3], label, depth)
    return [f.as_dict() for f in sorted(out, key=lambda f: (f.code, f.site))]


def _overlap_findings(tags: list[str], positions: np.ndarray, label: np.ndarray,
                      depth: np.ndarray) -> list[Finding]:
    """One PLACE004 per cluster of two or more (overlap_clusters' labels): a pair with
    its depth, a larger cluster with its size, how many of it share one point (blocks
    inserted at one spot), and its first tags."""
    out = []
    order = np.argsort(label, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(label[order])) + 1)
    for members in (g for g in groups if len(g) > 1):
        names = sorted(tags[m] for m in members)
        if len(names) == 2:
            a, b = names
            out.append(finding("PLACE004", f"{a}|{b}",
                               f"footprints of {a} and {b} overlap by {depth[members[0]]:.2f} m"))
            continue
        n, shown = len(names), names[:LISTED_TAGS]
        spots = np.unique(np.round(positions[members] * 1000.0), axis=0, return_counts=True)[1]
        piled = f"; {spots.max()} of them at one point" if spots.max() > 1 else ""
        more = f" and {n - len(shown)} more" if n > len(shown) else ""
        site = "|".join(names[:3]) + (f"|and {n - 3} more" if n > 3 else "")
        out.append(finding("PLACE004", site,
                           f"footprints of {n} placements overlap, each by more than {OVERLAP_TOLERANCE_M:.2f} m "
                           f"with one or more of the others{piled}: {', '.join(shown)}{more}"))
    return out
