"""The phone camera, modelled outside Blender on the linear (scene-referred) render:

    pixel = NR(sRGB(clip(gain * (wb * radiance + veil), 0, 1)))

- wb: grey-world auto white balance, metered with the exposure; NR: the phone ISP's
  noise reduction (3x3 median + non-local means; saturated areas stay at 255).
- gain: exposure locked once per scene (a condition, or a scenario) by centre-weighted
  metering of a first render to a mean of 0.18, clamped to the phone's longest exposure
  at its highest ISO (GAIN_MAX), so night stays dark instead of being lifted to grey.
- clip: the sensor saturates like a real one (a Standard transform; Filmic/AgX would
  compress highlights and hide exactly the saturation the study measures).
- veil: veiling glare of the lens, proportional to the direct sun irradiance reaching the
  lens and falling off with the sun's angle to the optical axis; zero when the sun is
  behind the lens, below the horizon or occluded. It is added after metering: a locked
  exposure does not react to it, which is what washes the crop out in low sun.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

@dataclass(frozen=True)
class PhoneCamera:
    """Exposure and glare of a phone camera (defaults: a Galaxy S23 class main camera).

    gain_max: the largest linear gain (about 1/10 s at ISO 3200, 15 stops above a sunny
    scene's exposure); radiance below ~0.003 W/m2/sr stays dark. veil_k and veil_width
    (rad) set the veiling glare: veil = veil_k * E_sun_at_lens * exp(-(theta/width)^2)
    in radiance units (W/m2/sr per W/m2): a few per cent of the sun's irradiance per
    steradian near the axis, negligible beyond ~40 degrees; a plausible phone lens with
    a smudged cover glass, not a device measurement.

    samples and render_denoise: the path tracer's budget. 4 samples through Cycles'
    OpenImageDenoise (albedo and normal guides, BALANCED quality, on the CPU) land
    closer to a converged render than 16 raw samples (8-bit RMS error 3.5 against 9.9 at
    noon, 7.6 against 25.7 at midnight, in 40 % of the time; bench_render measures it
    against a 256-sample reference); 8 samples came 2-12 % closer at 1.5-2x the time, and
    moved the study's C by at most 0.006 and H by at most 0.016 (S not at all). OIDN on the CPU gives the same pixels in
    every run and process, so frames stay a function of scenario and seed.
    """

    metering_target: float = 0.40
    gain_max: float = 60.0
    gain_min: float = 1e-5
    veil_k: float = 0.15
    veil_width: float = 0.35
    width: int = 320
    height: int = 240
    samples: int = 4
    render_denoise: str = "BALANCED"  # Cycles OIDN quality (FAST, BALANCED, HIGH); "" = off
    denoise: float = 10.0  # ISP noise reduction (3x3 median, then OpenCV NL-means h); 0 = off


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function on [0, 1] values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


def metered_gain(linear_rgb: np.ndarray, cam: PhoneCamera) -> float:
    """Centre-weighted average metering: the gain that brings the weighted mean
    luminance to the metering target, clamped to what the phone can do."""
    h, w = linear_rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
    mean = float((luminance(linear_rgb) * weight).sum() / weight.sum())
    if not mean > 0.0:
        return cam.gain_max
    return float(np.clip(cam.metering_target / mean, cam.gain_min, cam.gain_max))


def veil_radiance(sun_dir: np.ndarray, view_axis: np.ndarray, dni: float, visible: bool, cam: PhoneCamera) -> float:
    """Veiling-glare radiance added over the frame by the sun at `sun_dir` (ENU unit)."""
    cos_t = float(np.dot(sun_dir, view_axis))
    if not visible or dni <= 0.0 or cos_t <= 0.0:
        return 0.0
    theta = math.acos(min(1.0, cos_t))
    return cam.veil_k * dni * math.exp(-((theta / cam.veil_width) ** 2))


def metered_white_balance(linear_rgb: np.ndarray, cam: PhoneCamera) -> np.ndarray:
    """Grey-world auto white balance with the metering's centre weights: per-channel
    gains (luminance-neutral, each within [1/4, 4]) that make the weighted mean grey,
    as a phone does under a blue night sky or sodium-coloured floodlights."""
    h, w = linear_rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
    mean = (linear_rgb * weight[..., None]).sum(axis=(0, 1)) / weight.sum()
    if not (mean > 0).all():
        return np.ones(3)
    wb = np.clip(mean.mean() / mean, 0.25, 4.0)
    return wb / float(luminance(wb[None, :])[0])


def develop(linear_rgb: np.ndarray, gain: float, veil: float, wb=None, cam: PhoneCamera | None = None) -> np.ndarray:
    """(h, w, 3) linear radiance -> (h, w, 3) uint8 sRGB (RGB order): white balance,
    exposure gain, veiling glare, sensor clip, sRGB, then the phone ISP's noise
    reduction (non-local means; it also stands in for the many frames a phone merges)."""
    wb = np.ones(3) if wb is None else np.asarray(wb, float)
    out = np.round(srgb_encode(gain * (linear_rgb * wb + veil)) * 255.0).astype(np.uint8)
    strength = (cam or PhoneCamera()).denoise
    if strength > 0:
        import cv2

        out = cv2.medianBlur(np.ascontiguousarray(out), 3)  # path-tracing salt and pepper first
        clipped = (out == 255).all(axis=-1)  # a saturated area stays saturated (not a firefly)
        out = cv2.fastNlMeansDenoisingColored(out, None, strength, strength, 5, 15)
        out[clipped] = 255
    return out


