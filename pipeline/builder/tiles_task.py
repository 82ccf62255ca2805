"""The tiles task's action: the 3D Tiles tileset of the built scene (viewer.tiles)."""

from __future__ import annotations

import json
from pathlib import Path

from .scene_record import scene_inputs


def build_tiles(staging: Path, sources: str, build: str, memo: str | None = None, memo_namespace: str = "") -> dict:
    """Task action: tiles/. `memo`: the cache folder whose memos keep each model's
    packs (baked meshes) by its glb, under `memo_namespace` (the task's code)."""
    from .. import config
    from ..viewer import tiles
    from ..engine.memo import ArrayMemo, FileMemo

    site = config.load_site(Path(sources) / "site.toml")
    record, manifests = scene_inputs(Path(build))
    lod = {"screen_tolerance_px": site.screen_tolerance_px, "reference_hfov_rad": site.reference_hfov_rad,
           "reference_width_px": site.reference_width_px}
    kept = None if memo is None else (FileMemo(Path(memo), memo_namespace), ArrayMemo(Path(memo), memo_namespace))
    wires = Path(build) / "scene" / "conductors.json"
    conductors = json.loads(wires.read_text()) if wires.is_file() else None
    return tiles.write(Path(staging) / "tiles", models=Path(build) / "models", record=record, manifests=manifests,
                       lod=lod, memo=kept, conductors=conductors)
