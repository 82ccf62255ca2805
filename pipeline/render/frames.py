"""Rendering a sequence of shots in one Cycles scene: each frame developed by the phone
model and written with its labels (what was rendered, in numbers)."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from ..files import atomic_write
from .cycles import CyclesScene
from ..perception.gauge import Dial, placed_dial
from ..geometry.pinhole import cull, intrinsics
from .sensor import PhoneCamera, develop, frame_seed, lens_glare, metered_gain, metered_white_balance
from ..runtime.site import Shot, BuiltSite

def frame_labels(shot: Shot, k: dict, site: BuiltSite, gain: float, veil: float, dial: Dial | None) -> dict:
    """Labels of one frame: what was rendered, in numbers (`dial`: the target's, gauge.placed_dial)."""
    pose = shot.cam_pose
    levels = shot.states.get(shot.target, {})
    level = levels.get("oil_level_tank")
    gauges = {"gauge_tank": dial.box(pose, k) if dial is not None else {"box": None, "visible": False}}
    return {
        "time": shot.when.isoformat(),
        "time_utc": shot.when.astimezone(dt.timezone.utc).isoformat(),
        "sun": {"azimuth_deg": math.degrees(shot.sun_azimuth), "elevation_deg": math.degrees(shot.sun_elevation),
                "irradiance_w_m2": shot.irradiance, "direct_normal_w_m2": shot.dni},
        "camera": {"zoom": shot.lens.zoom, "near": shot.lens.near, "far": shot.lens.far, **k,
                   "pose": [float(v) for v in pose.reshape(16)], "convention": "camera looks down -Z, +Y up; ENU",
                   "exposure_gain": gain, "veil": veil},
        "target": shot.target,
        "oil_levels": {v: float(x) for v, x in sorted(levels.items())},
        "pointer_angle_rad": dial.angle(level) if level is not None and dial is not None else None,
        "gauges": gauges,
    }


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_png(path: Path, rgb: np.ndarray) -> str:
    """PNG without timestamps (OpenCV writes none), returns its sha256."""
    import cv2

    ok, buf = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    data = buf.tobytes()
    atomic_write(path, data)
    return _sha(data)


def write_json(path: Path, data) -> None:
    atomic_write(path, json.dumps(data, sort_keys=True, indent=1, allow_nan=False) + "\n")




def render_shots(site: BuiltSite, shots: list[Shot], folder: Path, *, cam: PhoneCamera, seed: int,
                 gain: float | None = None, names: list[str] | None = None, meter_each: bool = False,
                 progress=None) -> list[dict]:
    """Render shots into folder/<name>.png + <name>.json; one scene (loaded once, kept
    between frames), exposure locked at the first shot unless `gain` is given or
    `meter_each` (the phone re-meters every shot). Returns one record per frame.
    `progress(done, total)` is called before the first and after each frame."""
    folder.mkdir(parents=True, exist_ok=True)
    if progress:
        progress(0, len(shots))
    lock = (gain, (1.0, 1.0, 1.0)) if gain is not None else None
    bl = CyclesScene(site, cam, seed)
    try:
        populate(bl, site, shots)
        records = []
        for i, shot in enumerate(shots):
            records.append(_one(bl, site, shot, folder, (names or [])[i] if names else f"frame_{i:04d}",
                                cam, lock))
            if progress:
                progress(i + 1, len(shots))
            if lock is None and not meter_each:
                c = records[-1]["labels"]["camera"]
                lock = (c["exposure_gain"], c["white_balance"])
        return records
    finally:
        bl.close()


def populate(bl: CyclesScene, site: BuiltSite, shots: list[Shot]) -> None:
    """Load what any shot's camera sees or what shadows into it, the targets at least,
    and the lighting poles near the targets as lamps."""
    spheres = site.spheres()
    wanted = {s.target for s in shots}
    for shot in shots:
        k = intrinsics(shot.lens.hfov, bl.cam.width, bl.cam.height)
        dist = float(np.linalg.norm(site.pose(site.placement(shot.target))[:3, 3] - shot.cam_pose[:3, 3]))
        far = min(shot.lens.far, dist + 15.0)  # beyond the target, its own tank hides the rest
        sun = shot.sun_dir if shot.sun_elevation > 0 else None
        wanted |= {it["tag"] for it in cull(spheres, shot.cam_pose, k, shot.lens.near, far, sun)}
    bl.load_many(sorted(wanted))
    bl.load_terrain()  # the ground: shadows, bounce light, what the gauge glass reflects
    centres = [site.pose(site.placement(t))[:3, 3] for t in {s.target for s in shots}]
    poles = [p["tag"] for p in site.placements if p["asset"] == "lighting_pole" and p["asset"] in site.manifests
             and min(np.linalg.norm(np.array(p["enu"]) - c) for c in centres) < 120.0]
    bl.add_lamps(sorted(poles))


def shot_key(shot: Shot) -> str:
    """What a frame shows, as text: its instant, camera pose and zoom. The sensor's noise
    is drawn from it (with the run's seed), as Cycles' own noise depends only on the
    seed and the scene, so a frame is the same wherever it stands in a sequence."""
    pose = ",".join(f"{v:.9g}" for v in np.asarray(shot.cam_pose, float).reshape(16))
    return f"{shot.when.isoformat()}|{pose}|{shot.lens.zoom:.9g}"


def develop_shot(bl: CyclesScene, shot: Shot, linear: np.ndarray, cam: PhoneCamera, lock,
                 seed: int = 0) -> tuple[np.ndarray, float, np.ndarray, float]:
    """The phone's picture of one linear render: (RGB uint8, gain, white balance, veil).
    `lock` = (gain, white balance) of a locked exposure, or None to meter this frame;
    `seed` draws the frame's sensor noise."""
    gain, wb, veil = shot_exposure(bl, shot, linear, cam, lock)
    rgb = develop(linear, gain, veil, wb, cam, seed=seed)
    return rgb, gain, wb, float(veil.mean())


def shot_exposure(bl: CyclesScene, shot: Shot, linear: np.ndarray, cam: PhoneCamera,
                  lock) -> tuple[float, np.ndarray, np.ndarray]:
    """(gain, white balance, the lens's veil (h, w, 3)) of one linear render, as
    develop_shot develops it."""
    if lock is None:
        gain, wb = metered_gain(linear, cam), metered_white_balance(linear, cam)
    else:
        gain, wb = lock[0], np.asarray(lock[1], float)
    k = intrinsics(shot.lens.hfov, linear.shape[1], linear.shape[0])
    visible = shot.sun_elevation > 0 and bl.sun_visible(shot.cam_pose[:3, 3], shot.sun_dir)
    veil = lens_glare(linear, gain, wb, shot.cam_pose, k, shot.sun_dir, shot.dni if visible else 0.0, cam)
    return gain, wb, veil


def _one(bl: CyclesScene, site: BuiltSite, shot: Shot, folder: Path, name: str, cam: PhoneCamera, lock) -> dict:
    """One frame; `lock` = (gain, white balance) of a locked exposure, or None to meter."""
    bl.set_shot(shot)
    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    t0 = time.perf_counter()
    linear = bl.render()
    seconds = time.perf_counter() - t0
    rgb, gain, wb, veil = develop_shot(bl, shot, linear, cam, lock, frame_seed(bl.scene.cycles.seed, shot_key(shot)))
    labels = frame_labels(shot, k, site, gain, veil, placed_dial(site, shot.target))
    labels["pointer_rows_px"] = bl.pointer_rows(shot.target, shot.cam_pose, k)
    labels["camera"]["white_balance"] = [float(v) for v in wb]
    labels["render_s"] = seconds
    labels["frame_s"] = time.perf_counter() - t0  # render + develop (ISP)
    digest = write_png(folder / f"{name}.png", rgb)
    labels["image"] = f"{name}.png"
    labels["sha256"] = digest
    write_json(folder / f"{name}.json", {k2: v for k2, v in labels.items() if k2 not in ("render_s", "frame_s")})
    return {"name": name, "image": f"{name}.png", "sha256": digest, "labels": labels, "rgb": rgb}
