"""The renderer's benchmark: seconds per frame of the study's gauge close-up, and its
error against a converged reference."""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from ..render.cycles import CyclesScene
from ..render.frames import populate
from ..render.sensor import PhoneCamera, develop, metered_gain, metered_white_balance
from ..runtime.site import load_site
from ..render.study import load_study, study_shots

# CyclesScene renders at Blender's factory light paths; the peer and the reference differ
# from ours only in their samples and denoiser.
PEER_CAMERA = PhoneCamera(samples=16, render_denoise="")  # what one would try first: raw samples
REFERENCE_CAMERA = PhoneCamera(samples=256, render_denoise="")  # converged enough to stand for the truth


def frame_error(linear: np.ndarray, reference: np.ndarray, cam: PhoneCamera) -> float:
    """RMS difference in 8-bit sRGB levels between a frame and a converged reference,
    both developed with the reference's exposure and white balance and without the
    ISP's noise reduction: what the renderer gets wrong, before the phone hides it."""
    raw = PhoneCamera(denoise=0.0)
    gain, wb = metered_gain(reference, cam), metered_white_balance(reference, cam)
    a = develop(linear, gain, 0.0, wb, raw).astype(np.float64)
    b = develop(reference, gain, 0.0, wb, raw).astype(np.float64)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def bench_render(out, repeats: int = 5, threads: int | None = None, *, sources: Path,
                 setup: str = "ours", reference: Path | None = None) -> dict:
    """Seconds per 320x240 frame of the study's gauge close-up at solar noon: the scene is
    loaded once (load_s), then `repeats` frames re-render it (render_s: Cycles alone;
    frame_s: with the phone's develop).

    setup: "ours" (PhoneCamera's samples and denoiser), "blender_defaults" (the peer: 16
    raw samples) or "reference" (256 raw samples, saved to `reference` as .npy, timed
    once); all at Blender's factory light paths. With a saved `reference`, the frame's
    error against it is reported too (frame_error)."""
    site = load_site(Path(out), sources)
    cam = {"ours": PhoneCamera(), "blender_defaults": PEER_CAMERA, "reference": REFERENCE_CAMERA}[setup]
    shot = dict(study_shots(site, load_study(Path(sources) / "study.toml")))["solar_noon"]
    bl = CyclesScene(site, cam, 1)
    if threads:
        bl.scene.render.threads = threads
    if setup == "reference":
        repeats = 1
    try:
        t0 = time.perf_counter()
        populate(bl, site, [shot])
        bl.set_shot(shot)
        load_s = time.perf_counter() - t0
        times, frames = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            linear = bl.render()
            times.append(time.perf_counter() - t)
            develop(linear, metered_gain(linear, cam), 0.0, metered_white_balance(linear, cam), cam)
            frames.append(time.perf_counter() - t)
        import bpy

        objects = sum(o.type == "MESH" for o in bpy.data.objects)
        lights = sum(o.type == "LIGHT" for o in bpy.data.objects)
    finally:
        bl.close()
    result = {"frame": f"{cam.width}x{cam.height} {cam.samples} spp"
                       f"{' + OIDN ' + cam.render_denoise if cam.render_denoise else ''}, solar_noon, {shot.target}",
              "setup": setup, "load_s": load_s, "loaded": sorted(t for t in bl.roots), "mesh_objects": objects,
              "lights": lights, "threads": threads or CyclesScene.THREADS, "samples": cam.samples,
              "render_denoise": cam.render_denoise, "median_s": statistics.median(times), "min_s": min(times),
              "max_s": max(times), "frame_median_s": statistics.median(frames), "repeats": repeats}
    if reference is not None:
        reference = Path(reference)
        if setup == "reference":
            np.save(reference, linear)
        else:
            result["rmse_8bit"] = frame_error(linear, np.load(reference), cam)
            result["reference"] = f"{REFERENCE_CAMERA.samples} spp, factory light paths, no denoiser"
    return result
