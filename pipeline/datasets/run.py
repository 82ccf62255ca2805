"""`twin dataset CONFIG`: labelled image sets from a built scene.

    OUT/datasets/<name>/
        images/<frame_id>.png    the phone's picture (8-bit sRGB)
        masks/<frame_id>.png     16-bit instance ids, 0 = background
        parts/<frame_id>.png     16-bit part ids (parts.PARTS), 0 = no part; with the instance
                                 mask: which part of which instance
        behind_glass/<frame_id>.png  the same with every glass transparent: what is behind it
                                 (from the same label pass, parts.split)
        glare/<frame_id>.png     8-bit, 1 where the sensor clipped (sensor.clipped), else 0
        depth/<frame_id>.npy     float32 planar depth (m) along the optical axis, inf = sky
        records/<frame_id>.json  one frame's labels and annotations (what a resumed run keeps)
        frames.jsonl, coco.json  the first N frames' records, assembled at the end (coco.json: the
                                 instances, then each gauge with its keypoints); coco_parts.json:
                                 the parts' COCO annotations, each naming its parent instance
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

Frames are the engine's tasks like a build's (engine.worker.run_task on the executors
of engine.executors: one pool, one worker set-up, a dead worker reported as the
build reports one); each worker hands its frames to a Blender subprocess of its own
(blender_process.py, frame.py), which also runs under a dask worker's nanny.
"""

from __future__ import annotations

import functools
import json
import os
import time
from concurrent.futures import as_completed
from pathlib import Path

from ..engine.executors import EXECUTORS, outcome
from ..engine.worker import Workers, run_task
from ..errors import UserError
from ..files import atomic_write
from . import config as dataset_config, labels, parts as part_labels, wire_labels
from .blender_process import render_frame
from .plan import Planner, frame_id
from ..runtime.site import BuiltSite, load_site

RENDERER = "blender-cycles-cpu"
FOLDERS = ("images", "masks", "parts", "behind_glass", "glare", "depth", "records")
ANNOTATIONS = ("annotations", "part_annotations", "gauge_annotations")  # coco.json's and coco_parts.json's
THREADS = 2  # a frame's (CyclesScene.THREADS): the native thread pools of its worker get as many


# --- the run (the calling process) -------------------------------------------------------


def run_dataset(config_path, out, *, frames: int | None = None, executor: str = "local",
                scheduler: str | None = None, workers: int = 1, tasks_per_worker: int | None = None,
                sources: Path, progress=None, labels_as_lights: bool = False, indices=None) -> Path:
    """Render the config's first `frames` frames (all by default) that are not on disk
    yet, then write frames.jsonl and coco.json. Returns the dataset's folder.
    Frames run on the engine's executors (`executor`: "local", "dask" on a
    LocalCluster or on the cluster at `scheduler`, "in-process"), `workers` at once,
    each in a Blender subprocess of its worker (blender_process.py); `tasks_per_worker`:
    frames a Blender process renders before it is replaced (default: the config's);
    `labels_as_lights`: the label pass as it was before (the bench's "before");
    `indices`: these frames of the sequence instead of the first ones (the bench's
    frames with the sun in view)."""
    cfg = dataset_config.load(config_path)
    n = cfg.count if frames is None else frames
    if not 1 <= n <= cfg.count:
        # the sequence is the config's: frames past its count belong to no dataset
        raise UserError(cfg.path, "--frames", f"{n}: from 1 to the config's count, {cfg.count}")
    wanted = list(range(n)) if indices is None else sorted(set(indices))
    if not wanted or not 0 <= wanted[0] <= wanted[-1] < cfg.count:
        raise UserError(cfg.path, "indices", f"{wanted[:3]}...: frames from 0 to the config's count, {cfg.count}")
    out = Path(out)
    sources = Path(sources)
    site = load_site(out, sources)
    folder = out / "datasets" / cfg.name
    _claim(folder, cfg)
    planner = Planner(cfg, site, sources)
    t0 = time.perf_counter()
    union = sorted({t for i in wanted for t in planner.plan(i).visible_tags})
    plan_s = time.perf_counter() - t0
    todo = [i for i in wanted if not _done(folder, i)]
    log = blender_log(out, cfg.name)
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_bytes(b"")  # this run's
    # absolute: a worker of a cluster started elsewhere has a working folder of its own
    job = {"build": os.path.abspath(out), "sources": os.path.abspath(sources),
           "config": str(Path(config_path).resolve()), "folder": os.path.abspath(folder), "union": union,
           "log": os.path.abspath(log), **({"labels_as_lights": True} if labels_as_lights else {})}
    if progress:
        progress(0, len(todo))
    t0 = time.perf_counter()
    seconds, parts = [], []
    if todo:
        per_process = tasks_per_worker or cfg.sensor.tasks_per_worker
        parts = _render(cfg, job, todo, per_process, executor, scheduler, workers, log, progress)
        seconds = [p["seconds"] for p in parts]
    wall = time.perf_counter() - t0
    _assemble(folder, cfg, site, wanted)
    atomic_write(folder / "timings.json", json.dumps(
        {"frames": len(wanted), "rendered": len(todo), "executor": executor, "workers": workers, "plan_s": plan_s,
         "wall_s": wall, "frame_s": seconds, "scene_placements": len(union),
         **{k: [p.get(k) for p in parts] for k in ("render_s", "labels_s")}},
        indent=1, sort_keys=True) + "\n")
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
                                                f"parts/{fid}.png", f"behind_glass/{fid}.png", f"glare/{fid}.png",
                                                f"depth/{fid}.npy"))


def _assemble(folder: Path, cfg, site: BuiltSite, indices: list[int]) -> None:
    records = [json.loads((folder / "records" / f"{frame_id(i)}.json").read_text()) for i in indices]
    lines = [json.dumps({k: v for k, v in r.items() if k not in ANNOTATIONS}, sort_keys=True, separators=(",", ":"))
             for r in records]
    atomic_write(folder / "frames.jsonl", "\n".join(lines) + "\n")
    images = [{"id": i + 1, "file_name": r["image"], "width": r["camera"]["width"], "height": r["camera"]["height"],
               "frame_id": r["frame_id"]} for i, r in enumerate(records)]
    categories = wire_labels.categories(site, labels.categories(site.manifests))
    gauge = part_labels.gauge_category(categories, labels.KEYPOINTS)
    # the gauges after every instance: an instance's annotation keeps its id whether or not gauges are labelled
    anns = _numbered(records, "annotations") + [{**a, "category_id": gauge["id"]}
                                                for a in _numbered(records, "gauge_annotations")]
    coco = {"info": {"description": f"substation-twin dataset {cfg.name}", "version": cfg.digest[:12],
                     "year": int(records[0]["local_time"][:4]) if records else 0},
            "licenses": [], "images": images, "annotations": _renumber(anns), "categories": categories + [gauge]}
    atomic_write(folder / "coco.json", json.dumps(coco, sort_keys=True, separators=(",", ":")) + "\n")
    parts = _numbered(records, "part_annotations")
    atomic_write(folder / "coco_parts.json", json.dumps(
        {**coco, "annotations": parts, "categories": part_labels.part_categories()},
        sort_keys=True, separators=(",", ":")) + "\n")


def _numbered(records: list[dict], key: str) -> list[dict]:
    """The records' annotations under `key`, each with its image's id, numbered from 1."""
    return _renumber([{"image_id": i + 1, **a} for i, r in enumerate(records) for a in r.get(key, [])])


def _renumber(anns: list[dict]) -> list[dict]:
    return [{**a, "id": j + 1} for j, a in enumerate(anns)]


def _render(cfg, job: dict, todo: list[int], per_process: int, executor: str, scheduler: str | None,
            workers: int, log: Path, progress) -> list[dict]:
    """Frames `todo` on the engine's executor, each a run_task call; the first failure
    (a frame's own, or a dead worker) stops the run with the frame it names."""
    factory = EXECUTORS[executor]
    if scheduler is not None:
        factory = functools.partial(factory, scheduler=scheduler)
    pool = factory(Workers(count=workers, threads=THREADS))
    seconds = []
    try:
        futures = {pool.submit(run_task, render_frame, {"job": job, "index": i, "tasks_per_worker": per_process},
                               None): i for i in todo}
        for f in as_completed(futures):
            result = outcome(f)
            if not result["ok"]:
                why = result.get("user_error") or result["error"]
                raise UserError(cfg.path, f"frame {frame_id(futures[f])}", f"{why} (Blender's log: {log})")
            seconds.append({**result["result"], "seconds": result["seconds"]})
            if progress:
                progress(len(seconds), len(todo))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return seconds
