"""Peer (a): Blender's own exporters writing the whole scene as one file, against our
modular scene; and Blender's re-export per state step (the study's runtime).

Every Blender run is a fresh subprocess (pipeline.bench.blender_script): bpy's
state, memory and import cost stay out of the bench process, and each load starts
from an empty Blender like a user opening the file.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .context import Context
from .stats import summarize, summarize_values


def run_script(*args: str, timeout: float = 1200.0) -> dict:
    cmd = [sys.executable, "-m", "pipeline.bench.blender_script", *args]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"timeout_s": timeout}
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith("BENCH_JSON "):
            return json.loads(line[len("BENCH_JSON "):])
    raise RuntimeError(f"blender_script {args[0]} exited {proc.returncode}: {(proc.stderr or proc.stdout)[-500:]}")


def _loads(files: dict[str, Path], repeats: int) -> dict:
    """Fresh-process load of each file, repeats interleaved so drift hits all alike."""
    runs: dict[str, list[dict]] = {k: [] for k in files}
    for _ in range(repeats):
        for label, path in files.items():
            runs[label].append(run_script("load", str(path)))
    out = {}
    for label, rs in runs.items():
        out[label] = {"file": str(files[label]), "time": summarize([r["seconds"] for r in rs]),
                      "maxrss": summarize_values([r["maxrss_bytes"] for r in rs], "bytes"),
                      "objects": rs[-1]["objects"], "meshes": rs[-1]["meshes"]}
        if files[label] != Path("none"):
            out[label]["bytes"] = _size(files[label])
    return out


def _size(path: Path) -> int:
    """A file's size; for a USD stage, the stage plus every layer it references."""
    path = Path(path)
    if path.suffix not in (".usda", ".usd", ".usdc"):
        return path.stat().st_size
    try:
        from pxr import Sdf, UsdUtils

        layers, assets, _ = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
        return sum(Path(layer.realPath).stat().st_size for layer in layers if layer.realPath)
    except Exception:  # usd-core missing or an odd layer: the stage file alone
        return path.stat().st_size


def blender_section(ctx: Context) -> dict:
    built = ctx.sample_build()
    work = ctx.work / "blender"
    repeats = 1  # a whole-scene export is minutes in Blender
    a = run_script("assemble", str(built), str(work), str(repeats), timeout=ctx.pick(300.0, 600.0))
    if "timeout_s" in a:
        raise RuntimeError(f"Blender's glTF export of the whole scene did not finish in {a['timeout_s']:.0f} s")
    # Blender's USD export of the sample runs for minutes and takes gigabytes: capped
    # (the cap includes opening the assembled .blend), and a timeout is recorded as the
    # figure it is; a higher cap only spends the bench's budget on a known answer
    u = run_script("usd", a["blend"], str(work), timeout=ctx.pick(120.0, 150.0))
    ctx.shared["blender_glb"] = a["file"]
    ours = {p.suffix: p for p in sorted((built / "scene").iterdir()) if p.suffix in (".glb", ".usda")}
    files = {"empty (bpy baseline)": Path("none"), "blender_monolithic.glb": Path(a["file"])}
    if "timeout_s" not in u:
        files["blender_monolithic.usdc"] = Path(u["file"])
    for suffix, p in ours.items():
        files[f"ours:{p.name}"] = p
    data = {
        "blender": a["blender"], "placements": a["placements"], "objects": a["objects"], "meshes": a["meshes"],
        "assemble_s": a["assemble_s"], "export_gltf": summarize(a["export_s"]), "blender_glb_bytes": a["bytes"],
        "export_gltf_maxrss_bytes": a["maxrss_bytes"],
        "ours_bytes": {p.name: _size(p) for p in ours.values()},
        # one fresh-process load per file: the differences between the files are far
        # above the machine's noise, and more rounds of the monolithic files cost minutes
        "loads": _loads(files, 1),
    }
    if "timeout_s" in u:
        data["export_usd_timeout_s"] = u["timeout_s"]
    else:
        data.update(export_usd=summarize(u["export_s"]), blender_usd_bytes=u["bytes"],
                    export_usd_maxrss_bytes=u["maxrss_bytes"], open_blend_s=u["open_s"])
    scene = ctx.shared.get("scene_build")
    if scene:
        data["ours_scene_build"] = scene
    return data


def reexport_section(ctx: Context, asset: str | None = None) -> dict:
    """The study's per-step Blender re-export of one model (the reactor when present)."""
    built = ctx.sample_build()
    if asset is None:
        models = sorted(p.name for p in (built / "models").iterdir() if (p / f"{p.name}.glb").exists())
        asset = "shunt_reactor" if "shunt_reactor" in models else models[0]
    r = run_script("reexport", str(built), asset, str(ctx.work / "reexport"), str(ctx.pick(3, 10)))
    return {"asset": asset, "objects": r["objects"], "bytes": r["bytes"], "step": summarize(r["step_s"]),
            "what": "rotate the pointer, recolour its material, export_scene.gltf of the model (GLB); "
                    "Blender 5 has no COLLADA exporter, which the study used"}
