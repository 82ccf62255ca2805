"""The Gazebo section: the sample world as Gazebo Fortress's libraries read it
(tools/gzprobe), against the layout of one <include> per placement measured in the
same run, and what one placement of each package variant costs in either layout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from lxml import etree

from .. import ir
from ..export.names import fmt, lod_model_name
from ..scene import world_collisions, world_sdf
from ..scene.placements import Placed
from .context import Context

# Placements per measured world when costing one placement of a variant.
_COPIES = 24


def _world(path: Path, body: str) -> Path:
    path.write_text(f'<?xml version="1.0"?><sdf version="1.9"><world name="w">{body}</world></sdf>\n')
    return path


def _include(uri: str, name: str, pose) -> str:
    return (f"<include><uri>model://{uri}</uri><name>{name}</name>"
            f"<pose>{' '.join(fmt(v) for v in pose)}</pose><static>true</static></include>")


def _includes_world(path: Path, record: dict) -> Path:
    """The world as it was written before placements were grouped: one include each."""
    body = _include(record["terrain"], "terrain", (0,) * 6)
    for p in record["placements"]:
        x, y, z = p["enu"]
        body += _include(lod_model_name(p["asset"], p["lod"]), p["tag"], (x, y, z, 0, 0, p["yaw_rad"]))
    return _world(path, body)


def _at(xyz) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = xyz
    return pose


def _placement_costs(ctx: Context, models: Path, record: dict) -> list[dict]:
    """Per variant the scene uses: MB and seconds sdformat spends on one placement as an
    include (its own model) and as a frame of a grouped model, over _COPIES of each."""
    from ..validate import gazebo

    empty = gazebo.probe_world(_world(ctx.work / "empty.sdf", ""), [models], meshes=False)["world"]
    variants = sorted({lod_model_name(p["asset"], p["lod"]) for p in record["placements"]})
    rows = []
    for variant in variants[: ctx.pick(2, len(variants))]:
        poses = [(3.0 * k, 0.0, 0.0, 0.0, 0.0, 0.0) for k in range(_COPIES)]
        included = _world(ctx.work / "inc.sdf", "".join(_include(variant, f"p{k}", pose) for k, pose in enumerate(poses)))
        # the placements world_sdf groups: its tag, asset, scale, position and yaw
        asset = variant.split("__lod")[0]
        members = [Placed(ir.Placement(f"p{k}", asset, "L1", pose[0], pose[1]), _at(pose[:3]), 0.0)
                   for k, pose in enumerate(poses)]
        # as in the world: their collisions in the cells (amortized over a cell's many)
        model = world_sdf.grouped_model(variant, models / variant / "model.sdf", members,
                                        cells=world_collisions.CollisionCells(models))
        grouped = _world(ctx.work / "grp.sdf", etree.tostring(model, encoding="unicode"))
        row = {"variant": variant}
        for name, world in (("include", included), ("grouped", grouped)):
            seen = gazebo.probe_world(world, [models], meshes=False)["world"]
            row[f"{name}_mb"] = (seen["peak_rss_mb"] - empty["peak_rss_mb"]) / _COPIES
            row[f"{name}_ms"] = 1000 * (seen["parse_s"] - empty["parse_s"]) / _COPIES
        rows.append(row)
    return rows


def gazebo_section(ctx: Context) -> dict:
    from ..validate import gazebo

    built = ctx.sample_build()
    models = built / "models"
    world = next((built / "scene").glob("*.sdf"))
    record = json.loads((built / "scene" / "placements.json").read_text())
    seen = gazebo.probe_world(world, [models], meshes=False, physics_s=ctx.pick(0.5, 5.0))
    out = {"placements": len(record["placements"]),
           "world": {k: seen["world"][k] for k in ("parse_s", "peak_rss_mb", "models", "links", "visuals", "collisions")},
           "budget": {"peak_rss_mb": world_sdf.PARSE_BUDGET_MB, "parse_s": gazebo.WORLD_PARSE_BUDGET_S},
           "physics": seen.get("physics", {})}
    if not ctx.quick:  # gigabytes and most of a minute: the full run only
        before = gazebo.probe_world(_includes_world(ctx.work / "includes.sdf", record), [models], meshes=False)
        out["one_include_per_placement"] = {k: before["world"][k] for k in out["world"]}
    out["per_placement"] = _placement_costs(ctx, models, record)
    return out
