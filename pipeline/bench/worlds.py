"""A built Gazebo world as the bench measures it: probed as gz-sim's server loads it
(tools/gzprobe: sdformat's parse time, CPU time and peak memory, dartsim's real-time
factor), and the site.toml edit that writes it with or without the switches' moving
parts ([gazebo] moving_parts), so that both are measured side by side in one run."""

from __future__ import annotations

import os
import re
import tomllib
from pathlib import Path

from .context import Context

# what a site.toml edit of [gazebo] may rerun: the scene and what reads it (the assets,
# their views and the terrain stay)
SCENE_SIDE = frozenset({"scene", "viewer", "tiles"})


def probe(ctx: Context, built: Path) -> dict:
    """The world of `built` as the probe reads it (meshes not loaded), with the load
    average when it started (the machine is shared): parse figures, dartsim's, and the
    counts of models, links, joints (as dartsim built them), visuals and collisions."""
    from ..validate import gazebo

    load = os.getloadavg()
    world = next((built / "scene").glob("*.sdf"))
    seen = gazebo.probe_world(world, [built / "models"], meshes=False, physics_s=ctx.pick(0.2, 1.0))
    elements = {k: seen["world"][k] for k in ("models", "links", "visuals", "collisions")}
    physics = seen.get("physics", {})
    if "joints" in physics:
        elements["joints"] = physics["joints"]
    return {"load_avg": [round(v, 2) for v in load], "physics": physics, "elements": elements,
            "world": {k: seen["world"][k] for k in ("parse_s", "parse_cpu_s", "peak_rss_mb") if k in seen["world"]}}


def set_moving_parts(site_toml: Path, value: str) -> None:
    """site.toml's [gazebo] moving_parts set to `value` ("all" or "none"), the rest of
    the file as it was."""
    text = site_toml.read_text()
    gazebo = tomllib.loads(text).get("gazebo")
    line = f'moving_parts = "{value}"'
    if gazebo is None:
        text = text.rstrip("\n") + f"\n\n[gazebo]\n{line}\n"
    elif "moving_parts" in gazebo:
        text = re.sub(r"^moving_parts\s*=.*$", line, text, count=1, flags=re.M)
    else:
        text = re.sub(r"^\[gazebo\][ \t]*$", f"[gazebo]\n{line}", text, count=1, flags=re.M)
    site_toml.write_text(text)
    if tomllib.loads(text).get("gazebo", {}).get("moving_parts") != value:  # a layout the edit missed
        raise ValueError(f"{site_toml}: could not set [gazebo] moving_parts = {value!r}")
