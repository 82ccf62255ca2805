"""The phone camera, modelled outside Blender on the linear (scene-referred) render:

    optical = (1 - eta) (radiance + sun disc) + halo * (radiance + sun disc)
    pixel   = NR(sRGB(clip(noise(gain * wb * optical), 0, 1)))

- lens: a point-spread function with a sharp core and a wide, heavy-tailed halo that
  holds a fraction eta of the light. The core is the render's own pixel filter; the halo
  spreads every source over the frame, and the sun (invisible to the Cycles camera) enters
  through its disc: a sun in or near the field saturates a patch around it and lights the
  frame's side towards it more than the far side (sun_glare, scene_glare).
- wb: grey-world auto white balance, metered with the exposure.
- gain: exposure locked once per scene (a condition, or a scenario) by centre-weighted
  metering of a first render to the metering target, clamped to the phone's longest
  exposure at its highest ISO (gain_max), so night stays dark instead of being lifted to
  grey.
  Metering sees the render without the lens's glare: a locked exposure does not react to
  it, which is what washes a crop out in low sun.
- noise: photon shot noise (Poisson in electrons) and read noise (Gaussian), from a
  generator seeded per frame, before the ISP.
- clip: the sensor saturates like a real one (a Standard transform; Filmic/AgX would
  compress highlights and hide exactly the saturation the study measures).
- NR: the phone ISP's noise reduction: isolated outliers (path tracing's fireflies and
  dark specks) take their 3x3 median, then non-local means; saturated areas stay at 255.
  A plain 3x3 median would erase every line one pixel wide: the wires and lattice that
  make a substation hard to perceive.

Everything here is float64 numpy and scipy's single-threaded FFT: a frame's pixels are a
function of its inputs and seed, in any process.
"""

from __future__ import annotations

import functools
import hashlib
import math
from dataclasses import dataclass

import numpy as np

from ..geometry.pinhole import project

SUN_HALF_ANGLE = 0.00465  # rad: the solar disc's angular radius
SUN_SOLID_ANGLE = 2.0 * math.pi * (1.0 - math.cos(SUN_HALF_ANGLE))  # 6.8e-5 sr


@dataclass(frozen=True)
class PhoneCamera:
    """Exposure, lens glare and sensor noise of a phone camera (defaults: a Galaxy S23
    class camera).

    gain_max: the largest linear gain (about 1/10 s at ISO 3200, 15 stops above a sunny
    scene's exposure); radiance below ~0.003 W/m2/sr stays dark.

    Glare: the halo of the lens's point-spread function is the ABg (Harvey) scatter
    law of stray-light analysis, p(theta) = A / (B + theta^g) per steradian, the shape of
    measured glare spread functions of camera lenses (the ISO 9358 veiling-glare
    literature; Talvala et al., "Veiling glare in high dynamic range imaging"): flat
    within the shoulder `glare_shoulder` (rad, B = shoulder^g), then a power law of slope
    `glare_slope` (2 to 3). `glare_fraction` is the share of the light the halo takes
    from the core over the front hemisphere: the veiling glare index of camera lenses is
    1-5 %; 4 % stands for a phone's plastic elements behind a cover glass.

    Noise: `full_well_e` electrons fill a frame pixel at base ISO and `read_noise_e` is
    the read noise (e- rms). Phone pixels of 1.1-2.4 um hold ~2,000-10,000 e- at the
    ~1,700 e-/um2 that sensor measurements show (Roger N. Clark's sensor performance
    summaries), and read noise of current CMOS sensors is 1.5-3 e-. Gains above
    gain_max / iso_max come from analog gain (ISO 50 to 3200: iso_max 64), which divides
    the electrons a full-scale pixel holds: night frames are the noisy ones. A phone
    merges a burst of `burst_frames` such exposures into one picture (2-8 in daylight,
    up to 15 at night: Hasinoff et al., "Burst photography for high dynamic range and
    low-light imaging on mobile cameras"; Liba et al., "Handheld mobile photography in
    very low light"), which divides the noise's variance by the burst's length.

    samples and render_denoise: the path tracer's budget. 4 samples through Cycles'
    OpenImageDenoise (albedo and normal guides, BALANCED quality, on the CPU) land
    closer to a converged render than 16 raw samples in less time (bench_render measures
    it against a 256-sample reference). OIDN on the CPU gives the same pixels in every run
    and process, so frames stay a function of scenario and seed.
    """

    metering_target: float = 0.40
    gain_max: float = 60.0
    gain_min: float = 1e-5
    glare_fraction: float = 0.04
    glare_slope: float = 2.5
    glare_shoulder: float = 0.002  # rad
    full_well_e: float = 6000.0
    read_noise_e: float = 2.0
    burst_frames: int = 8
    iso_max: float = 64.0
    width: int = 320
    height: int = 240
    samples: int = 4
    render_denoise: str = "BALANCED"  # Cycles OIDN quality (FAST, BALANCED, HIGH); "" = off
    denoise: float = 10.0  # ISP noise reduction (despeckle, then OpenCV NL-means h); 0 = off


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function on [0, 1] values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


def _centre_weights(h: int, w: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))


def metered_gain(linear_rgb: np.ndarray, cam: PhoneCamera) -> float:
    """Centre-weighted average metering: the gain that brings the weighted mean
    luminance to the metering target, clamped to what the phone can do."""
    weight = _centre_weights(*linear_rgb.shape[:2])
    mean = float((luminance(linear_rgb) * weight).sum() / weight.sum())
    if not mean > 0.0:
        return cam.gain_max
    return float(np.clip(cam.metering_target / mean, cam.gain_min, cam.gain_max))


def metered_white_balance(linear_rgb: np.ndarray, cam: PhoneCamera) -> np.ndarray:
    """Grey-world auto white balance with the metering's centre weights: per-channel
    gains (luminance-neutral, each within [1/4, 4]) that make the weighted mean grey,
    as a phone does under a blue night sky or sodium-coloured floodlights."""
    weight = _centre_weights(*linear_rgb.shape[:2])
    mean = (linear_rgb * weight[..., None]).sum(axis=(0, 1)) / weight.sum()
    if not (mean > 0).all():
        return np.ones(3)
    wb = np.clip(mean.mean() / mean, 0.25, 4.0)
    return wb / float(luminance(wb[None, :])[0])


# --- the lens: core and halo -------------------------------------------------------------


@functools.lru_cache(maxsize=16)
def _halo_scale(slope: float, shoulder: float) -> float:
    """The hemisphere integral of 1 / (B + theta^g) in sr (A = fraction / this)."""
    theta = np.geomspace(1e-9, math.pi / 2, 200001)
    f = 2.0 * math.pi * np.sin(theta) / (shoulder**slope + theta**slope)
    return float(np.sum((f[1:] + f[:-1]) * np.diff(theta)) / 2.0)


def halo_psf(theta: np.ndarray, cam: PhoneCamera) -> np.ndarray:
    """The lens halo p(theta) (1/sr) at angles theta (rad) from a source: its integral
    over the front hemisphere is cam.glare_fraction."""
    a = cam.glare_fraction / _halo_scale(cam.glare_slope, cam.glare_shoulder)
    return a / (cam.glare_shoulder**cam.glare_slope + np.asarray(theta, float) ** cam.glare_slope)


def _rays(u: np.ndarray, v: np.ndarray, k: dict) -> np.ndarray:
    """(..., 3) unit rays in camera axes (x right, y up, looking down -z) through pixel
    positions (u right, v down)."""
    u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
    d = np.stack([(u - k["cx"]) / k["fx"], -(v - k["cy"]) / k["fy"], -np.ones(u.shape)], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) between unit vectors, accurate at small angles too."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _kernel(cu: float, cv: float, dy: np.ndarray, dx: np.ndarray, k: dict, cam: PhoneCamera) -> np.ndarray:
    """The halo (1/sr) at pixel offsets (dy rows, dx columns) from a source at pixel
    position (cu, cv): angles between exact rays, so the halo of a source far outside
    the frame is right as well."""
    here = _rays(np.float64(cu), np.float64(cv), k)
    there = _rays(cu + dx[None, :], cv + dy[:, None], k)
    return halo_psf(_angle(there, here), cam)


def scene_glare(linear_rgb: np.ndarray, gain: float, wb, k: dict, cam: PhoneCamera) -> np.ndarray:
    """(h, w, 3) radiance that the halo of the frame's over-bright light adds: what lies
    above the sensor's clip at this exposure (a glint of the sun on glass, a floodlight)
    spread over the frame by FFT convolution. The halo of in-range light is a fog of a
    few per cent that the exposure absorbs, and the frame cannot see the surroundings
    that would add to it at its edges: it is left out."""
    lin = np.asarray(linear_rgb, np.float64)
    clip = 1.0 / (gain * np.asarray(wb, np.float64))
    excess = np.maximum(lin - clip, 0.0)
    if not excess.any():
        return np.zeros_like(lin)
    h, w = lin.shape[:2]
    kernel = _kernel(k["cx"], k["cy"], np.arange(-(h - 1), h, dtype=float), np.arange(-(w - 1), w, dtype=float),
                     k, cam) / (k["fx"] * k["fy"])  # per pixel: 1/sr times a pixel's solid angle
    return np.maximum(fft_convolve(excess, kernel[..., None], "same"), 0.0)


def fft_convolve(a: np.ndarray, b: np.ndarray, mode: str) -> np.ndarray:
    """The linear convolution of real `a` and `b` over their first two axes (b's other
    axes of length 1 or a's), "same" (a's shape) or "valid" (where b lies wholly in a),
    by scipy.fft: the steps of scipy.signal.fftconvolve for these inputs, and its bits,
    without importing scipy.signal, which imports scipy.stats: a cost to every process
    that renders."""
    from scipy import fft

    full = [a.shape[i] + b.shape[i] - 1 for i in (0, 1)]
    padded = [fft.next_fast_len(n, True) for n in full]
    product = fft.rfftn(a, padded, axes=(0, 1)) * fft.rfftn(b, padded, axes=(0, 1))
    out = fft.irfftn(product, padded, axes=(0, 1))[:full[0], :full[1]]
    keep = [a.shape[i] if mode == "same" else a.shape[i] - b.shape[i] + 1 for i in (0, 1)]
    start = [(full[i] - keep[i]) // 2 for i in (0, 1)]
    return out[start[0]:start[0] + keep[0], start[1]:start[1] + keep[1]].copy()


def lens_glare(linear_rgb: np.ndarray, gain: float, wb, pose: np.ndarray, k: dict, sun_dir: np.ndarray, dni: float,
               cam: PhoneCamera) -> np.ndarray:
    """(h, w, 3) radiance the lens adds to a frame: the sun's disc and halo (dni 0 when
    the sun is set or occluded) and the halo of the frame's over-bright light."""
    return sun_glare(sun_dir, dni, pose, k, cam)[..., None] + scene_glare(linear_rgb, gain, wb, k, cam)


def _disc_weights(u: float, v: float, radius: float, half: int, oversample: int = 8) -> np.ndarray:
    """(2 half + 1)^2 share of a disc (centre (u, v), radius px) in each pixel of the
    patch centred on the pixel that holds (u, v); sums to 1."""
    iu, iv = math.floor(u), math.floor(v)
    s = (np.arange(oversample) + 0.5) / oversample
    offs = np.arange(-half, half + 1, dtype=float)
    xs = (iu + offs)[:, None] + s[None, :]  # sample columns, per patch column
    ys = (iv + offs)[:, None] + s[None, :]
    inside = ((ys[:, None, :, None] - v) ** 2 + (xs[None, :, None, :] - u) ** 2) <= radius**2
    cover = inside.sum(axis=(2, 3)).astype(np.float64)
    if cover.sum() == 0.0:  # a disc smaller than the samples' spacing: all of it in its pixel
        cover[half, half] = 1.0
    return cover / cover.sum()


def sun_glare(sun_dir: np.ndarray, dni: float, pose: np.ndarray, k: dict, cam: PhoneCamera) -> np.ndarray:
    """(h, w) radiance (W/m2/sr, grey) that the sun adds through the lens: its disc (the
    core's share of DNI / 6.8e-5 sr) where it is in the frame, and the halo of the disc
    (FFT convolution of the disc's pixels with the halo at exact ray angles) over the
    frame. The sun's irradiance on the entrance pupil falls with the cosine of its angle
    to the axis; a sun behind the lens plane, set or occluded (dni 0) adds nothing.

    sun_dir: (3,) ENU unit vector towards the sun; pose: (4, 4) camera-to-world."""
    h, w = int(k["height"]), int(k["width"])
    out = np.zeros((h, w))
    cos_axis = float(-(pose[:3, :3].T @ np.asarray(sun_dir, float))[2])
    if not dni > 0.0 or cos_axis <= 0.0:
        return out
    u, v = project(pose[:3, 3][None, :] + np.asarray(sun_dir, float)[None, :], pose, k)[0]
    radius = k["fx"] * math.tan(SUN_HALF_ANGLE)
    half = math.ceil(radius) + 1
    weights = _disc_weights(u, v, radius, half)
    iu, iv = math.floor(u), math.floor(v)
    centre = (iu + 0.5, iv + 0.5)
    # Offsets from every patch pixel to every frame pixel: the valid convolution is the frame.
    dx = np.arange(-(iu + half), w - iu + half, dtype=float)
    dy = np.arange(-(iv + half), h - iv + half, dtype=float)
    halo = fft_convolve(_kernel(*centre, dy, dx, k, cam), weights, "valid")
    out += dni * cos_axis * np.maximum(halo, 0.0)
    # The disc itself, where the patch overlaps the frame: the core's share of its energy.
    core = (1.0 - cam.glare_fraction) * dni * weights * (k["fx"] * k["fy"])
    r0, c0 = iv - half, iu - half
    ys, xs = slice(max(r0, 0), min(r0 + 2 * half + 1, h)), slice(max(c0, 0), min(c0 + 2 * half + 1, w))
    if ys.start < ys.stop and xs.start < xs.stop:
        out[ys, xs] += core[ys.start - r0:ys.stop - r0, xs.start - c0:xs.stop - c0]
    return out


# --- the sensor and the ISP ---------------------------------------------------------------


def frame_seed(seed: int, name: str) -> int:
    """A frame's noise seed from the run's seed and the frame's name (the same in every
    process, unlike Python's hash)."""
    return int.from_bytes(hashlib.sha256(f"{int(seed)}/{name}".encode()).digest()[:8], "little")


def sensor_noise(exposure: np.ndarray, gain: float, cam: PhoneCamera, seed: int) -> np.ndarray:
    """Shot and read noise on the sensor's exposure (1.0 = full scale) of a merged burst:
    electrons drawn from Poisson(exposure x full-scale electrons x burst frames), plus
    Gaussian read noise of that many reads, back to exposure units. Analog gain (above
    gain_max / iso_max) divides the full-scale electrons, so a night frame's pixels
    hold a few dozen per exposure."""
    analog = float(np.clip(gain * cam.iso_max / cam.gain_max, 1.0, cam.iso_max))
    full_scale = cam.full_well_e / analog * cam.burst_frames
    rng = np.random.default_rng(seed)
    mean_e = np.clip(exposure, 0.0, 2.0) * full_scale  # beyond full scale the pixel clips anyway
    read = cam.read_noise_e * math.sqrt(cam.burst_frames)
    electrons = rng.poisson(mean_e).astype(np.float64) + rng.normal(0.0, read, mean_e.shape)
    return electrons / full_scale


def clipped(linear_rgb: np.ndarray, gain: float, veil=0.0, wb=None) -> np.ndarray:
    """(h, w) bool: the pixels the sensor clips, from the radiance develop() exposes
    (the render plus the lens's veil, white-balanced, times the gain) reaching full
    scale in any channel, before noise: the glare's own extent, not a threshold on the
    8-bit picture (whose noise reduction and sRGB curve move it)."""
    wb = np.ones(3) if wb is None else np.asarray(wb, float)
    veil = np.asarray(veil, np.float64)
    if veil.ndim == 2:
        veil = veil[..., None]
    exposure = gain * (np.asarray(linear_rgb, np.float64) + veil) * wb
    return (exposure >= 1.0).any(axis=-1)


def develop(linear_rgb: np.ndarray, gain: float, veil=0.0, wb=None, cam: PhoneCamera | None = None, *,
            seed: int | None = None) -> np.ndarray:
    """(h, w, 3) linear radiance -> (h, w, 3) uint8 sRGB (RGB order): `veil` (W/m2/sr, a
    number or an (h, w) or (h, w, 3) array: what the lens adds, sun_glare) on the
    radiance, white balance and exposure gain, sensor noise when `seed` is given (None:
    a noiseless sensor, for references), the sensor's clip, sRGB, then the phone ISP's
    noise reduction (non-local means; it also stands in for the many frames a phone
    merges)."""
    cam = cam or PhoneCamera()
    wb = np.ones(3) if wb is None else np.asarray(wb, float)
    veil = np.asarray(veil, np.float64)
    if veil.ndim == 2:
        veil = veil[..., None]
    exposure = gain * (np.asarray(linear_rgb, np.float64) + veil) * wb
    if seed is not None:
        exposure = sensor_noise(exposure, gain, cam, seed)
    out = np.round(srgb_encode(exposure) * 255.0).astype(np.uint8)
    if cam.denoise > 0:
        import cv2

        out = despeckle(out)  # path-tracing salt and pepper first
        clipped = (out == 255).all(axis=-1)  # a saturated area stays saturated (not a firefly)
        out = cv2.fastNlMeansDenoisingColored(out, None, cam.denoise, cam.denoise, 5, 15)
        out[clipped] = 255
    return out


SPECK_LEVELS = 24.0  # how far (8-bit levels of mean brightness) a speck stands out from its neighbours


def despeckle(rgb: np.ndarray) -> np.ndarray:
    """The pixels brighter or darker by SPECK_LEVELS than seven of their eight neighbours
    (a lone speck, or one of a pair) take their 3x3 median; every other pixel is kept. A
    line one pixel wide has two neighbours along it like itself, so it stays, where a
    median over every pixel would erase it."""
    import cv2
    from scipy import ndimage

    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    level = rgb.astype(np.float64).mean(axis=2)
    second_highest = ndimage.rank_filter(level, -2, footprint=ring, mode="nearest")
    second_lowest = ndimage.rank_filter(level, 1, footprint=ring, mode="nearest")
    speck = (level > second_highest + SPECK_LEVELS) | (level < second_lowest - SPECK_LEVELS)
    out = rgb.copy()
    out[speck] = cv2.medianBlur(np.ascontiguousarray(rgb), 3)[speck]
    return out
