"""The build's tasks: per used asset a source, a geometry and a package task, the
terrain, the scene.

`plan()` reads the sources and returns the task graph; the actions below run in
worker processes and write into the staging folder they are given (paths relative
to build/). An asset's chain is three tasks:

- `source:<id>`: read the source file and clean it -> .source/<id>/<id>.ir (irfile),
  with the findings on the file as authored. The only task that reads a .blend (so
  the only one whose worker needs Blender). Its parameters are the asset.toml keys
  the readers use: none of the metadata, LOD or collision keys below.
- `geometry:<id>`: the cleaned source -> collision, LOD chain -> .ir/<id>/<id>.ir.
  The slow part (the LOD search). Its parameters are the [lod] and [collision] keys.
- `asset:<id>`: the .ir file and asset.toml's metadata -> the package in every format,
  the manifest and the findings.

So editing an asset's description, category, mass or triangle budget rewrites its
package and leaves its geometry alone; editing an LOD budget reruns the last two and
reads no source; editing the source reruns all three.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

from .. import config, ir
from ..digest import sha256_file
from ..errors import UserError
from .graph import Task, code_version
from ..spare import beside

SOURCE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.ingest.blend", "pipeline.ingest.cad",
               "pipeline.ingest.mesh", "pipeline.geometry.clean", "pipeline.validate.checks", "pipeline.spare",
               "pipeline.builder.irfile", "pipeline.builder.tasks")
GEOMETRY_CODE = ("pipeline.ir", "pipeline.config", "pipeline.geometry", "pipeline.validate.checks", "pipeline.spare",
                 "pipeline.builder.irfile", "pipeline.builder.tasks")
PACKAGE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.export", "pipeline.digest", "pipeline.validate.checks",
                "pipeline.builder.irfile", "pipeline.builder.tasks")
# what the per-mesh checks' memo entries depend on (validate.checks.mesh_findings)
CHECKS_CODE = ("pipeline.validate.checks", "pipeline.ir", "pipeline.digest")
SCENE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.ingest.floorplan", "pipeline.georef",
              "pipeline.scene", "pipeline.export", "pipeline.digest", "pipeline.geometry.transform")
# asset.toml keys only the package task reads (the readers get neutral values for them)
METADATA_KEYS = ("description", "category", "mass_kg", "triangle_budget")
# asset.toml tables only the geometry task reads
GEOMETRY_KEYS = ("lod", "collision")
SOURCE_FOLDER = ".source"
IR_FOLDER = ".ir"


# --- the asset chain ----------------------------------------------------------


def read_source(cfg: config.AssetConfig) -> ir.Asset:
    """The reader for the source's kind (DESIGN.md s.2), returning ir.Asset."""
    suffix = cfg.source.suffix.lower()
    if suffix == ".blend":
        from ..ingest.blend import read_blend
        return read_blend(cfg)
    if suffix in (".step", ".stp"):
        from ..ingest.cad import read_cad
        return read_cad(cfg)
    from ..ingest.mesh import read_mesh
    return read_mesh(cfg)


def asset_steps(cfg: config.AssetConfig, memo=None, checked=None) -> list[tuple[str, object]]:
    """The geometry pipeline of one cleaned asset: named Asset -> Asset steps, in order.
    `memo`: where the LOD search keeps its levels between builds (geometry.lod.LevelMemo);
    `checked`: where the per-mesh checks keep their findings (validate.checks.mesh_findings)."""
    from ..geometry.collision import CollisionOptions, collision_step
    from ..geometry.lod import LodOptions, lod_chain

    return [
        ("collision", collision_step(CollisionOptions(mode=cfg.collision_mode))),
        ("lod", lod_chain(LodOptions(budgets_m=cfg.lod_budgets_m), memo, checked)),
    ]


def source_path(asset_id: str) -> str:
    """Where an asset's source task leaves the cleaned source, relative to build/."""
    return f"{SOURCE_FOLDER}/{asset_id}/{asset_id}.ir"


def ir_path(asset_id: str) -> str:
    """Where an asset's geometry task leaves its result, relative to build/."""
    return f"{IR_FOLDER}/{asset_id}/{asset_id}.ir"


def source_params(cfg: config.AssetConfig) -> dict:
    """The asset.toml keys the source readers use."""
    return {k: v for k, v in sorted(cfg.params.items()) if k not in METADATA_KEYS + GEOMETRY_KEYS}


def geometry_params(cfg: config.AssetConfig) -> dict:
    """The asset.toml settings the geometry steps use (defaults filled in)."""
    return {"collision_mode": cfg.collision_mode, "lod_budgets_m": list(cfg.lod_budgets_m)}


def _source_config(cfg: config.AssetConfig) -> config.AssetConfig:
    """cfg with neutral metadata and geometry settings, so the source task depends on
    its parameters alone (a mass of 1 kg: the package task scales the links' shares
    to asset.toml's mass)."""
    return dataclasses.replace(cfg, description="", category="", mass_kg=1.0, triangle_budget=0,
                               lod_budgets_m=(), collision_mode="")


def build_source(staging: Path, asset_toml: str) -> dict:
    """Task action: one asset's source file read and cleaned, written as an .ir file
    with the findings on the file as authored."""
    from ..geometry.clean import CleanOptions, clean
    from ..validate.checks import as_dicts, check_asset
    from . import irfile

    timings = {}
    t = time.perf_counter()
    cfg = _source_config(config.load_asset_config(Path(asset_toml)))
    source = read_source(cfg)
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
    return {"asset": cfg.id, "timings": timings}


def build_geometry(staging: Path, asset_toml: str, build: str, memo: str | None = None,
                   memo_namespace: str = "", checks_namespace: str = "") -> dict:
    """Task action: one asset's cleaned source through the geometry steps, written as
    an .ir file (the source task's findings carried along). `memo`: the cache folder
    whose memo keeps the LOD search's levels (builder.memo), under `memo_namespace`
    (the task's code version), and the per-mesh checks' findings, under
    `checks_namespace` (theirs)."""
    from . import irfile
    from .memo import ArrayMemo

    cfg = config.load_asset_config(Path(asset_toml))
    asset, extra = irfile.read(Path(build) / source_path(cfg.id))
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


def with_metadata(asset: ir.Asset, cfg: config.AssetConfig) -> ir.Asset:
    """asset.toml's description, category and mass on an asset the geometry task made:
    the links keep their shares of the mass."""
    total = sum(link.mass for link in asset.links)
    links = asset.links
    if total > 0:
        links = tuple(dataclasses.replace(link, mass=cfg.mass_kg * link.mass / total) for link in links)
    return asset.with_(description=cfg.description, category=cfg.category, links=links)


def build_asset(staging: Path, asset_toml: str, build: str, memo: str | None = None,
                memo_namespace: str = "", checks_namespace: str = "") -> dict:
    """Task action: one asset's package from its geometry task's result. `memo`: the
    cache folder whose memo holds the COLLADA documents of earlier builds, under
    `memo_namespace` (the task's code version), and the per-mesh checks' findings
    (most made by the geometry task's checks of the same meshes), under
    `checks_namespace`."""
    from ..export import manifest
    from ..export.package import write_package
    from ..validate.checks import Finding, as_dicts, budget_findings, check_asset
    from . import irfile
    from .memo import ArrayMemo, FileMemo

    t = time.perf_counter()
    cfg = config.load_asset_config(Path(asset_toml))
    documents = None if memo is None else FileMemo(Path(memo), memo_namespace)
    checked = None if memo is None else ArrayMemo(Path(memo), checks_namespace)
    asset, extra = irfile.read(Path(build) / ir_path(cfg.id))
    asset = with_metadata(asset, cfg)
    source_findings = [Finding.from_dict(d) for d in extra["source_findings"]]
    source_findings += budget_findings(asset.id, extra["source_triangles"], cfg.triangle_budget)
    models = Path(staging) / "models"
    models.mkdir(parents=True, exist_ok=True)
    outputs, lod_models, built_findings, reused = write_package(
        asset, models, alongside=lambda: check_asset(asset, cfg.triangle_budget, checked), memo=documents)
    source = {"file": cfg.source.name, "sha256": sha256_file(cfg.source), "config_sha256": sha256_file(cfg.path)}
    data = manifest.content(asset, source=source, outputs=outputs, lod_models=lod_models)
    data["findings"] = {"source": as_dicts(source_findings), "built": as_dicts(built_findings)}
    manifest.write(data, models / asset.id)
    return {"asset": asset.id, "triangles": [lod["triangles"] for lod in data["lods"]],
            "errors_m": [lod["error_m"] for lod in data["lods"]], "timings": {"write": time.perf_counter() - t},
            **({"collada_documents": reused} if reused else {})}


def build_terrain(staging: Path, sources: str, build: str) -> dict:
    """Task action: the terrain package (scene.assemble, imported where it runs: a
    plan needs no pyproj)."""
    from ..scene.assemble import build_terrain as action

    return action(staging=staging, sources=sources, build=build)


def build_scene(staging: Path, sources: str, build: str) -> dict:
    """Task action: the world in every format (scene.assemble)."""
    from ..scene.assemble import build_scene as action

    return action(staging=staging, sources=sources, build=build)


# --- planning -----------------------------------------------------------------


@dataclass
class Plan:
    site: config.Site
    floorplan: ir.FloorPlan
    assets: dict[str, config.AssetConfig]
    used: list[str]
    unused: list[str]
    problems: list[UserError] = field(default_factory=list)
    tasks: list[Task] = field(default_factory=list)


def scenario_assets(sources: Path) -> set[str]:
    """Asset ids that scenarios name in their `assets` list (built even if unplaced)."""
    used: set[str] = set()
    for path in sorted((Path(sources) / "scenarios").glob("*.toml")):
        data = config.read_toml(path)
        used.update(str(a) for a in data.get("assets", []))
    return used


CHECKS_NAME = ".checked.json"  # in a build folder: config checks that passed (config.py)


def load_sources(sources: Path, memo: Path | None = None, checked: Path | None = None) -> Plan:
    """What the sources hold. `memo`: a file where the floor plan read last time is
    kept with its key, so that a no-op build does not parse the DXF again; `checked`:
    a file of the config checks that passed, so that it does not check them again."""
    from ..ingest.floorplan import read_floorplan_memo

    sources = Path(sources)
    before = _read_passed(checked)
    passed = config.PassedChecks(before)
    site = config.load_site(sources / "site.toml", passed)
    assets, problems = config.load_assets(sources, passed)
    if problems:
        raise problems[0]
    if checked is not None and passed.met != before:
        _write_passed(checked, passed.met)
    plan_path = site.root / site.floorplan
    fp = read_floorplan_memo(plan_path, set(assets), set(site.level_names), memo)
    placed = {p.asset_id for p in fp.placements}
    used = sorted(placed | (scenario_assets(sources) & set(assets)))
    unused = sorted(set(assets) - set(used))
    return Plan(site=site, floorplan=fp, assets=assets, used=used, unused=unused)


def _read_passed(path: Path | None) -> set[str]:
    import json

    if path is None:
        return set()
    try:
        keys = json.loads(path.read_text())
    except (OSError, ValueError):
        return set()
    return {k for k in keys if isinstance(k, str)} if isinstance(keys, list) else set()


def _write_passed(path: Path, passed: set[str]) -> None:
    """The keys this build met, atomically (an edited file's old key goes)."""
    import json
    import os
    import uuid

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    tmp.write_text(json.dumps(sorted(passed)))
    os.replace(tmp, path)


def plan(sources: Path, build: Path, only: list[str] | None = None, cache: Path | None = None) -> Plan:
    """The task graph for a sources folder. `only`: just these assets' packages;
    `cache`: the cache folder the build uses (default: in the build folder)."""
    from ..ingest.floorplan import MEMO_NAME
    from .cache import cache_root

    p = load_sources(sources, memo=Path(build) / MEMO_NAME, checked=Path(build) / CHECKS_NAME)
    wanted = p.used
    if only:
        for a in only:
            if a not in p.assets:
                raise UserError(Path(sources) / "assets", a, "no such asset")
        wanted = sorted(only)
    source_code = code_version(*SOURCE_CODE)
    geometry_code, package_code = code_version(*GEOMETRY_CODE), code_version(*PACKAGE_CODE)
    checks_code = code_version(*CHECKS_CODE)
    memo = str(cache_root(build, cache).resolve())
    for asset_id in wanted:
        cfg = p.assets[asset_id]
        source, toml = cfg.source.resolve(), cfg.path.resolve()
        # the LOD search dominates a chain and grows with the mesh: the modeller's
        # budget is the one size known before reading the source
        cost = float(cfg.triangle_budget)
        p.tasks.append(Task(
            name=f"source:{asset_id}",
            stage="sources",
            action=build_source,
            args={"asset_toml": str(toml)},
            inputs=(source,),
            params={"asset": asset_id, "asset.toml": source_params(cfg)},
            code=source_code,
            outputs=(f"{SOURCE_FOLDER}/{asset_id}/",),
            needs_blender=source.suffix.lower() == ".blend",
            cost=cost,  # its chain's: the longest chains start first
        ))
        p.tasks.append(Task(
            name=f"geometry:{asset_id}",
            stage="geometry",
            action=build_geometry,
            args={"asset_toml": str(toml), "build": str(Path(build).resolve()),
                  "memo": memo, "memo_namespace": geometry_code, "checks_namespace": checks_code},
            deps=(f"source:{asset_id}",),
            params={"asset": asset_id, "asset.toml": geometry_params(cfg)},
            code=geometry_code,
            outputs=(f"{IR_FOLDER}/{asset_id}/",),
            cost=cost,
        ))
        p.tasks.append(Task(
            name=f"asset:{asset_id}",
            stage="assets",
            action=build_asset,
            args={"asset_toml": str(toml), "build": str(Path(build).resolve()), "memo": memo,
                  "memo_namespace": package_code, "checks_namespace": checks_code},
            inputs=(toml, source),
            deps=(f"geometry:{asset_id}",),
            params={"asset": asset_id},
            code=package_code,
            outputs=(f"models/{asset_id}/", f"models/{asset_id}__lod*"),
        ))
    if not only:
        p.tasks.extend(scene_tasks(p, Path(sources), Path(build)))
    return p


def scene_tasks(p: Plan, sources: Path, build: Path) -> list[Task]:
    """The terrain task (the platform outlines -> its package) and the scene task
    (every placed asset's package and the terrain -> the world in three formats)."""
    code = code_version(*SCENE_CODE)
    site = p.site
    tname = config.terrain_model_name(site)
    sources, build = Path(sources).resolve(), Path(build).resolve()
    args = {"sources": str(sources), "build": str(build)}
    inputs = (site.path.resolve(), (site.root / site.floorplan).resolve())
    terrain = Task(name="terrain", stage="terrain", action=build_terrain, args=args, inputs=inputs,
                   params={"terrain": tname}, code=code, outputs=(f"models/{tname}/",))
    placed_assets = sorted({pl.asset_id for pl in p.floorplan.placements})
    scene = Task(name="scene", stage="scene", action=build_scene, args=args, inputs=inputs,
                 deps=("terrain", *(f"asset:{a}" for a in placed_assets)),
                 params={"site": site.name}, code=code, outputs=("scene/",))
    return [terrain, scene]
