"""Gauge readers on one dial of one image: the dial from its placement's pointer
binding, the ROI from its projected rim, the study's C, S and pointer extent
(metrics.measure) on it, and the level a reader infers: the ray from the pivot along
which the face's dark pixels run, mapped through the inverse of the binding's
level -> angle map. A dial narrower than MIN_DIAL_PX, or not wholly in the frame, is
counted and not scored. The dial (gauge.dial_of) comes from the binding's rest pose and axis, so every
bound dial is read where it is, the transformers' too.

Two readers differ in what "dark" is. `study`: the study's fixed V <= 80 (its H
threshold). `relative`: V at most DARK_OF_FACE of the face's median V, which follows
the phone's exposure: the black pointer develops to a mid grey in an auto-exposed
frame, often above the fixed threshold.

H is the pointer's dark-pixel row extent (the study's threshold) over its true
projected row extent in the same view (baseline.py says why this reference).
"""

from __future__ import annotations

import math

import numpy as np

from .metrics import measure
from .gauge import FACE_RADIUS, Dial
from ..geometry.pinhole import project

MIN_DIAL_PX = 24  # the face's projected minor axis below which a dial is counted, not read
DARK_V = 80  # the study's pointer threshold on V (HSV, 0..255)
DARK_OF_FACE = 0.95  # the relative reader's threshold: this share of the face's median V
MIN_FACE_V = 40  # a face whose median V is below this shows nothing to read
MAX_DARK_SHARE = 0.5  # a face darker than this is night or shadow, not a pointer
FACE_SHARE = 0.97  # the face inside the bezel's shadowed rim (study.face_only's disc)
SPAN = (0.2, 0.8)  # the stretch of the pointer the reader follows, in face radii (the tip is at 0.85)
RADII = 16  # samples along the span
MIN_COVER = 12  # of RADII: how much of the span a ray's dark line must cover
ANGLES = 720  # pointer directions tried, half a degree apart
POINTER_HALF_WIDTH_M = 0.006  # the pointer's half width along the followed span, about
MIN_RIDGE = 8.0  # V a line must lie below a side: a dark line, not a dark stretch of face
MIN_RIDGE_OF_FACE = 0.1  # ... and at least this share of the face's median V

# The authored pointer (sources/authoring/_parts.py pointer_mesh), in its own frame:
# along +Y from a hub 3 cm behind the pivot to 0.85 of the face radius, 4 mm thick
# along the axis. Its projected row extent is the true H numerator.
POINTER_OUTLINE = np.array([(-0.012, -0.03), (0.012, -0.03), (0.002, 0.85 * FACE_RADIUS), (-0.002, 0.85 * FACE_RADIUS)])
POINTER_THICKNESS_M = 0.004

STATUS_READ = "read"
SCORED = "scored"
NOT_SCORED = ("too_small", "cut")  # counted, not scored
UNREADABLE = ("no_pointer", "dark_face", "no_line")
READERS = ("relative", "study")


def level_of_angle(angle: float, binding: dict) -> float:
    """The inverse of the binding's level -> angle map (gauge.pointer_angle): the level (clamped to the domain) whose
    pointer angle is `angle` (rad, taken within a turn of the range's middle)."""
    (d0, d1), (r0, r1) = binding["domain"], binding["range"]
    mid = (r0 + r1) / 2.0
    a = mid + (angle - mid + math.pi) % (2.0 * math.pi) - math.pi
    x = d0 + (d1 - d0) * (a - r0) / (r1 - r0)
    return float(min(max(x, min(d0, d1)), max(d0, d1)))


# --- geometry of one view (pure numpy) ---------------------------------------------------


def dial_plane_coordinates(dial: Dial, cam_pose: np.ndarray, k: dict, box: tuple[int, int, int, int]) -> np.ndarray:
    """(h, w, 2) float64: where each pixel centre of `box` (x0, y0, x1, y1) sees the
    dial's plane, as (left, up) metres from the pivot; NaN where the ray misses it."""
    x0, y0, x1, y1 = box
    cols, rows = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
    rays = np.stack([(cols - k["cx"]) / k["fx"], -(rows - k["cy"]) / k["fy"], -np.ones_like(cols)], axis=-1)
    rays = rays @ cam_pose[:3, :3].T
    eye = cam_pose[:3, 3]
    denom = rays @ dial.axis
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((dial.centre - eye) @ dial.axis) / denom
    hit = eye + t[..., None] * rays - dial.centre
    out = np.stack([hit @ dial.left, hit @ dial.up], axis=-1)
    out[~(t > 0)] = np.nan
    return out


def minor_axis_px(uv: np.ndarray) -> float:
    """The minor axis (px) of the ellipse through (n, 2) points spread evenly in angle
    on a projected circle: the variance along an axis of half-length b is b^2 / 2."""
    if np.isnan(uv).any():
        return 0.0
    lam = np.linalg.eigvalsh(np.cov(uv.T, bias=True))
    return float(2.0 * math.sqrt(2.0 * max(lam[0], 0.0)))


def pointer_rows_px(dial: Dial, angle: float, cam_pose: np.ndarray, k: dict) -> float:
    """Row extent (px) of the pointer's outline at `angle`, projected: the true H numerator."""
    along, across = dial.direction(angle), dial.direction(angle - math.pi / 2.0)
    flat = dial.centre + POINTER_OUTLINE[:, :1] * across + POINTER_OUTLINE[:, 1:] * along
    pts = np.vstack([flat, flat + POINTER_THICKNESS_M * dial.axis])
    v = project(pts, cam_pose, k)[:, 1]
    return float(np.nanmax(v) - np.nanmin(v)) if not np.isnan(v).all() else 0.0


# --- the reader ----------------------------------------------------------------------------


def polar_grid(face_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(ANGLES,) directions (rad) and (RADII,) distances (m) from the pivot along the span."""
    theta = np.arange(ANGLES) * (2.0 * math.pi / ANGLES)
    return theta, np.linspace(SPAN[0] * face_radius, SPAN[1] * face_radius, RADII)


def polar_values(value: np.ndarray, box: tuple[int, int, int, int], dial: Dial, cam_pose: np.ndarray,
                 k: dict) -> np.ndarray:
    """(ANGLES, RADII) float32: the crop's V (value: (h, w) of `box`) sampled bilinearly
    where the dial's polar grid projects: row i is the ray at angle i."""
    import cv2

    theta, radii = polar_grid(FACE_RADIUS)
    dirs = np.cos(theta)[:, None] * dial.up + np.sin(theta)[:, None] * dial.left
    pts = dial.centre + (dirs[:, None, :] * radii[None, :, None]).reshape(-1, 3)
    uv = project(pts, cam_pose, k).reshape(ANGLES, RADII, 2)
    mx = (uv[..., 0] - box[0] - 0.5).astype(np.float32)  # pixel i's centre lies at i + 0.5
    my = (uv[..., 1] - box[1] - 0.5).astype(np.float32)
    return cv2.remap(np.ascontiguousarray(value, np.float32), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def read_angle(polar: np.ndarray, face_values: np.ndarray, threshold: float, pixel_m: float) -> tuple[float | None, str]:
    """The pointer's angle (rad, 0 along the dial's up, positive towards its left), or
    (None, why): `no_pointer` (no face pixel at or below `threshold`: glare),
    `dark_face` (a dim face, or most of it dark: night, shadow), `no_line` (no ray
    from the pivot along which a thin dark line covers the pointer's span).

    polar: (ANGLES, RADII) V on the polar grid; face_values: (n,) V of the face's
    pixels; pixel_m: one pixel's size on the dial (m). A sample is on the line when it
    is dark and darker by MIN_RIDGE than one of its sides (a pointer's half width and a
    pixel and a half away): a shadowed stretch of face has no brighter side, and the
    pointer's own shadow along one side leaves the other. The ray whose line covers the
    most of the span wins (a shadow's edge crosses the rays, covering little of any
    one); the line's strength around it refines the angle."""
    face_v = float(np.median(face_values))
    dark = face_values <= threshold
    if face_v < MIN_FACE_V or dark.mean() > MAX_DARK_SHARE:
        return None, "dark_face"
    if not dark.any():
        return None, "no_pointer"
    theta, radii = polar_grid(FACE_RADIUS)
    step = theta[1] - theta[0]
    offsets = np.ceil((POINTER_HALF_WIDTH_M + 1.5 * pixel_m) / radii / step).astype(int)
    rows, cols = np.arange(ANGLES)[:, None], np.arange(RADII)[None, :]
    ridge = np.maximum(polar[(rows - offsets) % ANGLES, cols], polar[(rows + offsets) % ANGLES, cols]) - polar
    line = (polar <= threshold) & (ridge >= max(MIN_RIDGE, MIN_RIDGE_OF_FACE * face_v))
    cover = line.sum(axis=1)
    strength = np.where(line, ridge, 0.0).sum(axis=1)
    best = int(np.argmax(cover * (strength.max() + 1.0) + strength))  # span covered, then contrast
    if cover[best] < MIN_COVER:
        return None, "no_line"
    near = np.arange(-int(offsets.min()), int(offsets.min()) + 1)
    weights = strength[(best + near) % ANGLES]
    angle = theta[best] + step * float(near @ weights) / float(weights.sum())
    return float((angle + math.pi) % (2.0 * math.pi) - math.pi), STATUS_READ


# --- one gauge of one frame ------------------------------------------------------------------


def score_gauge(bgr: np.ndarray, dial: Dial, cam_pose: np.ndarray, k: dict, truth: float | None) -> dict:
    """The ROI, C, S, pointer extent, H and each reader's level of one dial in one image
    (bgr: (h, w, 3) uint8). row["status"]: SCORED, or one of NOT_SCORED (then no reader
    ran); row[reader] = {status: read or one of UNREADABLE, angle_rad, read, error}."""
    face_uv = project(dial.circle(dial.face_radius), cam_pose, k)
    rim_uv = project(dial.circle(dial.rim_radius), cam_pose, k)
    row = {"dial_px": round(minor_axis_px(face_uv), 3)}
    if np.isnan(rim_uv).any():
        return {**row, "status": "cut"}
    lo, hi = rim_uv.min(axis=0), rim_uv.max(axis=0)
    if lo[0] < 0 or lo[1] < 0 or hi[0] > k["width"] or hi[1] > k["height"]:
        return {**row, "status": "cut"}
    if row["dial_px"] < MIN_DIAL_PX:
        return {**row, "status": "too_small"}
    box = (int(math.floor(lo[0])), int(math.floor(lo[1])), int(math.ceil(hi[0])), int(math.ceil(hi[1])))
    crop = bgr[box[1]:box[3], box[0]:box[2]]
    plane = dial_plane_coordinates(dial, cam_pose, k, box)
    face = np.nan_to_num(np.hypot(plane[..., 0], plane[..., 1]), nan=np.inf) <= FACE_SHARE * FACE_RADIUS
    face_only = crop.copy()
    face_only[~face] = 128  # neither red, white nor dark for the H masks (study.face_only)
    m = measure(crop, face_only)
    true_angle = None if truth is None else dial.angle(truth)
    true_rows = pointer_rows_px(dial, true_angle, cam_pose, k) if true_angle is not None else None
    value = crop.max(axis=2)  # HSV's V is the largest of B, G, R
    face_values = value[face]
    out = {**row, "status": SCORED, "roi": list(box), "C": m["C"], "S": m["S"], "extent_px": m["extent_px"],
           "true_extent_px": true_rows, "H": m["extent_px"] / true_rows if true_rows else None,
           "true_angle_rad": true_angle, "face_v": float(np.median(face_values))}
    polar = polar_values(value, box, dial, cam_pose, k)
    pixel_m = 2.0 * FACE_RADIUS / row["dial_px"]
    for name, threshold in thresholds(face_values).items():
        angle, status = read_angle(polar, face_values, threshold, pixel_m)
        reading = level_of_angle(angle, dial.binding) if angle is not None else None
        out[name] = {"status": status, "angle_rad": angle, "read": reading,
                     "error": reading - truth if reading is not None and truth is not None else None}
    return out


def thresholds(face_values: np.ndarray) -> dict[str, float]:
    """Each reader's V at or below which a pixel is dark, from the face's V (n,)."""
    return {"relative": DARK_OF_FACE * float(np.median(face_values)), "study": float(DARK_V)}
