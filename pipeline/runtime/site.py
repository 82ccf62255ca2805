"""What the renderer reads from a build and site.toml (the BuiltSite), and what one frame
needs, free of bpy (the Shot)."""

from __future__ import annotations

import datetime as dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import config
from . import camera as camera_model
from .. import sun as sun_model

@dataclass
class BuiltSite:
    """What the renderer reads from a build (placements.json, manifests) and site.toml."""

    build: Path
    placements: list[dict]
    manifests: dict[str, dict]
    origin: tuple[float, float, float]
    date: str
    inspection: dict[str, dict] = field(default_factory=dict)  # name -> {enu, target}
    terrain: str | None = None  # the terrain package (placed at the ENU origin)
    zone: dt.tzinfo | None = None  # site.toml [site] timezone, as site.toml or the build records it
    # the Gazebo world's switches as the build wrote them: "all" move on joints, "none", or
    # the tag patterns of those that move (config.moves_in_gazebo; placements.json records
    # it, "auto" resolved)
    moving_parts: str | tuple[str, ...] = "all"
    moving_parts_by: str | None = None  # "auto" when the build chose moving_parts itself

    def placement(self, tag: str) -> dict:
        for p in self.placements:
            if p["tag"] == tag:
                return p
        raise KeyError(tag)

    def pose(self, p: dict) -> np.ndarray:
        c, s = math.cos(p["yaw_rad"]), math.sin(p["yaw_rad"])
        m = np.eye(4)
        m[:2, :2] = [[c, -s], [s, c]]
        m[:3, 3] = p["enu"]
        return m

    def spheres(self) -> list[dict]:
        """World bounding spheres of every placement whose package is built."""
        out = []
        for p in self.placements:
            m = self.manifests.get(p["asset"])
            if m is None:
                continue
            lo, hi = np.array(m["bounds"][0]), np.array(m["bounds"][1])
            centre = self.pose(p) @ np.r_[(lo + hi) / 2, 1.0]
            out.append({"tag": p["tag"], "asset": p["asset"], "centre": centre[:3],
                        "radius": float(np.linalg.norm(hi - lo) / 2)})
        return out


def load_site(build: Path, sources: Path) -> BuiltSite:
    from ..errors import UserError
    from ..export import manifest as manifest_io

    build = Path(build)
    index = build / "scene" / "placements.json"
    if not index.is_file():
        raise UserError(index, None, "no built scene: run `twin build` first")
    data = json.loads(index.read_text())
    manifests = {}
    for asset in sorted({p["asset"] for p in data["placements"]}):
        if (build / "models" / asset / manifest_io.MANIFEST).is_file():
            manifests[asset] = manifest_io.read(build / "models" / asset)
    o = data["origin"]
    origin = (o["latitude_deg"], o["longitude_deg"], o["height_m"])
    gazebo = data.get("gazebo", {})
    site = BuiltSite(build, data["placements"], manifests, origin, "2025-03-20",
                     moving_parts=config.moving_parts_setting(gazebo.get("moving_parts", "all")),
                     moving_parts_by=gazebo.get("chosen_by"))
    if data.get("timezone"):
        site.zone = config.time_zone(data["timezone"], index, "timezone")
    terrain = data.get("terrain")
    if terrain and (build / "models" / terrain / f"{terrain}.glb").is_file():
        site.terrain = terrain
    sources = Path(sources)
    if (sources / "site.toml").is_file():
        _add_site_toml(site, sources / "site.toml")
    return site


def _add_site_toml(site: BuiltSite, path: Path) -> None:
    """Inspection points in ENU through the same georeferencer the build used."""
    from ..georef import Georeferencer
    from ..scene.placements import inspection_points_enu

    cfg = config.load_site(path)
    site.date, site.zone = cfg.date, cfg.zone
    enu = inspection_points_enu(cfg, Georeferencer(cfg, site.origin))
    for p, e in zip(cfg.inspection_points, enu):
        site.inspection[p.name] = {"enu": np.asarray(e, float), "target": p.target}


# --- per-frame description ----------------------------------------------------------------


@dataclass
class Shot:
    """Everything one frame needs, free of bpy."""

    when: dt.datetime
    cam_pose: np.ndarray
    lens: camera_model.Lens
    sun_elevation: float  # rad
    sun_azimuth: float  # rad
    irradiance: float  # W/m2, direct horizontal
    states: dict = field(default_factory=dict)  # tag -> {variable: value}
    visual_states: list = field(default_factory=list)  # nodes.VisualState
    target: str = ""
    # every span's (degC), or per conductor type (twin serve's groups); None: as built
    conductor_temperature_c: float | dict[str, float | None] | None = None

    @property
    def sun_dir(self) -> np.ndarray:
        return sun_model.direction_enu(self.sun_elevation, self.sun_azimuth)

    @property
    def dni(self) -> float:
        s = math.sin(self.sun_elevation)
        return self.irradiance / s if s > 1e-6 else 0.0

