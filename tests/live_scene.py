"""A tiny built scene for the live twin's tests: two placements of the hand-made reactor
of test_runtime_apply (a pointer that turns with oil_level_tank, a column that grows
with oil_level_b1, a lamp whose material follows the level), placements.json as the
scene assembly writes it (origin, time zone, ENU poses), and a dataset config whose PTZ
preset looks from one at the other: what `twin dataset` and `twin serve` both read."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.export import gltf, manifest

from test_runtime_apply import ASSET, tiny_asset

ORIGIN = {"latitude_deg": -12.6991063, "longitude_deg": -38.2994788, "height_m": 48.0}
TIMEZONE = "America/Bahia"

DATASET = """
[dataset]
name = "live"
seed = 5
count = 1
[sensor]
width = 48
height = 36
samples = 1
render_denoise = ""
[conditions]
dates = ["2025-03-20"]
local_time = ["09:00", "15:00"]
tau_atm = [0.1, 0.4]
[states]
oil_level = [20.0, 100.0]
switch_open = 0.5
[[cameras]]
kind = "ptz"
mast = "R-2"
presets = [{ target = "R-1", zoom = 2.0 }]
"""


def make(root: Path) -> tuple[Path, Path, Path]:
    """(build, sources, dataset config) under root."""
    build, sources = root / "build", root / "sources"
    pkg = build / "models" / ASSET
    asset = tiny_asset()
    outputs = gltf.write(asset, pkg)
    manifest.write(manifest.content(asset, source={"sha256": "0"}, outputs={o: "0" for o in outputs},
                                    lod_models=[]), pkg)
    (build / "scene").mkdir(parents=True)
    (build / "scene" / "placements.json").write_text(json.dumps({
        "origin": ORIGIN, "timezone": TIMEZONE, "placements": [
            {"tag": "R-1", "asset": ASSET, "state": "reactor_A1", "enu": [0.0, 0.0, 0.0], "yaw_rad": 0.0},
            {"tag": "R-2", "asset": ASSET, "state": "reactor_A2", "enu": [0.5, -4.0, 0.0], "yaw_rad": 0.3}]}))
    sources.mkdir()
    config = root / "live.toml"
    config.write_text(DATASET)
    return build, sources, config
