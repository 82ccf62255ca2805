"""The terrain and scene tasks' actions: the terrain package and the world in every
format (scene.assemble, imported where it runs: a plan needs no pyproj)."""

from __future__ import annotations

from pathlib import Path

# what build_scene imports (inside functions): an idle worker imports them ahead
WARM = ("pipeline.scene.assemble", "pipeline.scene.scene_gltf", "pipeline.scene.stage_usd",
        "pipeline.scene.world_sdf", "pipeline.scene.checks", "pipeline.scene.terrain", "pipeline.georef",
        "pipeline.ingest.floorplan", "pyproj", "astral", "pxr.Usd", "pxr.Sdf", "pxr.Gf")


def build_terrain(staging: Path, settings: dict) -> dict:
    """Task action: the terrain package, from what its key holds (tasks.terrain_settings)."""
    from ..scene.assemble import build_terrain as action

    return action(staging=staging, settings=settings)


def build_scene(staging: Path, sources: str, build: str) -> dict:
    """Task action: the world in every format."""
    from ..scene.assemble import build_scene as action

    return action(staging=staging, sources=sources, build=build)
