"""The build's tasks: per used asset a source, a geometry and a package task, the
terrain, the scene.

`plan()` reads the sources and returns the task graph. The actions run in worker
processes and write into the staging folder they are given (paths relative to
build/, builder.layout); each kind has its module, and the text of that module and
of every pipeline module it imports is that kind's code version (engine.code): an
edit of the planning here reruns no task. An asset's chain is three tasks:

- `source:<id>` (builder.source_task): read the source file and clean it ->
  .source/<id>/<id>.ir (irfile), with the findings on the file as authored. The
  only task that reads a .blend (so the only one whose worker needs Blender). Its
  parameters are the asset.toml keys the readers use: none of the metadata, LOD or
  collision keys below. The files the reader opens through the source (textures,
  a glTF's .bin, an OBJ's .mtl) key it too, as its last run reported them
  (graph.Task.reads_in: paths in the asset's folder).
- `geometry:<id>` (builder.geometry_task): the cleaned source -> collision, LOD
  chain -> .ir/<id>/<id>.ir. The slow part (the LOD search). Its parameters are the
  [lod] and [collision] keys.
- `asset:<id>` (builder.package_task): the .ir file and asset.toml's metadata ->
  the package in every format, the manifest and the findings.

So editing an asset's description, category, mass or triangle budget rewrites its
package and leaves its geometry alone; editing an LOD budget reruns the last two and
reads no source; editing the source reruns all three.

For each placed asset, `placed:<id>` (builder.placed_task) writes what the scene and
the tiles read of its package (.placed/<id>/view.json); they depend on that, not on
the package: a description edit rewrites the package and stops at the view (the
engine's early cutoff), so a large site's scene is not written again for it.

After the scene (builder.scene_task, which also makes the terrain), the viewer's:

- `viewer:libs` (builder.libs_task): three.js and CesiumJS from tools/node_modules
  -> viewer/lib/. Keyed on the libraries' package.json (a version's files never
  change), so it runs when npm installs another version, not when the scene changes.
- `viewer` (builder.viewer_task): the pages, twin.json and the sun table -> viewer/
  (but lib/). Reads placements.json, the placed models' manifests, site.toml and
  the scenarios.
- `tiles` (builder.tiles_task): the 3D Tiles tileset -> tiles/. Reads
  placements.json, the placed models' packages and the terrain's, and site.toml's
  [lod].

Like the scene, the page and the tiles stand on a failed asset's last package (the
scene was made from it), so they always show the scene that is there.

An asset whose asset.toml cannot be read is one task, `asset:<id>`, that fails with
that error without running (Task.problem): the other assets build, and the scene
stands on the asset's last package if the build folder holds one (Task.previous_ok).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .. import config, ir, site_frame
from ..ingest import size
from ..errors import UserError
from ..files import atomic_write
from ..engine.code import ROOT as CODE_ROOT, code_of
from .geometry_task import WARM as GEOMETRY_WARM, build_geometry
from ..engine.graph import Task
from .layout import IR_FOLDER, SOURCE_FOLDER
from .libs_task import build_libs
from .package_task import WARM as PACKAGE_WARM, build_asset
from .placed_task import VIEW_FOLDER, build_view
from .scene_task import WARM as SCENE_WARM, build_scene, build_terrain
from .source_task import build_source
from .tiles_task import build_tiles
from .viewer_task import build_viewer

# what the memo entries of steps inside tasks depend on: the per-mesh checks'
# findings (findings.mesh_findings) and the sun tables (viewer.sun_table)
CHECKS_MODULE = "pipeline.findings"
SUN_MODULE = "pipeline.viewer.sun_table"
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
    # the folders the tasks' inputs are named under in their keys (graph.input_name):
    # the sources, and the code's (the viewer's static files, the installed libraries)
    roots: dict[str, Path] = field(default_factory=dict)


def scenario_assets(sources: Path) -> set[str]:
    """Asset ids that scenarios name in their `assets` list (built even if unplaced)."""
    used: set[str] = set()
    for path in sorted((Path(sources) / "scenarios").glob("*.toml")):
        data = config.read_toml(path)
        used.update(str(a) for a in data.get("assets", []))
    return used


CHECKS_NAME = ".checked.json"  # in a build folder: config checks that passed (config.py)


def load_sources(sources: Path, memo: Path | None = None, checked: Path | None = None, scene: bool = True) -> Plan:
    """What the sources hold. `memo`: a file where the floor plan read last time is
    kept with its key, so that a no-op build does not parse the DXF again; `checked`:
    a file of the config checks that passed, so that it does not check them again;
    `scene`: whether the scene is built (its frame is checked: site_frame)."""
    from ..ingest.floorplan import read_floorplan_memo

    sources = Path(sources)
    before = _read_passed(checked)
    passed = config.PassedChecks(before)
    site = config.load_site(sources / "site.toml", passed)
    assets, problems = config.load_assets(sources, passed)
    known = config.asset_ids(sources)
    plan_path = site.root / site.floorplan
    fp = read_floorplan_memo(plan_path, known, set(site.level_names), memo, site.floorplan_options)
    if scene:  # the plan on the globe at [origin], the time zone at its longitude: before any task
        site_frame.check(site, fp, passed)
    if checked is not None and not problems and passed.met != before:
        _write_passed(checked, passed.met)
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
    """The keys this build met (an edited file's old key goes)."""
    import json

    atomic_write(path, json.dumps(sorted(passed)))


def plan(sources: Path, build: Path, only: list[str] | None = None, cache: Path | None = None) -> Plan:
    """The task graph for a sources folder. `only`: just these assets' packages;
    `cache`: the cache folder the build uses (default: in the build folder)."""
    from ..ingest.floorplan import MEMO_NAME, require_placements_and_platforms
    from ..engine.cache import cache_root

    p = load_sources(sources, memo=Path(build) / MEMO_NAME, checked=Path(build) / CHECKS_NAME, scene=not only)
    p.roots = {"sources": Path(sources).absolute(), "code": CODE_ROOT}
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
    source_code, geometry_code = code_of(build_source.__module__), code_of(build_geometry.__module__)
    package_code, checks_code = code_of(build_asset.__module__), code_of(CHECKS_MODULE)
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
            reads_in=cfg.folder.resolve(),  # textures, .bin, .mtl the reader opens through the source
            problem=size.refusal(source),  # refused by stat: the file is never read, not even hashed
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
    code = code_of(build_scene.__module__)
    site = p.site
    tname = config.terrain_model_name(site)
    sources, build = Path(sources).resolve(), Path(build).resolve()
    args = {"sources": str(sources), "build": str(build)}
    inputs = (site.path.resolve(), (site.root / site.floorplan).resolve())
    # the terrain is made from its parameters alone: moving an INSERT or editing an
    # inspection point leaves it up to date
    settings = terrain_settings(site, p.floorplan.platforms)
    terrain = Task(name="terrain", stage="terrain", action=build_terrain, args={"settings": settings},
                   params={"terrain": tname, "settings": settings}, code=code, outputs=(f"models/{tname}/",))
    placed_assets = sorted({pl.asset_id for pl in p.floorplan.placements})
    view_code = code_of(build_view.__module__)
    # what the scene reads of each package (builder.placed_task): an edit the view does
    # not see (a description) reruns neither the scene nor the tiles
    views = [Task(name=f"placed:{a}", stage="assets", action=build_view, args={"build": str(build), "asset": a},
                  deps=(f"asset:{a}",), params={"asset": a}, code=view_code, outputs=(f"{VIEW_FOLDER}/{a}/",),
                  previous_ok=(f"asset:{a}",)) for a in placed_assets]
    packages = tuple(v.name for v in views)
    # a placed asset that fails in this build is placed from its last package, so one
    # broken source does not hold back every other asset's changes; a failed terrain
    # (the ground every placement stands on) blocks the scene
    # the conductor types and clearance table are read by the scene alone
    wiring = site.raw.get("wiring", {})
    tables = [site.root / wiring.get("types", "conductors.toml"), site.root / wiring.get("clearances", "clearances.toml")]
    scene_inputs = inputs + tuple(t.resolve() for t in tables if t.is_file())
    scene = Task(name="scene", stage="scene", action=build_scene, args=args, inputs=scene_inputs,
                 deps=("terrain", *packages), params={"site": site.name}, code=code, outputs=("scene/",),
                 warm=SCENE_WARM, previous_ok=packages)
    return [*views, terrain, scene]


def terrain_settings(site: config.Site, platforms) -> dict:
    """What the terrain is made of, as plain data (its task's key and arguments): the
    platform outlines, the levels, the [terrain] settings, the georeferencing and the
    [origin] (without one, the platforms' centre is the origin), the site's name."""
    return {
        "name": site.name, "floorplan": site.floorplan, "crs": site.crs, "grid_origin": list(site.grid_origin),
        "grid_rotation_deg": site.grid_rotation_deg, "grid_scale": site.grid_scale,
        "origin": None if site.origin is None else list(site.origin),
        "levels": [[lv.name, lv.elevation] for lv in site.levels],
        "slope_ratio": site.slope_ratio, "natural_ground": site.natural_ground, "skirt_width": site.skirt_width,
        "platforms": [[pf.level, [[float(x), float(y)] for x, y in pf.outline], pf.handle] for pf in platforms],
    }


def viewer_tasks(site: config.Site, sources: Path, build: Path, placed_assets: list[str], memo: str) -> list[Task]:
    """The viewer's three tasks, after the scene."""
    from ..viewer import libs, page

    sources, build = Path(sources).resolve(), Path(build).resolve()
    args = {"sources": str(sources), "build": str(build)}
    scenarios = tuple(sorted((sources / "scenarios").glob("*.toml")))
    assets = tuple(f"asset:{a}" for a in placed_assets)
    views = tuple(f"placed:{a}" for a in placed_assets)  # the tiles read what the scene does of a package
    installed = libs.manifests()
    tiles_code = code_of(build_tiles.__module__)
    return [
        Task(name="viewer:libs", stage="scene", action=build_libs, args={},
             inputs=tuple(p for p in installed.values() if p is not None),
             params={"installed": sorted(n for n, p in installed.items() if p)}, code=code_of(build_libs.__module__),
             outputs=(f"{libs.LIB}/",)),
        Task(name="viewer", stage="scene", action=build_viewer,
             args={**args, "memo": memo, "memo_namespace": code_of(SUN_MODULE)},
             inputs=(site.path.resolve(), *scenarios, *page.static_files()), deps=("scene", *assets),
             params={"site": site.name}, code=code_of(build_viewer.__module__), previous_ok=assets,
             outputs=tuple(f"viewer/{n}" for n in page.PAGES) + ("viewer/app/", "viewer/data/")),
        Task(name="tiles", stage="scene", action=build_tiles,
             args={**args, "memo": memo, "memo_namespace": tiles_code}, inputs=(site.path.resolve(),),
             deps=("scene", "terrain", *views), params={"site": site.name}, code=tiles_code,
             outputs=("tiles/",), previous_ok=views),
    ]
