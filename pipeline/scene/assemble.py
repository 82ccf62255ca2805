"""Scene assembly: the terrain package and the world in SDF, USD and glTF.

Two tasks: `terrain` (a model package built from the platform outlines) and `scene`
(reads every used package's manifest, places each placement on the globe, picks its
LOD, writes the three scene files and placements.json).
"""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path

import numpy as np

from .. import config, glb
from ..errors import UserError
from ..findings import as_dicts
from .. import sun as sun_model
from ..fork_join import beside
from ..export import names
from . import placements as placing
from . import conductor_outputs, conductors, scene_gltf, stage_usd, world_sdf
from .checks import check_placements
from .terrain import terrain_asset

SUN_LOCAL_TIME = dt.time(13, 0)  # the built scene's sun: early afternoon on the site's date, site time


def _load(sources: Path, build: Path | None = None):
    from ..georef import Georeferencer, default_origin
    from ..ingest.floorplan import MEMO_NAME, read_floorplan_memo

    site = config.load_site(Path(sources) / "site.toml")
    # every asset folder, as the planner reads the plan: a placed asset whose build
    # failed is placed from its last package
    assets = config.asset_ids(Path(sources))
    memo = None if build is None else Path(build) / MEMO_NAME
    fp = read_floorplan_memo(site.root / site.floorplan, assets, set(site.level_names), memo,
                             site.floorplan_options)
    origin = site.origin or default_origin(site, fp.platforms)
    return site, fp, Georeferencer(site, origin)


def scene_sun(site: config.Site, origin_llh) -> dict:
    """Sun of the built scene (the runtime moves it): the ephemeris at a fixed local
    time on the site's date, in its [site] timezone, apparent (refracted) as an observer
    sees it; intensity scaled by the study's clear-sky irradiance."""
    local = config.local_time(dt.datetime.combine(dt.date.fromisoformat(site.date), SUN_LOCAL_TIME), site.zone)
    when = local.astimezone(dt.timezone.utc)
    el, az = sun_model.ephemeris(origin_llh[0], origin_llh[1], when, refraction=True)
    irradiance = sun_model.irradiance(math.radians(el))
    return {"elevation_deg": round(el, 9), "azimuth_deg": round(az, 9), "irradiance_w_m2": round(irradiance, 6),
            "intensity": round(irradiance / 1000.0, 6), "illuminance_lux": round(irradiance * 100.0, 3),
            "time_local": local.isoformat(), "time_utc": when.isoformat()}


def terrain_site(settings: dict) -> config.Site:
    """The site as the terrain sees it, from its task's parameters (builder.tasks.
    terrain_settings): what the terrain does not use takes neutral values, so that
    nothing outside its key can shape it."""
    origin = settings["origin"]
    return config.Site(
        path=Path("site.toml"), name=settings["name"], floorplan=settings["floorplan"], timezone="UTC",
        crs=settings["crs"], grid_origin=tuple(settings["grid_origin"]),
        grid_rotation_deg=settings["grid_rotation_deg"], grid_scale=settings["grid_scale"],
        origin=None if origin is None else tuple(origin),
        levels=tuple(config.Level(name, elevation) for name, elevation in settings["levels"]),
        slope_ratio=settings["slope_ratio"], natural_ground=settings["natural_ground"],
        skirt_width=settings["skirt_width"], screen_tolerance_px=0.0, reference_hfov_rad=0.0,
        reference_width_px=0, inspection_points=())


def build_terrain(staging: Path, settings: dict) -> dict:
    """Task action: the terrain package (all formats) into models/<site>_terrain/, from
    the platforms, levels, terrain and georeferencing settings alone (its key)."""
    from ..export import manifest
    from ..export.package import write_package
    from .. import ir
    from ..georef import Georeferencer, default_origin

    site = terrain_site(settings)
    platforms = [ir.Platform(level, np.asarray(outline, dtype=np.float64), handle)
                 for level, outline, handle in settings["platforms"]]
    georef = Georeferencer(site, site.origin or default_origin(site, platforms))
    name = config.terrain_model_name(site)
    asset = terrain_asset(site, platforms, georef, name)
    models = Path(staging) / "models"
    models.mkdir(parents=True, exist_ok=True)
    outputs, lod_models, _, _ = write_package(asset, models)
    data = manifest.content(asset, source={"file": site.floorplan, "sha256": ""}, outputs=outputs, lod_models=lod_models)
    manifest.write(data, models / name)
    return {"terrain": name, "triangles": asset.triangle_count(0)}


def build_scene(staging: Path, sources: str, build: str) -> dict:
    """Task action: the world in SDF, USD and glTF, and placements.json."""
    from ..export import manifest
    from .terrain import height_at

    from ..wiring import load_wiring

    site, fp, georef = _load(Path(sources), Path(build))
    wiring = load_wiring(site)
    models = Path(build) / "models"
    used = sorted({p.asset_id for p in fp.placements})
    manifests = {a: manifest.read(models / a) for a in used}
    placed = placing.place(site, list(fp.placements), georef)
    eyes = placing.inspection_points_enu(site, georef)
    placed = placing.choose_lods(placed, manifests, eyes, site)
    spans = conductors.build(site, wiring, placed, manifests, georef, eyes, fp.conductor_lines)
    origin = georef.origin_llh
    sun = scene_sun(site, origin)
    tname = config.terrain_model_name(site)

    _check_moving_parts(site, placed, manifests)
    lod_hist = {str(k): sum(p.lod == k for p in placed) for k in sorted({p.lod for p in placed})}
    out = Path(staging) / "scene"
    out.mkdir(parents=True, exist_ok=True)
    wires = conductor_outputs.sdf_model(spans, out, capsules=wiring.collision == "capsules")
    variants = conductor_outputs.sdf_variants(spans, wiring.sag_variants_c, out) if spans else []
    conductors.write_record(out / "conductors.json", spans, wiring, sdf_variants=variants)

    def sdf_and_usd():
        world = out / f"{site.name}.sdf"
        world_args = dict(site_name=site.name, origin_llh=origin, placed=placed, terrain_model=tname, sun=sun,
                          models=models, own_model=frozenset(a for a, m in manifests.items() if m.get("bindings")),
                          extra_models=() if wires is None else (wires,))
        if site.moving_parts == "auto":
            chosen, estimate = world_sdf.write_within_budget(world, **world_args)
        else:
            world_sdf.write(world, moves=lambda tag: config.moves_in_gazebo(site.moving_parts, tag), **world_args)
            chosen, estimate = site.moving_parts, None
        stage_usd.write(out / f"{site.name}.usda", site_name=site.name, models=models, origin_llh=origin,
                        crs=site.crs, placed=placed, terrain_model=tname, sun=sun,
                        articulated=frozenset(a for a, m in manifests.items() if m.get("joints")),
                        extra=lambda site_prim: conductor_outputs.add_usd(site_prim, spans))
        return chosen, estimate

    def gltf_checks_and_record():
        scene_gltf.write(out / f"{site.name}.glb", models=models, placed=placed, terrain_model=tname,
                         origin_llh=origin, crs=site.crs, site_name=site.name, sun=sun,
                         extra=lambda sb: conductor_outputs.add_gltf(sb, spans))
        terrain = _terrain_asset(models / tname)
        en = np.array([p.pose[:2, 3] for p in placed]) if placed else np.zeros((0, 2))
        findings = check_placements(site, fp, placed, manifests, height_at(terrain, en))
        findings += _clearance_findings(site, wiring, spans, lambda xy: height_at(terrain, xy))
        return _placements_record(site, fp, placed, origin, sun, tname, lod_hist, findings)

    # two halves of about equal cost (USD the largest part of one, glTF of the
    # other) side by side, when a core is spare
    (chosen, estimate), record = beside(sdf_and_usd, gltf_checks_and_record)
    # what the world was written with, for the live twin (which reads the build, not the sources)
    record["gazebo"] = {"moving_parts": chosen}
    if estimate is not None:
        record["gazebo"].update(chosen_by="auto", parse_estimate_mb=round(estimate))
        if chosen == "none":
            record["findings"].append(as_dicts([world_sdf.at_rest_finding(f"{site.name}.sdf", estimate)])[0])
    (out / "placements.json").write_text(_json_by_line(record))
    return {"placements": len(placed), "lod_histogram": lod_hist, "findings": len(record["findings"]),
            "conductors": len(spans)}


def _check_moving_parts(site, placed, manifests: dict) -> None:
    """Each tag pattern of [gazebo] moving_parts matches a placement with moving parts:
    one that matches none is a mistake (a typo, a bay renamed), not a choice."""
    if isinstance(site.moving_parts, str):
        return
    switches = sorted(p.placement.tag for p in placed
                      if any(j["type"] in names.MOVABLE_JOINTS for j in manifests[p.placement.asset_id].get("joints", [])))
    unmatched = [pattern for pattern in site.moving_parts
                 if not any(config.moves_in_gazebo((pattern,), tag) for tag in switches)]
    if unmatched:
        have = ", ".join(switches[:4]) + (", ..." if len(switches) > 4 else "") if switches else "none"
        raise UserError(site.path, "gazebo.moving_parts",
                        f"{', '.join(map(repr, unmatched))} matches no placement with moving parts "
                        f"({len(switches)} placements have them: {have})")


def _placements_record(site, fp, placed, origin, sun: dict, terrain: str, lod_hist: dict, findings: list) -> dict:
    """placements.json: every placement's ENU pose, LOD and distance, and the checks.
    An index for the runtime and for people: lengths to the micrometre, yaw to 1e-9
    rad, heading to 1e-7 degree, distances to the millimetre (the scene files hold the
    poses in full); a state only where the placement has one. (Its `gazebo`, what the
    world was written with, is added once the world is.)"""
    return {
        "site": site.name, "crs": site.crs, "timezone": site.timezone,
        "origin": {"latitude_deg": origin[0], "longitude_deg": origin[1], "height_m": origin[2]},
        "sun": sun, "terrain": terrain, "lod_histogram": lod_hist,
        "placements": [{
            "tag": p.placement.tag, "asset": p.placement.asset_id, "level": p.placement.level,
            **({"state": p.placement.state} if p.placement.state else {}),
            "plan": [round(v, 6) for v in (p.placement.x, p.placement.y, p.placement.z)],
            "dxf_handles": list(p.placement.dxf_handles),
            **({"scale": p.placement.scale} if p.placement.scale != 1.0 else {}),
            "heading_deg": round(p.placement.heading_deg, 7), "enu": [round(float(v), 6) for v in p.pose[:3, 3]],
            "yaw_rad": round(p.yaw, 9), "lod": p.lod,
            "distance_m": None if not np.isfinite(p.distance_m) else round(p.distance_m, 3),
        } for p in sorted(placed, key=lambda p: p.placement.tag)],
        "findings": findings,
        "ignored_entities": [list(x) for x in fp.ignored],
    }


def _json_by_line(record: dict) -> str:
    """record as JSON, one line per top-level key and per item of a top-level list:
    the file diffs by placement, and each line goes through json's C encoder (an
    indent makes json fall back to its pure-Python one, slow at thousands of
    placements)."""
    fields = []
    for key in sorted(record):
        value = record[key]
        if isinstance(value, list) and value:
            items = ",\n".join(f"  {json.dumps(v, sort_keys=True, separators=(',', ':'))}" for v in value)
            fields.append(f" {json.dumps(key)}: [\n{items}\n ]")
        else:
            fields.append(f" {json.dumps(key)}: {json.dumps(value, sort_keys=True)}")
    return "{\n" + ",\n".join(fields) + "\n}\n"


def _clearance_findings(site, wiring, spans, ground) -> list[dict]:
    """The conductors' clearance findings (scene.clearance) as dicts, when the
    sources hold a clearance table."""
    from ..findings import as_dicts
    from . import clearance

    table = site.root / site.raw.get("wiring", {}).get("clearances", "clearances.toml")
    if not spans or not table.is_file() or not table.resolve().is_relative_to(site.root.resolve()):
        return []
    found, _ = clearance.check(spans, clearance.load_table(table), ground)
    return as_dicts(found)


def _terrain_asset(folder: Path):
    """The terrain read back from the built terrain glTF, so the checks test what
    was written, not what was meant."""
    from .. import ir

    doc, binary = glb.read(folder / names.gltf_file(folder.name))
    visuals = []
    for ni, m in glb.visual_nodes(doc):
        prim = doc["meshes"][doc["nodes"][ni]["mesh"]]["primitives"][0]
        pos = glb.accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
        idx = glb.accessor(doc, binary, prim["indices"]).reshape(-1, 3)
        pos = (np.c_[pos, np.ones(len(pos))] @ (m.T @ glb.Z_TO_Y))[:, :3]  # Y-up -> ENU
        visuals.append(ir.Visual(str(ni), "x", (ir.Mesh(pos, idx),)))
    return ir.Asset(id="t", category="terrain", links=(ir.Link("t", visuals=visuals),))
