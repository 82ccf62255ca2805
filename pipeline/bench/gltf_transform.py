"""Peer (b): the glTF-Transform CLI on our files, same inputs, same run.

- simplify: per model, `gltf-transform weld` then `simplify --ratio r --error 1` (the
  CLI's documented recipe; error 1 = unconstrained, so the ratio decides) with r =
  our coarsest LOD's triangles / LOD0's: a matched-count comparison. Both results are
  measured with the same metric, two-sided Hausdorff against LOD0
  (pipeline.geometry.metrics). Its input is our model .glb after `prune` (drops the
  out-of-scene LOD nodes, which it would otherwise simplify too); prune is not timed.
- dedup and instance: on our scene .glb and on Blender's monolithic .glb (peer (a)),
  time and size in -> out.

The CLI's time includes starting Node (the way a build would call it); ours is the
LOD step of our asset task (every level, error-bounded search and measurement
included). The tool comes from tools/node_modules (`cd tools && npm ci`).
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

from . import glb
from .context import Context
from .stats import summarize

TOOLS = Path(__file__).resolve().parents[2] / "tools"
MEASURE_SAMPLES = 50_000


def cli() -> Path:
    exe = TOOLS / "node_modules" / ".bin" / "gltf-transform"
    if not exe.exists():
        raise FileNotFoundError(f"{exe} missing: run `cd tools && npm ci` (package.json pins @gltf-transform/cli)")
    return exe


def version() -> str:
    return json.loads((TOOLS / "node_modules" / "@gltf-transform" / "cli" / "package.json").read_text())["version"]


def run(*args: str, timeout: float = 600.0) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run([str(cli()), *args], capture_output=True, text=True, timeout=timeout)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"gltf-transform {args[0]} failed: {(proc.stderr or proc.stdout).strip()[-400:]}")
    return seconds


def _error(ref, other) -> float:
    from ..geometry.metrics import hausdorff

    return float(hausdorff(ref[0], ref[1], other[0], other[1], samples=MEASURE_SAMPLES))


def _our_lod_seconds(built: Path, asset: str) -> float | None:
    """Time of our LOD step in the asset's last build (the task result's timings)."""
    try:
        state = json.loads((built / ".state.json").read_text())
        timings = state["tasks"][f"geometry:{asset}"]["result"]["timings"]
    except (OSError, KeyError, json.JSONDecodeError):
        return None
    return float(timings["lod"]) if "lod" in timings else None


def simplify_models(ctx: Context, built: Path, work: Path) -> list[dict]:
    rows = []
    files = []
    for folder in sorted((built / "models").iterdir()):
        path = folder / f"{folder.name}.glb"
        if path.exists() and "__lod" not in folder.name and glb.lod_count(path) > 1:
            files.append((len(glb.triangles(path)[1]), folder.name, path))
    files.sort(reverse=True)
    repeats = ctx.pick(1, 2)
    for _, asset, path in files[: ctx.pick(2, 4)]:
        ref = glb.triangles(path, 0)
        k = glb.lod_count(path) - 1
        ours = glb.triangles(path, k)
        ratio = max(len(ours[1]) / max(len(ref[1]), 1), 1e-4)
        pruned, welded, simplified = work / f"{asset}.pruned.glb", work / f"{asset}.weld.glb", work / f"{asset}.simplified.glb"
        run("prune", str(path), str(pruned))
        times = []
        for _ in range(repeats):
            t = run("weld", str(pruned), str(welded))
            t += run("simplify", str(welded), str(simplified), "--ratio", f"{ratio:.6f}", "--error", "1")
            times.append(t)
        theirs = glb.triangles(simplified, 0)
        rows.append({
            "asset": asset, "lod0_triangles": int(len(ref[1])), "our_level": k,
            "ours": {"triangles": int(len(ours[1])), "error_m": _error(ref, ours),
                     "lod_step_seconds": _our_lod_seconds(built, asset), "file_bytes": path.stat().st_size,
                     "note": "file holds every LOD level"},
            "gltf_transform": {"triangles": int(len(theirs[1])), "error_m": _error(ref, theirs),
                               "time": summarize(times), "file_bytes": simplified.stat().st_size,
                               "ratio_arg": ratio},
        })
    return rows


def scene_ops(ctx: Context, inputs: dict[str, Path], work: Path) -> list[dict]:
    rows = []
    for label, path in inputs.items():
        for op in ("dedup", "instance"):
            dst = work / f"{label}.{op}.glb"
            times = [run(op, str(path), str(dst)) for _ in range(ctx.pick(1, 2))]
            rows.append({"input": label, "op": op, "time": summarize(times),
                         "bytes_in": path.stat().st_size, "bytes_out": dst.stat().st_size})
    return rows


def gltf_transform_section(ctx: Context) -> dict:
    built = ctx.sample_build()
    work = ctx.work / "gltf_transform"
    work.mkdir(parents=True, exist_ok=True)
    out: dict = {"version": version()}
    out["simplify"] = simplify_models(ctx, built, work)
    scenes = {f"ours:{p.name}": p for p in sorted((built / "scene").glob("*.glb"))}
    blender = ctx.shared.get("blender_glb")
    if blender and Path(blender).exists():
        scenes["blender_monolithic"] = Path(blender)
    try:
        out["scene"] = scene_ops(ctx, scenes, work)
    except Exception as e:  # keep the simplify figures if a scene op fails
        out["scene_error"] = f"{type(e).__name__}: {e}"
    return out
