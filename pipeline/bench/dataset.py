"""The dataset section: seconds per labelled frame (render, develop, instance and
depth passes, annotations, files) of the shipped dataset config at 640x480, the
same frames rendered side by side by:

- local_1, local_2: the local executor with one and two worker processes;
- dask_1, dask_2:   dask.distributed (a LocalCluster) with one and two workers;
- per_frame:        the study's own method: a fresh Blender per frame that imports
                    the scene's packages again and renders once (one worker replaced
                    after every frame);
- labels_before:    local_1 with the label pass as it was before issue 38 (its
                    emission sampled as light: a light tree over every triangle), in
                    the same bench run: `labels` compares the two per frame (the
                    label pass's share, and after/before), the files being identical.

Each run starts from an empty dataset folder; every run's files must be byte-identical
to local_1's (recorded). The quick mode renders 2 frames at 160x120.

`sun_in_view`: the labels where glare is in the picture (issue 38 item 8): frames of
the same config in the first and last hours of daylight whose camera has the sun in its
field of view, found by planning (no render), rendered, and every annotation of theirs
decoded against its masks (datasets.verify)."""

from __future__ import annotations

import json
import re
import statistics
import time
from pathlib import Path

from .context import Context

CONFIG = Path("datasets") / "inspection_route.toml"
RUNS = (("local_1", "local", 1, None), ("local_2", "local", 2, None), ("dask_1", "dask", 1, None),
        ("dask_2", "dask", 2, None), ("per_frame", "local", 1, 1), ("labels_before", "local", 1, None))


def _config(source: Path, dst: Path, frames: int, width: int, height: int) -> Path:
    """The shipped config with `frames` frames at width x height."""
    text = source.read_text()
    for key, value in (("count", frames), ("width", width), ("height", height)):
        # whole-number lines only: a camera's `height = 1.2` stays
        text = re.sub(rf"(?m)^{key} = \d+[ \t]*$", f"{key} = {value}", text)
    dst.write_text(text)
    return dst


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "timings.json"}


def dataset_section(ctx: Context) -> dict:
    from ..datasets.run import run_dataset

    built = ctx.built or ctx.out
    source = ctx.sources / CONFIG
    if not source.is_file() or not (built / "scene" / "placements.json").is_file():
        return {"skipped": f"no {CONFIG} in these sources, or no built scene"}
    frames = ctx.pick(2, 8)
    width, height = ctx.pick((160, 120), (640, 480))
    runs, reference = {}, None
    config = _config(source, ctx.work / "dataset.toml", frames, width, height)
    for name, executor, workers, tasks in RUNS:
        out = ctx.work / "dataset" / name
        out.mkdir(parents=True)
        for sub in ("models", "scene"):
            (out / sub).symlink_to(built / sub)
        t0 = time.perf_counter()
        folder = run_dataset(config, out, executor=executor, workers=workers, tasks_per_worker=tasks,
                             sources=ctx.sources, labels_as_lights=name == "labels_before")
        wall = time.perf_counter() - t0
        timings = json.loads((folder / "timings.json").read_text())
        files = _files(folder)
        if reference is None:
            reference = files
        per_frame = sorted(timings["frame_s"])
        runs[name] = {
            "executor": executor, "workers": workers, "tasks_per_worker": tasks, "frames": frames,
            "wall_s": wall, "seconds_per_frame": wall / frames, "frames_per_minute": 60.0 * frames / wall,
            # a worker's first frame loads the scene; the rest show the steady cost
            "first_frame_s": max(per_frame), "steady_frame_median_s": statistics.median(per_frame[:-workers] or per_frame),
            "plan_s": timings["plan_s"], "scene_placements": timings["scene_placements"],
            "render_median_s": statistics.median(timings["render_s"]),
            "labels_median_s": statistics.median(timings["labels_s"]),
            "identical_to_local_1": files == reference}
    base = runs["local_1"]["seconds_per_frame"]
    sun = sun_in_view(ctx, _config(source, ctx.work / "sun.toml", ctx.pick(400, 2000), width, height), built,
                      ctx.pick(2, 8))
    before, after = runs["labels_before"], runs["local_1"]
    parts = ("steady_frame_median_s", "render_median_s", "labels_median_s")
    labels = {"before": {k: before[k] for k in parts}, "after": {k: after[k] for k in parts},
              "label_share_before": _share(before), "label_share_after": _share(after),
              "frame_after_to_before": after["steady_frame_median_s"] / before["steady_frame_median_s"],
              "labels_after_to_before": after["labels_median_s"] / before["labels_median_s"],
              "identical": before["identical_to_local_1"]}
    return {"labels": labels, "sun_in_view": sun, "frame": f"{width}x{height}, labels included", "config": str(CONFIG), "runs": runs,
            "ratios": {"dask_2_to_local_2": runs["dask_2"]["seconds_per_frame"] / runs["local_2"]["seconds_per_frame"],
                       "dask_1_to_local_1": runs["dask_1"]["seconds_per_frame"] / base,
                       "throughput_2_to_1_workers": runs["local_2"]["frames_per_minute"]
                       / runs["local_1"]["frames_per_minute"],
                       "per_frame_to_local_1": runs["per_frame"]["seconds_per_frame"] / base}}


def _share(run: dict) -> float:
    """The label pass's share of a frame's two passes."""
    return run["labels_median_s"] / (run["render_median_s"] + run["labels_median_s"])


def sun_in_view(ctx: Context, config: Path, built: Path, frames: int) -> dict:
    """Render the first `frames` frames of `config` (its local-time window moved to the
    morning's low sun) with the sun inside the camera's frame, and verify their labels."""
    from ..datasets import config as dataset_config
    from ..datasets.plan import Planner
    from ..datasets.run import run_dataset
    from ..datasets.verify import verify_frame
    from ..runtime.site import load_site

    config.write_text(re.sub(r'(?m)^local_time = .*$', 'local_time = ["05:40", "07:30"]', config.read_text()))
    cfg = dataset_config.load(config)
    planner = Planner(cfg, load_site(built, ctx.sources), ctx.sources)
    t0 = time.perf_counter()
    picked = [i for i in range(cfg.count) if _sun_in_frame(planner.plan(i), cfg.sensor.width, cfg.sensor.height)]
    scan_s = time.perf_counter() - t0
    if not picked:
        return {"skipped": f"none of {cfg.count} planned frames has the sun in view"}
    out = ctx.work / "dataset" / "sun"
    out.mkdir(parents=True)
    for sub in ("models", "scene"):
        (out / sub).symlink_to(built / sub)
    folder = run_dataset(config, out, sources=ctx.sources, indices=picked[:frames])
    checked, problems, glare = 0, [], []
    for i in picked[:frames]:
        record = json.loads((folder / "records" / f"{i:06d}.json").read_text())
        n, found = verify_frame(folder, record)
        checked, problems = checked + n, problems + found
        glare.append({"frame": record["frame_id"], "clipped_px": record["glare"]["clipped_px"],
                      "hidden_pointers": sum(bool(g.get("glare_hides_pointer")) for g in record["gauges"])})
    return {"planned": cfg.count, "sun_in_view": len(picked), "scan_s": scan_s, "rendered": len(glare),
            "annotations": checked, "problems": problems, "frames": glare}


def _sun_in_frame(plan, width: int, height: int) -> bool:
    """The sun's disc centre projects inside the frame (above the horizon, occluded or not)."""
    from ..geometry.pinhole import intrinsics, project

    shot = plan.shot
    if shot.sun_elevation <= 0:
        return False
    k = intrinsics(shot.lens.hfov, width, height)
    u, v = project((shot.cam_pose[:3, 3] + 1.0e4 * shot.sun_dir)[None, :], shot.cam_pose, k)[0]
    return bool(0 <= u < width and 0 <= v < height)
