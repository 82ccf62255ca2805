"""`twin dataset CONFIG`: labelled image sets from a built scene.

    OUT/datasets/<name>/
        images/<frame_id>.png    the phone's picture (8-bit sRGB)
        masks/<frame_id>.png     16-bit instance ids, 0 = background
        depth/<frame_id>.npy     float32 planar depth (m) along the optical axis, inf = sky
        records/<frame_id>.json  one frame's labels and annotations (what a resumed run keeps)
        frames.jsonl, coco.json  the first N frames' records, assembled at the end
        dataset.json             config digest, frames, renderer; timings.json: seconds

Frames are independent tasks: frame i is a function of (config, built scene, i) alone
(dataset_plan.py), rendered in a scene that holds the meshes the run's frames see (the
union of their culled sets) and shows only its own, lit by every floodlight of the site
(not only those of the poles some frame sees). What a frame shows and what lights it
do not depend on which frames run beside it, so the bytes do not depend on the
executor, the number of workers or the order, a run of N frames is the first N of a
longer one, and a killed run resumes by rendering the frames whose record is missing
(every file is written by rename; the record last). Only the frames asked for are
planned (--frames N plans N, whatever the config's count).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from concurrent.futures import Executor, as_completed
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, ContextManager, Iterator

import numpy as np

from ..errors import UserError
from ..files import atomic_path, atomic_write
from . import config as dataset_config, labels
from .plan import FramePlan, Planner, frame_id, switch_angles
from ..perception.gauge import dial_of
from ..geometry.pinhole import intrinsics
from ..render.sensor import PhoneCamera
from ..runtime.site import BuiltSite, load_site

RENDERER = "blender-cycles-cpu"
FramePool = Callable[[int, int], ContextManager[Executor]]  # (workers, frames a worker renders before it goes)
FOLDERS = ("images", "masks", "depth", "records")


# --- the run (the calling process) -------------------------------------------------------


def run_dataset(config_path, out, *, frames: int | None = None, pool: FramePool | None = None,
                executor: str = "local", workers: int = 1, tasks_per_worker: int | None = None,
                sources: Path, progress=None) -> Path:
    """Render the config's first `frames` frames (all by default) that are not on disk
    yet, then write frames.jsonl and coco.json. Returns the dataset's folder.
    `pool`: where frames render (default local_frames, spawned processes here; see
    dask_frames); `executor`: its name in timings.json; `tasks_per_worker`: frames a
    Blender process renders before it is replaced (default: the config's)."""
    cfg = dataset_config.load(config_path)
    n = cfg.count if frames is None else frames
    if not 1 <= n <= cfg.count:
        # the sequence is the config's: frames past its count belong to no dataset
        raise UserError(cfg.path, "--frames", f"{n}: from 1 to the config's count, {cfg.count}")
    out = Path(out)
    sources = Path(sources)
    site = load_site(out, sources)
    folder = out / "datasets" / cfg.name
    _claim(folder, cfg)
    planner = Planner(cfg, site, sources)
    t0 = time.perf_counter()
    union = sorted({t for i in range(n) for t in planner.plan(i).visible_tags})
    plan_s = time.perf_counter() - t0
    todo = [i for i in range(n) if not _done(folder, i)]
    log = blender_log(out, cfg.name)
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_bytes(b"")  # this run's
    job = {"build": str(out), "sources": str(sources), "config": str(Path(config_path).resolve()),
           "folder": str(folder), "union": union, "log": str(log)}
    if progress:
        progress(0, len(todo))
    t0 = time.perf_counter()
    seconds = []
    if todo:
        with (pool or local_frames)(workers, tasks_per_worker or cfg.sensor.tasks_per_worker) as frame_pool:
            futures = [frame_pool.submit(render_frame, job, i) for i in todo]
            for f in as_completed(futures):
                try:
                    result = f.result()
                except Exception as e:  # noqa: BLE001 - a worker that died (a crash, killed for memory)
                    raise UserError(cfg.path, "frames", f"a worker stopped: {type(e).__name__}: {e} "
                                                        f"(Blender's log: {log})") from None
                if not result["ok"]:
                    raise UserError(cfg.path, f"frame {result['frame_id']}", result["error"])
                seconds.append(result["seconds"])
                if progress:
                    progress(len(seconds), len(todo))
    wall = time.perf_counter() - t0
    _assemble(folder, cfg, site, n)
    atomic_write(folder / "timings.json", json.dumps(
        {"frames": n, "rendered": len(todo), "executor": executor, "workers": workers, "plan_s": plan_s,
         "wall_s": wall, "frame_s": seconds, "scene_placements": len(union)}, indent=1, sort_keys=True) + "\n")
    return folder


def blender_log(out: Path, name: str) -> Path:
    """Where the Blender processes of dataset `name` write their log (thousands of
    lines a run: not the terminal's)."""
    return Path(out) / "logs" / f"dataset_{name}.log"


def _claim(folder: Path, cfg) -> None:
    """A dataset folder belongs to one config: resuming with another would mix frames."""
    stamp = folder / "dataset.json"
    if stamp.is_file():
        try:
            digest = json.loads(stamp.read_text()).get("config_sha256")
        except (OSError, json.JSONDecodeError):
            digest = None
        if digest != cfg.digest:
            raise UserError(stamp, cfg.name, "made from another version of the config: delete the folder or "
                                             "change dataset.name to start a new dataset")
    for sub in FOLDERS:
        (folder / sub).mkdir(parents=True, exist_ok=True)
    atomic_write(stamp, json.dumps({"dataset": cfg.name, "config": cfg.path.name, "config_sha256": cfg.digest,
                                    "seed": cfg.seed, "count": cfg.count, "renderer": RENDERER},
                                   indent=1, sort_keys=True) + "\n")


def _done(folder: Path, index: int) -> bool:
    fid = frame_id(index)
    return all((folder / p).is_file() for p in (f"records/{fid}.json", f"images/{fid}.png", f"masks/{fid}.png",
                                                f"depth/{fid}.npy"))


def _assemble(folder: Path, cfg, site: BuiltSite, n: int) -> None:
    records = [json.loads((folder / "records" / f"{frame_id(i)}.json").read_text()) for i in range(n)]
    lines = [json.dumps({k: v for k, v in r.items() if k != "annotations"}, sort_keys=True,
                        separators=(",", ":")) for r in records]
    atomic_write(folder / "frames.jsonl", "\n".join(lines) + "\n")
    images, anns = [], []
    for i, r in enumerate(records):
        images.append({"id": i + 1, "file_name": r["image"], "width": r["camera"]["width"],
                       "height": r["camera"]["height"], "frame_id": r["frame_id"]})
        for a in r["annotations"]:
            anns.append({"id": len(anns) + 1, "image_id": i + 1, **a})
    coco = {"info": {"description": f"substation-twin dataset {cfg.name}", "version": cfg.digest[:12],
                     "year": int(records[0]["local_time"][:4]) if records else 0},
            "licenses": [], "images": images, "annotations": anns,
            "categories": labels.categories(site.manifests)}
    atomic_write(folder / "coco.json", json.dumps(coco, sort_keys=True, separators=(",", ":")) + "\n")


def dask_frames(dask_executor, scheduler: str | None = None) -> FramePool:
    """Frames on dask.distributed through `dask_executor` (the builder's; handed in,
    since the runtime does not import the builder): a LocalCluster, or the cluster at
    `scheduler`, whose workers see OUT and the sources at the same paths.

    A dask worker runs tasks on threads, and Blender renders on its main thread only:
    each worker keeps one Blender process of its own (a one-process pool, replaced
    after `tasks_per_worker` frames), which a worker may start only when it is not a
    daemon (`distributed.worker.daemon: false` for workers started elsewhere)."""

    @contextmanager
    def pool(workers: int, tasks_per_worker: int) -> Iterator[Executor]:
        import dask
        import distributed  # noqa: F401 - its config defaults load before one of them is set

        with dask.config.set({"distributed.worker.daemon": False}):
            with dask_executor(workers, scheduler) as executor:
                yield _InBlenderProcess(executor, tasks_per_worker)

    return pool


@contextmanager
def local_frames(workers: int, tasks_per_worker: int) -> Iterator[Executor]:
    """Spawned processes (Blender does not survive a fork), each replaced after
    `tasks_per_worker` frames, so a long run's memory stays that of a fresh one."""
    import multiprocessing
    import shutil
    from concurrent.futures import ProcessPoolExecutor

    from ..scratch import pool_folder

    temp = pool_folder()  # the scratch frames and Blender's session folders, whatever becomes of a process
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               max_tasks_per_child=tasks_per_worker, initializer=init_blender_process,
                               initargs=(temp,))
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        shutil.rmtree(temp, ignore_errors=True)


def init_blender_process(temp: str | None = None) -> None:
    """A spawned child starts with its parent's sys.path: when the parent imported bpy,
    that holds Blender's scripts/modules, whose pure-Python `bpy` package would shadow
    the real one (No module named '_bpy'). Those entries go; importing bpy adds them back.
    Its temporary files go to a folder of its own in `temp` (scratch)."""
    import sys

    from ..scratch import use_temp_folder

    sys.path[:] = [p for p in sys.path if f"{os.sep}bpy{os.sep}" not in p]
    use_temp_folder(temp)
    _exit_with_parent()


def _exit_with_parent() -> None:
    """A Blender process ends when the process that started it is gone (a dask
    worker closed by its nanny, a killed `twin dataset`), instead of waiting on a
    pipe nobody writes to."""
    import threading

    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


class _InBlenderProcess:
    """Submits `render_frame` calls to an executor's workers, each of which hands them
    to its own Blender process."""

    def __init__(self, pool: Executor, tasks_per_worker: int):
        self.pool, self.tasks_per_worker = pool, tasks_per_worker

    def submit(self, fn, *args):
        return self.pool.submit(_in_blender_process, fn, args, self.tasks_per_worker)


_BLENDER = None  # in a dask worker: its Blender process (a one-process pool), kept between frames


def _in_blender_process(fn, args: tuple, tasks_per_worker: int):
    global _BLENDER
    if _BLENDER is not None and getattr(_BLENDER, "_broken", False):
        _BLENDER = None  # its process died (a crash): the next frame starts another
    if _BLENDER is None:
        _BLENDER = local_frames(1, tasks_per_worker)
        import atexit

        atexit.register(_BLENDER.__exit__, None, None, None)
        _BLENDER = _BLENDER.__enter__()
    return _BLENDER.submit(fn, *args).result()


# --- one frame (a worker) -----------------------------------------------------------------

_WORKER: dict = {}  # the scene a worker keeps between frames of one dataset


def render_frame(job: dict, index: int) -> dict:
    """Render, label and write frame `index`; errors come back as data."""
    fid = frame_id(index)
    try:
        t0 = time.perf_counter()
        _log_to(job.get("log"))
        ctx = _context(job)
        _frame(ctx, Path(job["folder"]), ctx["planner"].plan(index))
        return {"ok": True, "frame_id": fid, "seconds": time.perf_counter() - t0}
    except UserError as e:
        return {"ok": False, "frame_id": fid, "error": str(e)}
    except Exception as e:  # noqa: BLE001 - the run reports it with the frame it stopped at
        import traceback

        return {"ok": False, "frame_id": fid, "error": f"{type(e).__name__}: {e}\n{traceback.format_exc()}"}


_LOG: list[str] = []  # in a Blender process: the log its file descriptors 1 and 2 go to


def _log_to(path: str | None) -> None:
    """Blender logs on file descriptors 1 and 2 of its process (the terminal's, in a
    spawned child): a frame's process appends both to the run's log, from its first
    frame on, before bpy is imported. Never the calling process's own."""
    import multiprocessing

    if not path or _LOG == [path] or multiprocessing.parent_process() is None:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    _LOG[:] = [path]


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
    ctx = open_scene(site, cam, cfg.seed, job["union"])
    _WORKER.clear()
    _WORKER.update(ctx, key=key, cfg=cfg, planner=Planner(cfg, site, Path(job["sources"])))
    return _WORKER


def open_scene(site: BuiltSite, cam: PhoneCamera, seed: int, tags: list[str]) -> dict:
    """A Cycles scene holding `tags` (and the terrain, and the floodlights of the
    lighting poles among them), every placement labelled with its instance id: what
    `shoot` renders frames in (a dataset's worker, `twin serve`'s render process)."""
    from ..render.cycles import CyclesScene

    scene = CyclesScene(site, cam, seed)
    scene.load_many(tags)
    scene.load_terrain()
    # every floodlight of the site, whether or not a frame of this run sees its pole:
    # a frame's light is then the same whichever frames share its worker
    scene.add_lamps([p["tag"] for p in site.placements if p["asset"] == "lighting_pole"])
    ids = labels.instance_ids(site.placements)
    scene.set_instances(ids)
    cats = {c["name"]: c["id"] for c in labels.categories(site.manifests)}
    category_of = {p["tag"]: cats.get(site.manifests.get(p["asset"], {}).get("category") or p["asset"], 0)
                   for p in site.placements}
    return {"site": site, "cam": cam, "scene": scene, "ids": ids, "tag_of": {v: k for k, v in ids.items()},
            "category_of": category_of}


def _frame(ctx: dict, folder: Path, plan: FramePlan) -> None:
    rgb, ids, depth, record = shoot(ctx, plan)
    fid = plan.frame_id
    _write_png(folder / "images" / f"{fid}.png", rgb[..., ::-1])
    _write_png(folder / "masks" / f"{fid}.png", ids)
    with atomic_path(folder / "depth" / f"{fid}.npy") as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, depth, allow_pickle=False)
    atomic_write(folder / "records" / f"{fid}.json", json.dumps(record, sort_keys=True, indent=1) + "\n")


def shoot(ctx: dict, plan: FramePlan) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """One frame in an `open_scene`: (RGB uint8 (h, w, 3), instance ids uint16, planar
    depth float32, the frame's record). Only what the plan names changes in the scene
    (seed, shown placements, switch joints, camera, sun and sky, bound visuals)."""
    from ..render.frames import develop_shot

    site, scene, cam, shot = ctx["site"], ctx["scene"], ctx["cam"], plan.shot
    scene.scene.cycles.seed = plan.seed
    scene.show_only(plan.visible_tags)
    for tag, position in plan.switches.items():
        if tag in scene.objects:
            m = site.manifests[site.placement(tag)["asset"]]
            scene.set_joints(tag, m, switch_angles(m, position))
    scene.set_shot(shot)
    scene.set_sky(plan.aerosol)
    linear = scene.render()
    rgb, gain, wb, veil = develop_shot(scene, shot, linear, cam, None, plan.seed)
    ids, depth = scene.render_labels()
    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    return rgb, ids, depth, _record(ctx, plan, k, ids, depth, gain, wb, veil)


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes through OpenCV (no timestamps; 16-bit when the array is): BGR or one channel."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(pixels))
    if not ok:
        raise RuntimeError("could not encode a PNG")
    return buf.tobytes()


def _write_png(path: Path, pixels: np.ndarray) -> None:
    try:
        data = encode_png(pixels)
    except RuntimeError:
        raise RuntimeError(f"could not encode {path}") from None
    atomic_write(path, data)


def _record(ctx: dict, plan: FramePlan, k: dict, ids: np.ndarray, depth: np.ndarray, gain: float,
            wb: np.ndarray, veil: float) -> dict:
    site, shot, fid = ctx["site"], plan.shot, plan.frame_id
    gauges = []
    for p in site.placements:
        dial = dial_of(site.pose(p), site.manifests.get(p["asset"], {}))
        if dial is None or p["tag"] not in plan.oil_levels:
            continue
        seen = labels.gauge_visibility(dial, shot.cam_pose, k, ids, depth, ctx["ids"][p["tag"]])
        if seen["visible"]:  # the pointer's rows as posed in this frame: the study's H numerator, true
            seen["pointer_rows_px"] = ctx["scene"].pointer_rows(p["tag"], shot.cam_pose, k)
        gauges.append({"tag": p["tag"], "reading": plan.oil_levels[p["tag"]].get(dial.binding["variable"]),
                       "unit": "%", **seen})
    kmat = [[k["fx"], 0.0, k["cx"]], [0.0, k["fy"], k["cy"]], [0.0, 0.0, 1.0]]
    return {
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
        "gauges": gauges,
        "instances": int(len(np.unique(ids[ids > 0]))),
        "annotations": labels.annotations(ids, ctx["tag_of"], ctx["category_of"]),
    }
