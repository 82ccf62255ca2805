"""The source task's action: an asset's source file read and cleaned (builder.tasks)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .. import config
from ..fork_join import beside
from .layout import source_path


def _source_config(cfg: config.AssetConfig) -> config.AssetConfig:
    """cfg with neutral metadata and geometry settings, so the source task depends on
    its parameters alone (a mass of 1 kg: the package task scales the links' shares
    to asset.toml's mass)."""
    return dataclasses.replace(cfg, description="", category="", mass_kg=1.0, triangle_budget=0,
                               lod_budgets_m=(), collision_mode="")


def build_source(staging: Path, asset_toml: str) -> dict:
    """Task action: one asset's source file read and cleaned, written as an .ir file
    with the findings on the file as authored."""
    from ..findings import as_dicts
    from ..geometry.clean import CleanOptions, clean
    from ..ingest.readers import read_source
    from ..validate.checks import check_asset
    from . import irfile

    timings = {}
    t = time.perf_counter()
    cfg = _source_config(config.load_asset_config(Path(asset_toml)))
    source, opened = _without_opened(read_source(cfg))
    timings["read"] = time.perf_counter() - t

    def cleaned():
        t = time.perf_counter()
        asset = clean(CleanOptions())(source)
        timings["clean"] = time.perf_counter() - t
        return asset

    # the modeller's file as authored, checked beside the clean-up (the triangle
    # budget is the package task's)
    asset, source_findings = beside(cleaned, lambda: check_asset(source))
    out = Path(staging) / source_path(cfg.id)
    out.parent.mkdir(parents=True, exist_ok=True)
    irfile.write(out, asset, {"source_findings": as_dicts(source_findings),
                              "source_triangles": source.triangle_count(0)})
    warnings = [message for key, message in source.metadata if key.startswith("warning.")]
    return {"asset": cfg.id, "timings": timings, **({"warnings": warnings} if warnings else {}),
            **({"opened": opened} if opened else {})}


def _without_opened(asset):
    """(the asset without its reader's `opened` record, that record): the files the
    reader opened through the source (path in the asset's folder -> sha256), which
    key the task (graph.Task.reads_in) and are no part of what it makes."""
    import json

    kept = tuple((k, v) for k, v in asset.metadata if k != "opened")
    opened = next((json.loads(v) for k, v in asset.metadata if k == "opened"), {})
    return asset.with_(metadata=kept), opened
