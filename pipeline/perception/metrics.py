"""The study's image metrics on a gauge crop (PAPER_NOTES.md, "Image metrics"), with its
fixed thresholds. Images are numpy uint8 arrays: gray (h, w), BGR (h, w, 3) as OpenCV
loads them; HSV on OpenCV's scale (H 0..180, S and V 0..255).

"Pointer = dark pixels inside the region": the gauge region (red and white face
pixels) has a hole exactly where the dark pointer covers the face, so "inside" means
inside the filled convex hull of the gauge-mask pixels, the smallest convex set that
contains the face; dark pixels outside it (housing, background) are not the pointer.
"""

from __future__ import annotations

import numpy as np

Roi = tuple[int, int, int, int]  # x, y, width, height in pixels


def _cv2():
    try:
        import cv2
    except ImportError as e:  # optional heavy dependency: fail where used
        raise ImportError("perception needs OpenCV: pip install opencv-python-headless") from e
    return cv2


def rms_contrast(gray_u8: np.ndarray) -> float:
    """C = sqrt(mean((I - mean I)^2)) / 255, I the grayscale values 0..255."""
    i = np.asarray(gray_u8, dtype=np.float64)
    return float(np.sqrt(np.mean((i - i.mean()) ** 2)) / 255.0)


def high_intensity_ratio(gray_u8: np.ndarray, threshold: int = 240) -> float:
    """S = fraction of pixels strictly above `threshold`."""
    i = np.asarray(gray_u8)
    return float(np.count_nonzero(i > threshold) / i.size)


def gauge_mask(bgr_u8: np.ndarray) -> np.ndarray:
    """(h, w) bool: red (H in [0, 10] or [160, 180], S >= 100, V >= 50) or white
    (S <= 60, V >= 200) pixels."""
    cv2 = _cv2()
    hsv = cv2.cvtColor(np.ascontiguousarray(bgr_u8, dtype=np.uint8), cv2.COLOR_BGR2HSV)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    red = ((h <= 10) | (h >= 160)) & (s >= 100) & (v >= 50)
    white = (s <= 60) & (v >= 200)
    return red | white


def _crop(img: np.ndarray, roi: Roi) -> np.ndarray:
    x, y, w, h = (int(v) for v in roi)
    if w <= 0 or h <= 0 or x < 0 or y < 0 or y + h > img.shape[0] or x + w > img.shape[1]:
        raise ValueError(f"roi {roi} is not inside the {img.shape[1]}x{img.shape[0]} image")
    return img[y:y + h, x:x + w]


def region(bgr_u8: np.ndarray) -> np.ndarray:
    """(h, w) bool: the filled convex hull of the gauge mask (empty if < 3 pixels)."""
    cv2 = _cv2()
    mask = gauge_mask(bgr_u8)
    out = np.zeros(mask.shape, dtype=np.uint8)
    ys, xs = np.nonzero(mask)
    if len(xs) >= 3:
        hull = cv2.convexHull(np.stack([xs, ys], axis=1).astype(np.int32))
        cv2.fillConvexPoly(out, hull, 1)
    return out.astype(bool) | mask


def pointer_height(bgr_u8: np.ndarray, roi: Roi) -> int:
    """y_max - y_min of the pointer pixels (V <= 80 inside the region) in the crop; 0
    when no pointer pixel is found (lost in darkness or glare)."""
    cv2 = _cv2()
    crop = _crop(np.asarray(bgr_u8), roi)
    v = cv2.cvtColor(np.ascontiguousarray(crop, dtype=np.uint8), cv2.COLOR_BGR2HSV)[..., 2]
    rows = np.nonzero(((v <= 80) & region(crop)).any(axis=1))[0]
    return int(rows.max() - rows.min()) if len(rows) else 0


def oil_height_ratio(frames, roi: Roi) -> list[float]:
    """H_i = pointer_height(frame_i) / H_ref, H_ref that of the first frame (so H_0 = 1).
    ValueError when the first frame shows no pointer (the reference is undefined)."""
    heights = [pointer_height(f, roi) for f in frames]
    if not heights:
        return []
    if heights[0] == 0:
        raise ValueError("no pointer found in the first frame: H_ref is undefined")
    return [h / heights[0] for h in heights]


def measure(bgr_crop: np.ndarray, bgr_face: np.ndarray) -> dict:
    """The study's C and S of a gauge crop and the pointer extent (px) on its dial face
    alone (pointer_height): the crop's corners hold bezel and its shadows, which
    the region's convex hull would otherwise take for pointer pixels."""
    gray = _cv2().cvtColor(np.ascontiguousarray(bgr_crop), _cv2().COLOR_BGR2GRAY)
    h, w = bgr_face.shape[:2]
    return {"C": rms_contrast(gray), "S": high_intensity_ratio(gray),
            "extent_px": float(pointer_height(bgr_face, (0, 0, w, h)))}
