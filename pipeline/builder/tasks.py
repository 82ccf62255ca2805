"""The build's tasks: per used asset a source, a geometry and a package task, the
terrain, the scene.

`plan()` reads the sources and returns the task graph. The actions run in worker
processes and write into the staging folder they are given (paths relative to
build/, builder.layout); each kind has its module, whose text is in that kind's
code version (an edit of the planning here reruns no task). An asset's chain is
three tasks:

- `source:<id>` (builder.source_task): read the source file and clean it ->
  .source/<id>/<id>.ir (irfile), with the findings on the file as authored. The
  only task that reads a .blend (so the only one whose worker needs Blender). Its
  parameters are the asset.toml keys the readers use: none of the metadata, LOD or
  collision keys below.
- `geometry:<id>` (builder.geometry_task): the cleaned source -> collision, LOD
  chain -> .ir/<id>/<id>.ir. The slow part (the LOD search). Its parameters are the
  [lod] and [collision] keys.
- `asset:<id>` (builder.package_task): the .ir file and asset.toml's metadata ->
  the package in every format, the manifest and the findings.

So editing an asset's description, category, mass or triangle budget rewrites its
package and leaves its geometry alone; editing an LOD budget reruns the last two and
reads no source; editing the source reruns all three.

An asset whose asset.toml cannot be read is one task, `asset:<id>`, that fails with
that error without running (Task.problem): the other assets build, and the scene
stands on the asset's last package if the build folder holds one (Task.previous_ok).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .. import config, ir
from ..errors import UserError
from .geometry_task import WARM as GEOMETRY_WARM, build_geometry
from .graph import Task, code_version
from .layout import IR_FOLDER, SOURCE_FOLDER
from .package_task import WARM as PACKAGE_WARM, build_asset
from .source_task import build_source
from .viewer_task import viewer_tasks

SOURCE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.ingest.blend", "pipeline.ingest.cad",
               "pipeline.ingest.mesh", "pipeline.ingest.units", "pipeline.ingest.gltf_file", "pipeline.glb",
               "pipeline.ingest.tessellate", "pipeline.geometry.clean", "pipeline.validate.checks", "pipeline.findings",
               "pipeline.geometry.edges", "pipeline.fork_join",
               "pipeline.builder.irfile", "pipeline.builder.layout", "pipeline.builder.source_task")
GEOMETRY_CODE = ("pipeline.ir", "pipeline.config", "pipeline.geometry", "pipeline.findings", "pipeline.fork_join",
                 "pipeline.builder.irfile", "pipeline.builder.layout", "pipeline.builder.geometry_task")
PACKAGE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.export", "pipeline.glb", "pipeline.digest",
                "pipeline.validate.checks", "pipeline.findings", "pipeline.geometry.edges", "pipeline.builder.irfile",
                "pipeline.builder.layout", "pipeline.builder.package_task")
# what the per-mesh checks' memo entries depend on (findings.mesh_findings)
CHECKS_CODE = ("pipeline.findings", "pipeline.geometry.edges", "pipeline.ir", "pipeline.digest")
SCENE_CODE = ("pipeline.ir", "pipeline.config", "pipeline.ingest.floorplan", "pipeline.georef",
              "pipeline.scene", "pipeline.export", "pipeline.glb", "pipeline.digest", "pipeline.geometry.transform",
              "pipeline.findings", "pipeline.geometry.edges")
# what build_scene imports (inside functions): an idle worker imports them ahead
SCENE_WARM = ("pipeline.scene.assemble", "pipeline.scene.scene_gltf", "pipeline.scene.stage_usd",
              "pipeline.scene.world_sdf", "pipeline.scene.checks", "pipeline.scene.terrain", "pipeline.georef",
              "pipeline.ingest.floorplan", "pyproj", "astral", "pxr.Usd", "pxr.Sdf", "pxr.Gf")
# asset.toml keys only the package task reads (the readers get neutral values for them)
METADATA_KEYS = ("description", "category", "mass_kg", "triangle_budget")
# asset.toml tables only the geometry task reads
GEOMETRY_KEYS = ("lod", "collision")


# --- the parameters of the asset chain's tasks ---------------------------------


def source_params(cfg: config.AssetConfig) -> dict:
    """The asset.toml keys the source readers use."""
    return {k: v for k, v in sorted(cfg.params.items()) if k not in METADATA_KEYS + GEOMETRY_KEYS}


def geometry_params(cfg: config.AssetConfig) -> dict:
    """The asset.toml settings the geometry steps use (defaults filled in)."""
    return {"collision_mode": cfg.collision_mode, "lod_budgets_m": list(cfg.lod_budgets_m)}


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
    if checked is not None and not problems and passed.met != before:
        _write_passed(checked, passed.met)
    known = config.asset_ids(sources)
    plan_path = site.root / site.floorplan
    fp = read_floorplan_memo(plan_path, known, set(site.level_names), memo, site.floorplan_options)
    placed = {p.asset_id for p in fp.placements}
    used = sorted(placed | (scenario_assets(sources) & known))
    unused = sorted(known - set(used))
    return Plan(site=site, floorplan=fp, assets=assets, used=used, unused=unused, problems=problems)


def asset_of(problem: UserError) -> str:
    """The asset a problem of config.load_assets belongs to: it names the asset.toml,
    or the asset's folder when the id itself is refused."""
    path = Path(problem.file)
    return path.parent.name if path.name == "asset.toml" else path.name


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
    from ..ingest.floorplan import MEMO_NAME, require_placements_and_platforms
    from .cache import cache_root

    p = load_sources(sources, memo=Path(build) / MEMO_NAME, checked=Path(build) / CHECKS_NAME)
    broken = {asset_of(e): e for e in p.problems}
    wanted = sorted(set(p.used) - set(broken))
    if only:
        for a in only:
            if a not in p.assets and a not in broken:
                raise UserError(Path(sources) / "assets", a, "no such asset")
        wanted = sorted(set(only) - set(broken))
        broken = {a: e for a, e in broken.items() if a in only}
    # every broken asset.toml is reported, used or not: the sources are wrong either way
    for asset_id, problem in sorted(broken.items()):
        p.tasks.append(Task(name=f"asset:{asset_id}", stage="assets", action=build_asset, args={},
                            outputs=(f"models/{asset_id}/", f"models/{asset_id}__lod*"), problem=problem))
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
            warm=GEOMETRY_WARM,
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
            warm=PACKAGE_WARM,
        ))
    if not only:
        require_placements_and_platforms(p.floorplan)
        p.tasks.extend(scene_tasks(p, Path(sources), Path(build)))
        placed = sorted({pl.asset_id for pl in p.floorplan.placements})
        p.tasks.extend(viewer_tasks(p.site, Path(sources), Path(build), placed, memo))
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
    packages = tuple(f"asset:{a}" for a in placed_assets)
    # a placed asset that fails in this build is placed from its last package, so one
    # broken source does not hold back every other asset's changes; a failed terrain
    # (the ground every placement stands on) blocks the scene
    scene = Task(name="scene", stage="scene", action=build_scene, args=args, inputs=inputs,
                 deps=("terrain", *packages), params={"site": site.name}, code=code, outputs=("scene/",),
                 warm=SCENE_WARM, previous_ok=packages)
    return [terrain, scene]
