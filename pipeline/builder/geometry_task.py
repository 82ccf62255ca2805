"""The geometry task's action: collision and LOD chain of an asset's cleaned source
(builder.tasks)."""

from __future__ import annotations

import time
from pathlib import Path

from .. import config
from .layout import ir_path, source_path

# What build_geometry imports (most of it inside functions) and jsonschema for
# asset.toml's check: a worker idle while the task waits imports them ahead, so the
# task does not wait for its imports.
WARM = ("pipeline.builder.irfile", "pipeline.engine.memo", "pipeline.geometry.collision", "pipeline.geometry.lod",
        "pipeline.findings", "pipeline.fork_join", "scipy.spatial", "fcpw", "igl", "meshoptimizer", "jsonschema")


def asset_steps(cfg: config.AssetConfig, memo=None, checked=None) -> list[tuple[str, object]]:
    """The geometry pipeline of one cleaned asset: named Asset -> Asset steps, in order.
    `memo`: where the LOD search keeps its levels between builds (geometry.simplify.Memo);
    `checked`: where the per-mesh checks keep their findings (findings.mesh_findings).
    The LOD step gets the validator's per-visual verdict and this worker's share of the
    cores (fork_join) from here: geometry imports neither."""
    from functools import partial

    from ..geometry.collision import CollisionOptions, collision_step
    from ..geometry.lod import LodOptions, lod_chain
    from ..geometry.simplify import Parallelism
    from ..findings import visual_verdict
    from ..fork_join import core_share, spread

    workers = Parallelism(cores=core_share(), spread=spread)
    return [
        ("collision", collision_step(CollisionOptions(mode=cfg.collision_mode))),
        ("lod", lod_chain(LodOptions(budgets_m=cfg.lod_budgets_m), memo, partial(visual_verdict, memo=checked),
                          workers)),
    ]


def build_geometry(staging: Path, asset_toml: str, build: str, memo: str | None = None,
                   memo_namespace: str = "", checks_namespace: str = "") -> dict:
    """Task action: one asset's cleaned source through the geometry steps, written as
    an .ir file (the source task's findings carried along). `memo`: the cache folder
    whose memo keeps the LOD search's levels (engine.memo), under `memo_namespace`
    (the task's code version), and the per-mesh checks' findings, under
    `checks_namespace` (theirs)."""
    from . import irfile
    from ..engine.memo import ArrayMemo

    cfg = config.load_asset_config(Path(asset_toml))
    asset, extra = irfile.read(Path(build) / source_path(cfg.id), cfg.source)
    timings = {}
    levels = None if memo is None else ArrayMemo(Path(memo), memo_namespace)
    checked = None if memo is None else ArrayMemo(Path(memo), checks_namespace)
    for name, step in asset_steps(cfg, levels, checked):
        t = time.perf_counter()
        asset = step(asset)
        timings[name] = time.perf_counter() - t
    out = Path(staging) / ir_path(cfg.id)
    out.parent.mkdir(parents=True, exist_ok=True)
    irfile.write(out, asset, extra)
    reused = {} if levels is None else {"lod_levels": {"recalled": levels.hits, "searched": levels.puts}}
    return {"asset": cfg.id, "timings": timings, **reused}
