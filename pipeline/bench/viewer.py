"""The viewer section: the built sample as a browser gets it. The scene page
(three.js) and the globe page (CesiumJS, the 3D Tiles) each opened in Chromium with
WebGL through SwiftShader (pipeline.viewer.check): time from navigation to the
first frame with the scene drawn, the browser's memory (proportional set size of
its processes, and the JS heap), what the frame drew; the tileset's bytes against
the scene .glb's; and what writing the tiles and the page costs.

SwiftShader renders on the CPU, so the times are an upper bound for a machine with a
GPU and move with the machine's load (recorded beside them); there the pages draw
without multisampling and fog (viewer/static/renderer.js), as each run records."""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

from .context import Context


def _bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) if folder.is_dir() else 0


def sizes(built: Path) -> dict:
    """The tileset's parts and the scene .glb, in bytes."""
    scene = next((built / "scene").glob("*.glb"))
    tiles = built / "tiles"
    parts = {"tileset_json": (tiles / "tileset.json").stat().st_size, "contents": _bytes(tiles / "content"),
             "meshes": _bytes(tiles / "meshes"), "terrain": (tiles / "terrain.glb").stat().st_size}
    total = sum(parts.values())
    tileset = json.loads((tiles / "tileset.json").read_text())
    count, depth = _count(tileset["root"])
    return {"scene_glb": scene.stat().st_size, "tileset": parts, "tileset_total": total,
            "ratio_to_scene_glb": total / scene.stat().st_size, "tiles": count, "depth": depth,
            "viewer_libraries": _bytes(built / "viewer" / "lib"), "viewer_data": _bytes(built / "viewer" / "data")}


def _count(node: dict, depth: int = 0) -> tuple[int, int]:
    n, deepest = 1, depth
    for c in node.get("children", []):
        cn, cd = _count(c, depth + 1)
        n, deepest = n + cn, max(deepest, cd)
    return n, deepest


def _page(built: Path, page: str, repeats: int, size) -> dict:
    from ..viewer import check

    runs, webgl = [], None
    for _ in range(repeats):
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
        r = check.run(built, page, size=size)
        if not r.get("ready"):
            raise RuntimeError(f"{page} was not ready: {(r.get('stats') or {}).get('errors') or r.get('error')}")
        s, webgl = r["stats"], r.get("webgl")
        runs.append({"first_frame_s": s["first_frame_ms"] / 1000.0, "ready_s": r["ready_ms"] / 1000.0,
                     "pss_mb": r["memory"]["pss_bytes"] / 2**20, "js_heap_mb": r["memory"]["js_heap_used_bytes"] / 2**20,
                     "phases_ms": s.get("phases_ms"), "load_average": load,
                     **{k: s[k] for k in ("draw_calls", "triangles", "instances", "tiles_with_content", "commands",
                                          "antialias", "fog") if k in s}})
    return {"runs": runs, "first_frame_s": statistics.median(r["first_frame_s"] for r in runs),
            "pss_mb": statistics.median(r["pss_mb"] for r in runs), "size_px": list(size),
            "webgl": webgl}


def _writers(ctx: Context, built: Path) -> dict:
    """Seconds to write the tiles and the page of the built scene (no memo: the sun
    table is computed)."""
    from .. import config
    from ..builder.scene_record import scene_inputs
    from ..viewer import page, tiles

    record, manifests = scene_inputs(built)
    site = config.load_site(ctx.shared.get("built_sources", ctx.sources) / "site.toml")
    lod = {"screen_tolerance_px": site.screen_tolerance_px, "reference_hfov_rad": site.reference_hfov_rad,
           "reference_width_px": site.reference_width_px}
    t = time.perf_counter()
    tiles.write(ctx.work / "viewer-bench" / "tiles", models=built / "models", record=record, manifests=manifests, lod=lod)
    t_tiles = time.perf_counter() - t
    t = time.perf_counter()
    page.write(ctx.work / "viewer-bench", sources=ctx.shared.get("built_sources", ctx.sources), record=record,
               manifests=manifests)
    return {"tiles_s": t_tiles, "page_s": time.perf_counter() - t}


def viewer_section(ctx: Context) -> dict:
    from ..viewer import check

    built = ctx.sample_build()
    out = {"sizes": sizes(built), "writers": _writers(ctx, built)}
    lacking = check.missing()
    if lacking:
        out["browser"] = f"not measured: missing {', '.join(lacking)} ({check.HINT})"
        return out
    # SwiftShader draws every pixel on the CPU: the quick run (the test suite's) shows
    # the pages at a quarter of the pixels
    size = ctx.pick((640, 400), (1280, 800))
    out["page"] = _page(built, "index.html", ctx.pick(1, 3), size)
    out["globe"] = _page(built, "globe.html", 1, size)
    return out
