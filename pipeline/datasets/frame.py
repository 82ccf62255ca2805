"""A frame in a Blender process (blender_process.py): the scene a process keeps
(`open_scene`), one frame's picture, labels and record in it (`shoot`), and a dataset's
frame written to its folder (`render`). `twin dataset`'s workers and `twin serve`'s
render process (live/render_worker.py) both shoot through here, so a live render is
byte-identical to the dataset's frame of the same camera, instant, state and seed."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..files import atomic_path, atomic_write
from ..geometry.pinhole import intrinsics
from ..perception.gauge import dial_of
from ..render import appearance
from ..render.sensor import PhoneCamera, clipped, develop, metered_gain, metered_white_balance
from ..runtime.site import BuiltSite, load_site
from . import config as dataset_config, labels, parts as part_labels, wire_labels
from .plan import FramePlan, Planner, switch_angles

_WORKER: dict = {}  # the scene a Blender process keeps between frames of one dataset


def render(job: dict, index: int) -> dict:
    """Render, label and write frame `index` of the run `job` (run.py); returns the
    seconds of its picture (render_s) and of its label pass (labels_s)."""
    ctx = _context(job)
    shot = shoot(ctx, ctx["planner"].plan(index), job.get("labels_as_lights", False))
    write(Path(job["folder"]), shot)
    return {k: shot[k] for k in ("render_s", "labels_s")}


def _context(job: dict) -> dict:
    key = json.dumps(job, sort_keys=True)
    if _WORKER.get("key") == key:
        return _WORKER
    if _WORKER.get("scene") is not None:
        _WORKER["scene"].close()
    cfg = dataset_config.load(job["config"])
    site = load_site(Path(job["build"]), Path(job["sources"]))
    cam = PhoneCamera(width=cfg.sensor.width, height=cfg.sensor.height, samples=cfg.sensor.samples,
                      render_denoise=cfg.sensor.render_denoise)
    ctx = open_scene(site, cam, cfg.seed, job["union"], looks=cfg.appearance is not None)
    _WORKER.clear()
    _WORKER.update(ctx, key=key, planner=Planner(cfg, site, Path(job["sources"])))
    return _WORKER


def open_scene(site: BuiltSite, cam: PhoneCamera, seed: int, tags: list[str], looks: bool = False) -> dict:
    """A Cycles scene holding `tags` (and the terrain, and every floodlight of the site),
    every placement labelled with its instance id and each object with its part id:
    what `shoot` renders frames in. `looks`: the materials take a frame's appearance
    (render/appearance.py; without, they stay as imported)."""
    from ..render.cycles import CyclesScene

    scene = CyclesScene(site, cam, seed)
    scene.load_many(tags)
    scene.load_terrain()
    # every floodlight of the site, whether or not a frame of this run sees its pole:
    # a frame's light is then the same whichever frames share its worker
    scene.add_lamps([p["tag"] for p in site.placements if p["asset"] == "lighting_pole"])
    ids = labels.instance_ids(site.placements)
    scene.set_instances(ids)
    scene.set_parts({tag: {name: part_labels.part_of(name) for name in objs} for tag, objs in scene.objects.items()},
                    see_through=part_labels.GLASS)
    if looks:
        appearance.prepare(scene)
    cats = {c["name"]: c["id"] for c in labels.categories(site.manifests)}
    category_of = {p["tag"]: cats.get(site.manifests.get(p["asset"], {}).get("category") or p["asset"], 0)
                   for p in site.placements}
    return wire_labels.attach({"site": site, "cam": cam, "scene": scene, "ids": ids,
                               "tag_of": {v: k for k, v in ids.items()}, "category_of": category_of, "looks": looks})


def shoot(ctx: dict, plan: FramePlan, labels_as_lights: bool = False) -> dict:
    """One frame in an `open_scene`: {"plan", "rgb" uint8 (h, w, 3), "ids" uint16,
    "depth" float32 (planar, m), "parts" uint16, "behind" uint16 (the parts with the
    glass transparent, parts.py), "clip" bool (the sensor's clipped pixels), "record",
    "render_s", "labels_s" (the seconds of the picture and of the label pass)}. Only what the plan names changes in the
    scene (seed, shown placements, switch joints, camera, sun and sky, bound visuals,
    the look). `labels_as_lights`: the label pass as it was before issue 38 (the bench)."""
    from ..render.frames import shot_exposure

    site, scene, cam, shot, look = ctx["site"], ctx["scene"], ctx["cam"], plan.shot, plan.look
    if look is not None and not ctx["looks"]:
        raise ValueError(f"frame {plan.frame_id} has a look, and its scene was opened without looks")
    scene.scene.cycles.seed = plan.seed
    scene.show_only(plan.visible_tags)
    for tag, position in plan.switches.items():
        if tag in scene.objects:
            m = site.manifests[site.placement(tag)["asset"]]
            scene.set_joints(tag, m, switch_angles(m, position))
    scene.set_shot(shot)
    scene.set_sky(plan.aerosol)
    if ctx["looks"]:
        appearance.apply(scene, look, plan.aerosol)
    t0 = time.perf_counter()
    linear = scene.render()
    t1 = time.perf_counter()
    lock = None
    if look is not None:  # the lens's vignetting, and the exposure compensated from the metered one
        linear = appearance.vignette(linear, look["vignetting"])
        lock = (metered_gain(linear, cam) * 2.0 ** look["exposure_ev"], metered_white_balance(linear, cam))
    gain, wb, veil = shot_exposure(scene, shot, linear, cam, lock)
    rgb = develop(linear, gain, veil, wb, cam, seed=plan.seed)
    clip = clipped(linear, gain, veil, wb)
    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    # The pointers as rendered, read while the scene is as evaluated for the render: the
    # label pass swaps the materials and back, and reading them after it evaluates the
    # whole scene again.
    pointer_rows = {tag: scene.pointer_rows(tag, shot.cam_pose, k) for tag in plan.oil_levels}
    t2 = time.perf_counter()
    ids, depth, code = scene.render_labels(as_lights=labels_as_lights)
    parts, behind = part_labels.split(code)
    wired, depth, parts = wire_labels.label_frame(ctx, shot, ids, depth, parts)
    behind = np.where(wired != ids, 0, behind).astype(behind.dtype)  # no gauge is seen through a wire
    ids = wired
    t3 = time.perf_counter()
    record = _record(ctx, plan, k, ids, depth, gain, wb, float(veil.mean()), clip, pointer_rows)
    record["part_annotations"] = part_labels.part_annotations(ids, parts, ctx["tag_of"], behind)
    record["gauge_annotations"] = [a for a in (part_labels.gauge_annotation(ids, parts, ctx["ids"][g["tag"]], g["tag"],
                                                                            g["keypoints"])
                                               for g in record["gauges"] if "keypoints" in g) if a is not None]
    return {"plan": plan, "rgb": rgb, "ids": ids, "depth": depth, "parts": parts, "behind": behind, "clip": clip,
            "record": record, "render_s": t1 - t0, "labels_s": t3 - t2}


def write(folder: Path, shot: dict) -> None:
    """A shot's files in a dataset's folder, each by rename, the record last (what a
    resumed run counts as done)."""
    fid = shot["plan"].frame_id
    atomic_write(folder / "images" / f"{fid}.png", encode_png(shot["rgb"][..., ::-1]))
    atomic_write(folder / "masks" / f"{fid}.png", encode_png(shot["ids"]))
    atomic_write(folder / "glare" / f"{fid}.png", encode_png(shot["clip"].astype(np.uint8)))
    atomic_write(folder / "parts" / f"{fid}.png", encode_png(shot["parts"]))
    atomic_write(folder / "behind_glass" / f"{fid}.png", encode_png(shot["behind"]))
    with atomic_path(folder / "depth" / f"{fid}.npy") as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, shot["depth"], allow_pickle=False)
    atomic_write(folder / "records" / f"{fid}.json", json.dumps(shot["record"], sort_keys=True, indent=1) + "\n")


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes through OpenCV (no timestamps; 16-bit when the array is): BGR or one channel."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(pixels))
    if not ok:
        raise RuntimeError(f"could not encode a PNG of {pixels.shape} {pixels.dtype}")
    return buf.tobytes()


def _gauges(ctx: dict, plan: FramePlan, k: dict, ids: np.ndarray, depth: np.ndarray, clip: np.ndarray,
            pointer_rows: dict) -> list:
    site, shot = ctx["site"], plan.shot
    gauges = []
    for p in site.placements:
        dial = dial_of(site.pose(p), site.manifests.get(p["asset"], {}))
        if dial is None or p["tag"] not in plan.oil_levels:
            continue
        seen = labels.gauge_visibility(dial, shot.cam_pose, k, ids, depth, ctx["ids"][p["tag"]])
        reading = plan.oil_levels[p["tag"]].get(dial.binding["variable"])
        angle = None if reading is None else dial.angle(reading)
        if angle is not None:
            seen["keypoints"] = labels.gauge_keypoints(dial, angle, shot.cam_pose, k, ids, depth, ctx["ids"][p["tag"]])
        # the pointer's rows as posed in this frame: the study's H numerator, true
        if seen["visible"] and angle is not None:
            seen["pointer_rows_px"] = pointer_rows[p["tag"]]
            seen.update(labels.pointer_glare(labels.pointer_pixels(dial, angle, shot.cam_pose, k), clip))
        gauges.append({"tag": p["tag"], "reading": reading, "unit": "%",
                       "pointer_angle_deg": None if angle is None else math.degrees(angle), **seen})
    return gauges


def _record(ctx: dict, plan: FramePlan, k: dict, ids: np.ndarray, depth: np.ndarray, gain: float,
            wb: np.ndarray, veil: float, clip: np.ndarray, pointer_rows: dict) -> dict:
    shot, fid = plan.shot, plan.frame_id
    kmat = [[k["fx"], 0.0, k["cx"]], [0.0, k["fy"], k["cy"]], [0.0, 0.0, 1.0]]
    record = {
        "frame_id": fid, "index": plan.index, "seed": plan.seed,
        "image": f"images/{fid}.png", "mask": f"masks/{fid}.png", "depth": f"depth/{fid}.npy",
        "camera": {"name": plan.camera, "K": kmat, "pose": shot.cam_pose.tolist(), "width": k["width"],
                   "height": k["height"], "zoom": shot.lens.zoom, "hfov_deg": math.degrees(k["hfov"]),
                   "near": shot.lens.near, "far": shot.lens.far, "target": shot.target,
                   "convention": "pose: world-from-camera, ENU metres; the camera looks down its -Z, +Y up; "
                                 "pixel (0, 0) is the top-left corner of the top-left pixel"},
        "exposure": {"gain": gain, "white_balance": [float(v) for v in wb], "veil": veil},
        "sun": {"azimuth_deg": math.degrees(shot.sun_azimuth), "elevation_deg": math.degrees(shot.sun_elevation),
                "irradiance": shot.irradiance, "irradiance_unit": "W/m2, direct on a horizontal surface"},
        "sky": {"tau_atm": plan.tau_atm, "aerosol_density": plan.aerosol},
        "local_time": shot.when.isoformat(),
        "states": {"oil_levels": plan.oil_levels, "switches": plan.switches},
        "gauges": _gauges(ctx, plan, k, ids, depth, clip, pointer_rows),
        "instances": int(len(np.unique(ids[ids > 0]))),
        **({"appearance": plan.look} if plan.look is not None else {}),
        "parts": f"parts/{fid}.png", "behind_glass": f"behind_glass/{fid}.png",
        "gauge_keypoints": list(labels.KEYPOINTS),
        "glare": {"mask": f"glare/{fid}.png", "clipped_px": int(clip.sum()),
                  "definition": "1 where the sensor clips: the exposed radiance (render + lens veil) "
                                "reaches full scale in a channel, before noise"},
        "annotations": labels.annotations(ids, ctx["tag_of"], ctx["category_of"]),
    }
    return wire_labels.add_to_record(ctx, record, ids, shot)
