"""The viewer's tasks, after the scene (pipeline.viewer):

- `viewer:libs`: three.js and CesiumJS from tools/node_modules -> viewer/lib/. Keyed
  on the libraries' package.json (a version's files never change), so it runs when
  npm installs another version, not when the scene changes.
- `viewer`: the pages, twin.json and the sun table -> viewer/ (but lib/). Reads
  placements.json, the placed models' manifests, site.toml and the scenarios.
- `tiles`: the 3D Tiles tileset -> tiles/. Reads placements.json, the placed models'
  packages and the terrain's, and site.toml's [lod].

Like the scene, the page and the tiles stand on a failed asset's last package (the
scene was made from it), so they always show the scene that is there.
"""

from __future__ import annotations

import json
from pathlib import Path

from .graph import Task, code_version

VIEWER_CODE = ("pipeline.viewer.page", "pipeline.viewer.sun_table", "pipeline.viewer.tiles", "pipeline.viewer.packs",
               "pipeline.runtime.sun", "pipeline.runtime.graph", "pipeline.runtime.nodes", "pipeline.config",
               "pipeline.georef", "pipeline.scene.placements", "pipeline.builder.viewer_task")
TILES_CODE = ("pipeline.viewer.tiles", "pipeline.viewer.packs", "pipeline.glb", "pipeline.scene.scene_gltf",
              "pipeline.geometry.transform", "pipeline.scene.placements", "pipeline.export.names", "pipeline.georef",
              "pipeline.config", "pipeline.builder.viewer_task")
LIBS_CODE = ("pipeline.viewer.libs", "pipeline.builder.viewer_task")
SUN_CODE = ("pipeline.viewer.sun_table", "pipeline.runtime.sun")  # what the kept sun tables depend on


def _scene_inputs(build: Path) -> tuple[dict, dict]:
    """placements.json and the placed models' manifests of a built scene."""
    from ..export import manifest

    record = json.loads((build / "scene" / "placements.json").read_text())
    used = sorted({p["asset"] for p in record["placements"]})
    return record, {a: manifest.read(build / "models" / a) for a in used}


def build_viewer(staging: Path, sources: str, build: str, memo: str | None = None, memo_namespace: str = "") -> dict:
    """Task action: viewer/ but its libraries."""
    from ..viewer import page
    from .memo import FileMemo

    record, manifests = _scene_inputs(Path(build))
    sun_memo = None if memo is None else FileMemo(Path(memo), memo_namespace)
    return page.write(staging, sources=Path(sources), record=record, manifests=manifests, sun_memo=sun_memo)


def build_tiles(staging: Path, sources: str, build: str, memo: str | None = None, memo_namespace: str = "") -> dict:
    """Task action: tiles/. `memo`: the cache folder whose memos keep each model's
    packs (baked meshes) by its glb, under `memo_namespace` (the task's code)."""
    from .. import config
    from ..viewer import tiles
    from .memo import ArrayMemo, FileMemo

    site = config.load_site(Path(sources) / "site.toml")
    record, manifests = _scene_inputs(Path(build))
    lod = {"screen_tolerance_px": site.screen_tolerance_px, "reference_hfov_rad": site.reference_hfov_rad,
           "reference_width_px": site.reference_width_px}
    kept = None if memo is None else (FileMemo(Path(memo), memo_namespace), ArrayMemo(Path(memo), memo_namespace))
    return tiles.write(Path(staging) / "tiles", models=Path(build) / "models", record=record, manifests=manifests,
                       lod=lod, memo=kept)


def build_libs(staging: Path) -> dict:
    """Task action: viewer/lib/."""
    from ..viewer import libs

    return libs.copy(staging)


def viewer_tasks(site, sources: Path, build: Path, placed_assets: list[str], memo: str) -> list[Task]:
    """The three tasks of a scene whose site is `site` (config.Site)."""
    from ..viewer import libs, page

    sources, build = Path(sources).resolve(), Path(build).resolve()
    args = {"sources": str(sources), "build": str(build)}
    scenarios = tuple(sorted((sources / "scenarios").glob("*.toml")))
    assets = tuple(f"asset:{a}" for a in placed_assets)
    installed = libs.manifests()
    return [
        Task(name="viewer:libs", stage="scene", action=build_libs, args={},
             inputs=tuple(p for p in installed.values() if p is not None),
             params={"installed": sorted(n for n, p in installed.items() if p)}, code=code_version(*LIBS_CODE),
             outputs=(f"{libs.LIB}/",)),
        Task(name="viewer", stage="scene", action=build_viewer,
             args={**args, "memo": memo, "memo_namespace": code_version(*SUN_CODE)},
             inputs=(site.path.resolve(), *scenarios, *page.static_files()), deps=("scene", *assets),
             params={"site": site.name}, code=code_version(*VIEWER_CODE), previous_ok=assets,
             outputs=tuple(f"viewer/{n}" for n in page.PAGES) + ("viewer/app/", "viewer/data/")),
        Task(name="tiles", stage="scene", action=build_tiles,
             args={**args, "memo": memo, "memo_namespace": code_version(*TILES_CODE)}, inputs=(site.path.resolve(),),
             deps=("scene", "terrain", *assets), params={"site": site.name}, code=code_version(*TILES_CODE),
             outputs=("tiles/",), previous_ok=assets),
    ]
