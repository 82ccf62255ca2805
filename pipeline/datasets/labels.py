"""Per-frame ground truth from the renderer's own passes: COCO instance annotations
(RLE masks, tight boxes, pixel areas) from the instance-id image, gauge visibility and
keypoints from the ids and the depth at the dial's centre, and whether the sensor's
clipped pixels cover a gauge's pointer (the parts: parts.py). Pure numpy, OpenCV and
pycocotools: no bpy."""

from __future__ import annotations

import numpy as np

from ..perception.gauge import Dial
from ..perception.gauge_reader import POINTER_OUTLINE
from ..geometry.pinhole import project

# a dial is visible when the surface at its centre's pixel is its own placement's and
# lies within this distance of the dial's centre along the view (the gauge glass, the
# bezel's depth)
DIAL_DEPTH_TOLERANCE_M = 0.25

# glare hides a pointer when the sensor clipped at least this share of its pixels: a
# reader sees a white blot there, not a dark line
GLARE_HIDES_SHARE = 0.5

# a gauge's keypoints, in COCO's order: the pointer's pivot, its tip (the authored
# pointer's length), and the scale's ends on the tip's circle
KEYPOINTS = ("dial_centre", "pointer_tip", "scale_start", "scale_end")
TIP_RADIUS = float(POINTER_OUTLINE[:, 1].max())


def instance_ids(placements: list[dict]) -> dict[str, int]:
    """A placement's instance id (its value in every mask): 1 + its rank among the
    tags, so a tag has the same id in every frame and every run of a site."""
    tags = sorted(p["tag"] for p in placements)
    if len(tags) >= 65535:
        raise ValueError(f"{len(tags)} placements do not fit a 16-bit mask")
    return {t: i + 1 for i, t in enumerate(tags)}


def categories(manifests: dict[str, dict]) -> list[dict]:
    """COCO categories: the assets' categories, sorted, ids from 1 (terrain excluded:
    ground is background, not an instance)."""
    names = sorted({m.get("category") or m["asset"] for m in manifests.values() if m.get("category") != "terrain"})
    return [{"id": i + 1, "name": n, "supercategory": "equipment"} for i, n in enumerate(names)]


def annotations(ids: np.ndarray, tag_of: dict[int, str], category_of: dict[str, int]) -> list[dict]:
    """One annotation per instance id present in `ids` (0 = background), in id order:
    RLE of exactly its pixels, its tight box [x, y, w, h] and its pixel count."""
    from pycocotools import mask as rle

    out = []
    present = np.unique(ids)
    for iid in present[present > 0]:
        binary = np.asfortranarray((ids == iid).astype(np.uint8))
        code = rle.encode(binary)
        rows, cols = np.nonzero(binary)
        x0, y0 = int(cols.min()), int(rows.min())
        tag = tag_of[int(iid)]
        out.append({"instance_id": int(iid), "tag": tag, "category_id": category_of[tag],
                    "segmentation": {"size": [int(v) for v in code["size"]], "counts": code["counts"].decode("ascii")},
                    "area": int(rows.size), "bbox": [x0, y0, int(cols.max()) - x0 + 1, int(rows.max()) - y0 + 1],
                    "iscrowd": 0})
    return out


def gauge_visibility(dial: Dial, cam_pose: np.ndarray, k: dict, ids: np.ndarray, depth: np.ndarray,
                     instance: int) -> dict:
    """Is `dial` (its placement's, gauge.dial_of) seen in this frame: its centre
    in the frame and facing the camera, on a pixel of its own instance, at the dial's
    depth (not hidden behind something of its own, such as the tank seen from behind)."""
    centre = dial.centre
    u, v = project(centre[None, :], cam_pose, k)[0]
    facing = float(dial.axis @ (cam_pose[:3, 3] - centre)) > 0.0
    record = {"centre_px": None if np.isnan(u) else [float(u), float(v)], "visible": False}
    if np.isnan(u) or not (0 <= u < k["width"] and 0 <= v < k["height"]):
        return record
    row, col = int(v), int(u)
    expected = float(-(centre - cam_pose[:3, 3]) @ cam_pose[:3, 2])  # planar depth of the centre
    record["visible"] = bool(facing and ids[row, col] == instance
                             and abs(float(depth[row, col]) - expected) <= DIAL_DEPTH_TOLERANCE_M)
    return record


def pointer_pixels(dial: Dial, angle: float, cam_pose: np.ndarray, k: dict) -> np.ndarray:
    """(h, w) bool: the pixels the pointer's outline (gauge_reader.POINTER_OUTLINE) at
    `angle` covers, projected; at least the pixel of its middle when it projects
    smaller than a pixel. Empty when the pointer is behind the camera or off the frame."""
    import cv2

    along, across = dial.direction(angle), dial.direction(angle - np.pi / 2.0)
    outline = dial.centre + POINTER_OUTLINE[:, :1] * across + POINTER_OUTLINE[:, 1:] * along
    uv = project(outline, cam_pose, k)
    mask = np.zeros((k["height"], k["width"]), np.uint8)
    if np.isnan(uv).any():
        return mask.astype(bool)
    # OpenCV's integer coordinates are pixel centres; ours put (0, 0) at a corner
    corners = np.round((uv - 0.5) * 16.0).astype(np.int32)
    cv2.fillPoly(mask, [corners], 1, lineType=cv2.LINE_8, shift=4)
    if not mask.any():
        u, v = uv.mean(axis=0)
        if 0 <= u < k["width"] and 0 <= v < k["height"]:
            mask[int(v), int(u)] = 1
    return mask.astype(bool)


def pointer_glare(pointer: np.ndarray, clipped: np.ndarray) -> dict:
    """The share of the pointer's pixels the sensor clipped, and whether that hides it."""
    n = int(pointer.sum())
    share = float(clipped[pointer].mean()) if n else 0.0
    return {"pointer_px": n, "pointer_clipped_share": share,
            "glare_hides_pointer": bool(n and share >= GLARE_HIDES_SHARE)}


def gauge_keypoints(dial: Dial, angle: float, cam_pose: np.ndarray, k: dict, ids: np.ndarray, depth: np.ndarray,
                    instance: int) -> list[float]:
    """COCO keypoints [x, y, v] * len(KEYPOINTS) of a gauge whose pointer is at `angle`:
    v 2 where the point is on its own instance's surface at its depth (the glass in
    front of the dial included), 1 in the frame but hidden, 0 (and x = y = 0) outside
    the frame or behind the camera."""
    r0, r1 = dial.binding["range"]
    points = np.array([dial.centre, dial.centre + TIP_RADIUS * dial.direction(angle),
                       dial.centre + TIP_RADIUS * dial.direction(r0), dial.centre + TIP_RADIUS * dial.direction(r1)])
    uv = project(points, cam_pose, k)
    facing = float(dial.axis @ (cam_pose[:3, 3] - dial.centre)) > 0.0
    out: list[float] = []
    for (u, v), point in zip(uv, points):
        if np.isnan(u) or not (0 <= u < k["width"] and 0 <= v < k["height"]):
            out += [0.0, 0.0, 0]
            continue
        expected = float(-(point - cam_pose[:3, 3]) @ cam_pose[:3, 2])
        row, col = int(v), int(u)
        seen = facing and ids[row, col] == instance and abs(float(depth[row, col]) - expected) <= DIAL_DEPTH_TOLERANCE_M
        out += [float(u), float(v), 2 if seen else 1]
    return out
