"""Labels of the conductors, whatever their size on the image: each span an instance of
the category `conductor`, labelled on every pixel its wire covers, even in part, where
nothing in front of it hides it.

The label pass (CyclesScene.render_labels) casts one ray through each pixel's centre,
so it sees a wire thinner than a pixel only on the pixels whose centre it happens to
cross: a 30 mm conductor at 100 m is a dotted line there. Here each span's polylines
(the very curves the renderer draws, render.conductors.Wires) are projected with the
frame's pinhole camera and their footprint rasterized exactly: a subconductor is a
band of half-width f r / d around its projected centreline (the tube's silhouette to
first order in r / d; perspective-correct: 1 / d is affine along a projected segment),
and a pixel is covered when the band meets the pixel's square. A covered pixel is the
wire's when the wire lies in front of what the centre ray hit there (the pass's depth),
the nearest wire where several cover it. Such a pixel's depth becomes the wire's when
the wire is the nearer. Pure numpy: no bpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import labels
from ..render.conductors import Wires
from ..geometry.pinhole import intrinsics

CATEGORY = "conductor"
STEP_PX = 4.0  # projected segments are cut into pieces this long: small windows of candidate pixels
MAX_CANDIDATES = 4_000_000  # pixels tested at once (memory)


@dataclass
class WireLabels:
    """The spans of a site as instances: ids after the placements', sorted by span id."""

    wires: Wires
    ids: dict[str, int]  # span id -> instance id
    ends: dict[str, dict]  # span id -> {"from", "to": "TAG.terminal", "tags": [tag, tag]}

    @classmethod
    def of(cls, wires: Wires | None, placement_ids: dict[str, int]) -> WireLabels | None:
        """None without spans. A span id that is also a placement's tag is refused: an
        instance is named by either."""
        if wires is None:
            return None
        from ..errors import UserError

        first = max(placement_ids.values(), default=0) + 1
        if first + len(wires.spans) - 1 > 65535:
            raise UserError(wires.path, None, f"{first - 1} placements and {len(wires.spans)} spans "
                                              "do not fit a 16-bit mask")
        ids, ends = {}, {}
        for i, s in enumerate(wires.spans):
            if s["id"] in placement_ids:
                raise UserError(wires.path, s["id"], "a span id that is also a placement's tag")
            ids[s["id"]] = first + i
            a, b = s["from"]["terminal"], s["to"]["terminal"]
            ends[s["id"]] = {"from": a, "to": b, "tags": [_tag_of(a, placement_ids), _tag_of(b, placement_ids)]}
        return cls(wires, ids, ends)

    def label(self, ids: np.ndarray, depth: np.ndarray, cam_pose: np.ndarray, hfov: float, near: float,
              far: float, temperature_c: float | dict | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The label pass's (instance ids (h, w) uint16, planar depth (h, w) float32)
        with every span's covered, unhidden pixels set to its id (copies)."""
        h, w = ids.shape
        k = intrinsics(hfov, w, h)
        pix, iid, dist, radius = [], [], [], []
        for sid, paths in self.wires.paths(temperature_c).items():
            r = self.wires.radius(self.wires.span(sid))
            for p in paths:
                if outside_view(p, r, cam_pose, k, near, far):
                    continue
                cols, rows, d = coverage(p, r, cam_pose, k, near, far)
                pix.append(rows * w + cols)
                iid.append(np.full(len(d), self.ids[sid], np.int64))
                dist.append(d)
                radius.append(np.full(len(d), r))
        ids, depth = ids.copy(), depth.copy()
        if not pix:
            return ids, depth
        pix, iid, dist, radius = (np.concatenate(v) for v in (pix, iid, dist, radius))
        flat_ids, flat_depth = ids.reshape(-1), depth.reshape(-1)
        # the wire's near side in front of what the centre ray hit (its own wire is no cover)
        seen = (flat_ids[pix] == iid) | (dist - radius < flat_depth[pix])
        pix, iid, dist = pix[seen], iid[seen], dist[seen]
        if len(pix) == 0:
            return ids, depth
        order = np.lexsort((iid, dist, pix))  # per pixel the nearest wire first
        pix, iid, dist = pix[order], iid[order], dist[order]
        first = np.r_[True, pix[1:] != pix[:-1]]
        pix, iid, dist = pix[first], iid[first], dist[first]
        flat_ids[pix] = iid
        flat_depth[pix] = np.minimum(flat_depth[pix], dist).astype(np.float32)
        return ids, depth

    def tags(self) -> dict[int, str]:
        """instance id -> span id (the annotation's `tag`)."""
        return {v: k for k, v in self.ids.items()}

    def describe(self, annotations: list[dict]) -> list[dict]:
        """The annotations with each conductor's span and its two ends added."""
        spans = self.tags()
        out = []
        for a in annotations:
            sid = spans.get(a["instance_id"])
            out.append(a if sid is None else {**a, "span": sid, **self.ends[sid]})
        return out

    def record(self, ids: np.ndarray, temperature_c: float | dict | None) -> dict:
        """The frame record's `conductors`: the temperature drawn (one, or per conductor
        type, None for a type as built) and where it comes from (the frame's state, or
        the built scene's: None if its spans differ), and the spans the frame shows,
        with their pixel counts."""
        spans = self.tags()
        present, counts = np.unique(ids[ids >= min(spans)], return_counts=True)
        built = {float(s["temperature_c"]) for s in self.wires.spans}
        drawn = temperature_c if temperature_c is not None else (built.pop() if len(built) == 1 else None)
        return {"temperature_c": drawn, "temperature_from": "built scene" if temperature_c is None else "state",
                "spans": [{"instance_id": int(i), "span": spans[int(i)], **self.ends[spans[int(i)]], "pixels": int(n)}
                          for i, n in zip(present, counts) if int(i) in spans]}


def category(categories: list[dict]) -> dict:
    """The `conductor` category: appended after the equipment's (their ids unchanged),
    or theirs when an asset's category is already named so."""
    same = [c for c in categories if c["name"] == CATEGORY]
    if same:
        return same[0]
    return {"id": max((c["id"] for c in categories), default=0) + 1, "name": CATEGORY, "supercategory": CATEGORY}


def _tag_of(terminal: str, tags: dict[str, int]) -> str | None:
    """The placement a `TAG.terminal` end belongs to: the longest tag before a dot
    (tags and terminal names may hold dots themselves)."""
    best = None
    for i, ch in enumerate(terminal):
        if ch == "." and terminal[:i] in tags:
            best = terminal[:i]
    return best


# --- hooks: where datasets.run opens a scene, labels a frame and writes its record ------


def attach(ctx: dict) -> dict:
    """An open_scene context with its scene's spans as instances (ids, names and the
    `conductor` category; ctx["wires"], None without spans)."""
    scene = ctx["scene"]
    wires = WireLabels.of(scene.wires.wires if scene.wires is not None else None, ctx["ids"])
    ctx["wires"] = wires
    if wires is not None:
        scene.wires.set_instances(wires.ids)
        cid = category(labels.categories(ctx["site"].manifests))["id"]
        ctx["tag_of"] = {**ctx["tag_of"], **wires.tags()}
        ctx["category_of"] = {**ctx["category_of"], **dict.fromkeys(wires.ids, cid)}
    return ctx


def categories(site, equipment: list[dict]) -> list[dict]:
    """COCO categories: the equipment's (labels.categories), then `conductor` when the
    site has spans. Its id follows theirs, so a site without spans keeps its ids."""
    from ..render.conductors import load

    if load(site.build) is None or any(c["name"] == CATEGORY for c in equipment):
        return equipment
    return [*equipment, category(equipment)]


def label_frame(ctx: dict, shot, ids: np.ndarray, depth: np.ndarray,
                parts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The label pass's ids, depth and part ids with the frame's spans rasterized in
    (a wire's pixel is no part); unchanged without spans."""
    wires = ctx.get("wires")
    if wires is None:
        return ids, depth, parts
    out_ids, out_depth = wires.label(ids, depth, shot.cam_pose, shot.lens.hfov, shot.lens.near, shot.lens.far,
                                     shot.conductor_temperature_c)
    return out_ids, out_depth, np.where(out_ids != ids, 0, parts).astype(parts.dtype)


def add_to_record(ctx: dict, record: dict, ids: np.ndarray, shot) -> dict:
    """A frame record with its conductors' annotations described (span and ends) and
    its `conductors` entry (unchanged without spans)."""
    wires = ctx.get("wires")
    if wires is None:
        return record
    return {**record, "annotations": wires.describe(record["annotations"]),
            "conductors": wires.record(ids, shot.conductor_temperature_c)}


# --- geometry: the footprint of a projected wire ----------------------------------------


def coverage(points: np.ndarray, radius: float, pose: np.ndarray, k: dict, near: float,
             far: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels a wire of `radius` along `points: (n, 3)` ENU covers, even in part, on
    the image of the camera at `pose` (world-from-camera, looking down -Z) with
    intrinsics `k`, between the `near` and `far` planes. Returns (cols, rows, depth),
    each (m,), one entry per (pixel, piece of the wire) that covers it (a pixel can
    repeat): the planar depth is the wire's centreline at the point of the piece
    nearest the pixel."""
    a, b, inv_a, inv_b = _project_segments(np.asarray(points, float), pose, k, near, far)
    if len(a) == 0:
        return _nothing()
    a, b, inv_a, inv_b = _split(a, b, inv_a, inv_b, STEP_PX)
    f = k["fx"]
    half_a, half_b = f * radius * inv_a, f * radius * inv_b
    reach = np.maximum(half_a, half_b)
    lo = np.floor(np.minimum(a, b) - reach[:, None]).astype(np.int64)
    hi = np.floor(np.maximum(a, b) + reach[:, None]).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [k["width"] - 1, k["height"] - 1])
    keep = (hi >= lo).all(axis=1)
    out = ([], [], [])
    idx = np.flatnonzero(keep)
    sizes = (hi[idx, 0] - lo[idx, 0] + 1) * (hi[idx, 1] - lo[idx, 1] + 1)
    start = 0
    while start < len(idx):  # in batches of at most MAX_CANDIDATES pixels (one piece at least)
        stop = start + max(1, int(np.searchsorted(np.cumsum(sizes[start:]), MAX_CANDIDATES, side="right")))
        sel = idx[start:stop]
        cols, rows, depth = _covered(a[sel], b[sel], inv_a[sel], inv_b[sel], half_a[sel], half_b[sel],
                                     lo[sel], hi[sel])
        for acc, v in zip(out, (cols, rows, depth)):
            acc.append(v)
        start = stop
    return tuple(np.concatenate(v) for v in out) if out[0] else _nothing()


def outside_view(points: np.ndarray, radius: float, pose: np.ndarray, k: dict, near: float, far: float) -> bool:
    """Whether `coverage` of this wire is certainly empty, at a fraction of its cost
    (most of a site's spans are out of a close-up's view): every point of the
    centreline nearer than `near`, or farther than `far`, or more than `radius` beyond
    one of the four planes through the lens and the image's edges. Each is a
    half-space, so the whole polyline and its band of half-width f r / d lie outside
    the image with its points."""
    cam = (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]
    x, y, depth = cam[:, 0], cam[:, 1], -cam[:, 2]
    if (depth < near).all() or (depth > far).all():
        return True
    # plane through the lens and the image edge u = edge: x = depth (edge - cx) / fx
    for coord, f, centre, edges in ((x, k["fx"], k["cx"], (0.0, k["width"])),
                                    (-y, k["fy"], k["cy"], (0.0, k["height"]))):
        for edge, side in ((edges[0], -1.0), (edges[1], 1.0)):
            slope = (edge - centre) / f
            if (side * (coord - depth * slope) > radius * np.hypot(1.0, slope)).all():
                return True
    return False


def _nothing() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)


def _project_segments(points: np.ndarray, pose: np.ndarray, k: dict, near: float, far: float):
    """The polyline's segments clipped to near <= depth <= far and projected: ends
    (m, 2) pixel coordinates (u right, v down) and their inverse depths (m,)."""
    cam = (points - pose[:3, 3]) @ pose[:3, :3]
    p, q = cam[:-1], cam[1:]
    dp, dq = -p[:, 2], -q[:, 2]
    t0, t1 = np.zeros(len(p)), np.ones(len(p))
    for bound, sign in ((near, 1.0), (far, -1.0)):  # keep sign * (depth - bound) >= 0
        fp, fq = sign * (dp - bound), sign * (dq - bound)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = fp / (fp - fq)
        t0 = np.where((fp < 0) & (fq >= 0), np.maximum(t0, t), t0)
        t1 = np.where((fp >= 0) & (fq < 0), np.minimum(t1, t), t1)
        gone = (fp < 0) & (fq < 0)
        t0, t1 = np.where(gone, 1.0, t0), np.where(gone, 0.0, t1)
    keep = t0 < t1
    p, q, t0, t1 = p[keep], q[keep], t0[keep, None], t1[keep, None]
    p, q = p + t0 * (q - p), p + t1 * (q - p)
    uv = []
    for c in (p, q):
        d = -c[:, 2]
        uv.append((np.c_[k["cx"] + k["fx"] * c[:, 0] / d, k["cy"] - k["fy"] * c[:, 1] / d], 1.0 / d))
    return uv[0][0], uv[1][0], uv[0][1], uv[1][1]


def _split(a, b, inv_a, inv_b, step: float):
    """Each projected segment cut into pieces at most `step` pixels long (the inverse
    depth interpolated linearly on the image, as perspective has it)."""
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step)).astype(np.int64)
    seg = np.repeat(np.arange(len(a)), n)
    i = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    s0, s1 = (i / n[seg])[:, None], ((i + 1) / n[seg])[:, None]
    d, di = b - a, inv_b - inv_a
    return (a[seg] + s0 * d[seg], a[seg] + s1 * d[seg], inv_a[seg] + s0[:, 0] * di[seg],
            inv_a[seg] + s1[:, 0] * di[seg])


def _covered(a, b, inv_a, inv_b, half_a, half_b, lo, hi):
    """Candidate pixels of each piece (its window lo..hi, inclusive) whose square the
    piece's band meets: (cols, rows, depth)."""
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    counts = nx * ny
    piece = np.repeat(np.arange(len(a)), counts)
    j = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    cols = lo[piece, 0] + j % nx[piece]
    rows = lo[piece, 1] + j // nx[piece]
    dist, s = square_distance(a[piece], b[piece], cols, rows)
    half = half_a[piece] + s * (half_b[piece] - half_a[piece])
    hit = dist < half
    inv = inv_a[piece] + s * (inv_b[piece] - inv_a[piece])
    return cols[hit], rows[hit], 1.0 / inv[hit]


def square_distance(a: np.ndarray, b: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance between segments a-b (each (m, 2)) and the pixel squares [col, col+1] x
    [row, row+1], and the parameter s in [0, 1] of the segment's nearest point (the
    middle of the part inside the square when they meet)."""
    d = b - a
    box_lo = np.c_[cols, rows].astype(float)
    box_hi = box_lo + 1.0
    # Liang-Barsky: the part of the segment inside the closed square
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    for axis in (0, 1):
        da = d[:, axis]
        flat = np.abs(da) < 1e-15
        with np.errstate(divide="ignore", invalid="ignore"):
            e0 = (box_lo[:, axis] - a[:, axis]) / da
            e1 = (box_hi[:, axis] - a[:, axis]) / da
        enter, leave = np.minimum(e0, e1), np.maximum(e0, e1)
        outside = flat & ((a[:, axis] < box_lo[:, axis]) | (a[:, axis] > box_hi[:, axis]))
        t0 = np.where(flat, t0, np.maximum(t0, enter))
        t1 = np.where(flat, np.where(outside, -1.0, t1), np.minimum(t1, leave))
    meets = t0 <= t1
    best = np.where(meets, 0.0, np.inf)
    s = np.where(meets, (t0 + t1) / 2.0, 0.0)
    # apart: the nearest of the ends to the square and the corners to the segment
    for end, at in ((a, 0.0), (b, 1.0)):
        gap = np.linalg.norm(np.maximum(0.0, np.maximum(box_lo - end, end - box_hi)), axis=1)
        better = gap < best
        best, s = np.where(better, gap, best), np.where(better, at, s)
    length2 = np.einsum("ij,ij->i", d, d)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        corner = box_lo + [dx, dy]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.einsum("ij,ij->i", corner - a, d) / length2, 0.0, 1.0)
        t = np.where(length2 > 0, t, 0.0)
        gap = np.linalg.norm(a + t[:, None] * d - corner, axis=1)
        better = gap < best
        best, s = np.where(better, gap, best), np.where(better, t, s)
    return best, s
