"""A dataset's frames as a sequence: frame i is a pure function of (config, site, i).

Each frame draws from its own random stream, seeded by (the config's seed, i), so the
first N frames of a run with --frames N are the first N of the full run, and a frame
is the same whichever worker renders it and in whatever order. Nothing here needs bpy.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import config
from ..errors import UserError
from ..runtime import camera as camera_model
from .. import sun as sun_model
from .config import CameraFamily, DatasetConfig
from ..perception.gauge import dial_of
from ..geometry.pinhole import cull, intrinsics, look_at
from ..runtime.site import Shot, BuiltSite

MAST_EYE_ABOVE_TILT_M = 0.15  # the PTZ head's lens above its tilt axis


@dataclass
class FramePlan:
    """One frame: the shot (camera, sun, visual states), and what the labels record."""

    index: int
    frame_id: str
    seed: int
    camera: str  # "<kind>:<name>"
    shot: Shot
    aerosol: float
    tau_atm: float
    oil_levels: dict[str, dict[str, float]]  # tag -> variable -> %
    switches: dict[str, str]  # tag -> "open" | "closed"
    visible_tags: list[str] = field(default_factory=list)  # what the frame loads (culled)
    look: dict | None = None  # the config's [appearance] drawn for this frame (appearance()), None without


def frame_id(index: int) -> str:
    return f"{index:06d}"


def frame_seed(cfg: DatasetConfig, index: int) -> int:
    """The frame's own seed (Cycles, sensor noise), from the config's seed and i."""
    return int(np.random.SeedSequence([cfg.seed, index]).generate_state(1)[0]) & 0x7FFFFFFF


class Planner:
    """Frames of one config on one site; the site's camera routes resolved once."""

    def __init__(self, cfg: DatasetConfig, site: BuiltSite, sources: Path):
        self.cfg, self.site = cfg, site
        self.weights = np.array([c.weight for c in cfg.cameras], float)
        if not self.weights.sum() > 0:
            raise UserError(cfg.path, "cameras", "every camera's weight is 0")
        self.weights /= self.weights.sum()
        self.spheres = site.spheres()
        self.routes = [self._route(c, i, sources) if c.kind == "route" else None for i, c in enumerate(cfg.cameras)]
        for i, c in enumerate(cfg.cameras):
            self._check(c, f"cameras[{i}]")
        # placements whose state the dataset samples (bound visuals), and switches
        self.bound = [p for p in site.placements if site.manifests.get(p["asset"], {}).get("bindings")]
        self.switchgear = [p for p in site.placements
                           if any(j["type"] == "revolute" for j in site.manifests.get(p["asset"], {}).get("joints", []))
                           and site.manifests[p["asset"]].get("category") == "switchgear"]

    # -- checks against the site
    def _check(self, c: CameraFamily, key: str) -> None:
        tags = {p["tag"] for p in self.site.placements}
        for name in c.points:
            if name not in self.site.inspection:
                raise UserError(self.cfg.path, f"{key}.points", f"{name!r} is not an inspection point of site.toml")
        if c.kind == "inspection_point" and not (c.points or self.site.inspection):
            raise UserError(self.cfg.path, key, "site.toml has no inspection points")
        if c.kind == "ptz":
            if c.mast not in tags:
                raise UserError(self.cfg.path, f"{key}.mast", f"{c.mast!r} is not a placement of the floor plan")
            for j, (target, _) in enumerate(c.presets):
                if target not in tags:
                    raise UserError(self.cfg.path, f"{key}.presets[{j}].target", f"{target!r} is not a placement")

    def _route(self, c: CameraFamily, i: int, sources: Path) -> np.ndarray:
        """(n, 3) ENU vertices of a route polyline, `height` above its level."""
        from ..georef import Georeferencer

        cfg = config.load_site(sources / "site.toml")
        try:
            level = cfg.level(c.level)
        except KeyError:
            raise UserError(self.cfg.path, f"cameras[{i}].level", f"{c.level!r} is not a level of site.toml") from None
        xy = np.array(c.path, float)
        return Georeferencer(cfg, self.site.origin).to_enu(xy, np.full(len(xy), level.elevation + c.height))

    # -- one frame
    def plan(self, index: int) -> FramePlan:
        cfg = self.cfg
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([cfg.seed, index, 1])))
        ci = int(rng.choice(len(cfg.cameras), p=self.weights))
        cam = cfg.cameras[ci]
        zoom = float(math.exp(rng.uniform(math.log(cam.zoom[0]), math.log(cam.zoom[1]))))
        pose, target, name, preset_zoom = self._pose(cam, ci, rng)
        zoom = preset_zoom or zoom
        when = self._when(rng)
        tau = float(rng.uniform(*cfg.conditions.tau_atm))
        aerosol = float(rng.uniform(*cfg.conditions.aerosol))
        el, az = sun_model.ephemeris(self.site.origin[0], self.site.origin[1], when)
        e = math.radians(el)
        oil, switches, visual = self._states(rng)
        shot = Shot(when, pose, camera_model.lens(zoom), e, math.radians(az), sun_model.irradiance(e, tau),
                    oil, visual, target)
        plan = FramePlan(index, frame_id(index), frame_seed(cfg, index), f"{cam.kind}:{name}", shot, aerosol, tau,
                         oil, switches)
        plan.visible_tags = self._visible(shot)
        if cfg.appearance is not None:
            plan.look = appearance(cfg.appearance, cfg.seed, index, plan.visible_tags)
        return plan

    def _when(self, rng: np.random.Generator) -> dt.datetime:
        c = self.cfg.conditions
        date = c.dates[int(rng.integers(len(c.dates)))]
        lo = c.local_time[0].hour * 60 + c.local_time[0].minute
        hi = c.local_time[1].hour * 60 + c.local_time[1].minute
        minute = int(rng.integers(lo, hi + 1))
        wall = dt.datetime.combine(date, dt.time(minute // 60, minute % 60))
        if self.site.zone is None:
            raise UserError(self.cfg.path, "conditions.local_time",
                            "local times need the site's time zone: site.toml [site] timezone, then rebuild")
        try:
            return config.local_time(wall, self.site.zone)
        except ValueError:  # a skipped or repeated wall time: the minute after is unambiguous
            return config.local_time(wall + dt.timedelta(hours=1), self.site.zone)

    def _aim(self, tag: str) -> np.ndarray:
        return aim(self.site, tag)

    def _pose(self, cam: CameraFamily, ci: int, rng: np.random.Generator) -> tuple[np.ndarray, str, str, float | None]:
        """(camera pose, target tag or "", the camera's name in the labels, the preset's
        zoom for a PTZ camera)."""
        if cam.kind == "inspection_point":
            names = list(cam.points) or sorted(self.site.inspection)
            name = names[int(rng.integers(len(names)))]
            point = self.site.inspection[name]
            return look_at(point["enu"], self._aim(point["target"])), point["target"], name, None
        if cam.kind == "ptz":
            target, preset_zoom = cam.presets[int(rng.integers(len(cam.presets)))]
            return look_at(self._mast_eye(cam.mast), self._aim(target)), target, f"{cam.mast}>{target}", preset_zoom
        route = self.routes[ci]
        seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
        s = rng.uniform(0.0, seg.sum())
        k = min(int(np.searchsorted(np.cumsum(seg), s, side="right")), len(seg) - 1)
        t = (s - (np.cumsum(seg)[k] - seg[k])) / seg[k]
        eye = route[k] + t * (route[k + 1] - route[k])
        ahead = (route[k + 1] - route[k]) / seg[k]
        near = [(float(np.linalg.norm(self._aim(p["tag"]) - eye)), p["tag"]) for p in self.site.placements
                if p["asset"] in cam.look_at and p["asset"] in self.site.manifests]
        near = [(d, tag) for d, tag in near if d <= cam.reach_m]
        if near:
            _, tag = min(near)
            return look_at(eye, self._aim(tag)), tag, f"route{ci}@{s:.1f}m", None
        return look_at(eye, eye + ahead * 10.0 + np.array([0.0, 0.0, -0.5])), "", f"route{ci}@{s:.1f}m", None

    def _mast_eye(self, mast: str) -> np.ndarray:
        return mast_eye(self.site, mast)

    def _states(self, rng: np.random.Generator):
        from ..runtime import nodes

        lo, hi = self.cfg.states.oil_level
        oil, values, observed = {}, {}, []
        for p in self.bound:
            m = self.site.manifests[p["asset"]]
            variables = sorted({b["variable"] for b in m["bindings"]})
            levels = {v: round(float(rng.uniform(lo, hi)), 3) for v in variables}
            oil[p["tag"]] = levels
            state = p.get("state") or p["tag"]
            values[state] = levels
            observed.append(nodes.Observed(p["tag"], state, p["asset"], m))
        switches = {p["tag"]: ("open" if rng.uniform() < self.cfg.states.switch_open else "closed")
                    for p in self.switchgear}
        return oil, switches, nodes.visual_states(values, observed)

    def _visible(self, shot: Shot) -> list[str]:
        return visible_tags(self.spheres, shot, self.cfg.sensor.width, self.cfg.sensor.height)


def aim(site: BuiltSite, tag: str) -> np.ndarray:
    """Where a camera aims at a placement: its gauge's dial when it has one, else the
    centre of its bounding box."""
    p = site.placement(tag)
    m = site.manifests.get(p["asset"], {})
    dial = dial_of(site.pose(p), m)
    if dial is not None:
        return dial.centre
    lo, hi = np.array(m["bounds"][0]), np.array(m["bounds"][1])
    return (site.pose(p) @ np.r_[(lo + hi) / 2, 1.0])[:3]


def mast_eye(site: BuiltSite, mast: str) -> np.ndarray:
    """A PTZ head's lens: above the tilt joint of the mast's model."""
    p = site.placement(mast)
    joints = site.manifests[p["asset"]].get("joints", [])
    tilt = next((j for j in joints if "tilt" in j["name"]), None)
    if tilt is None:
        _, hi = site.manifests[p["asset"]]["bounds"]
        local = np.array([0.0, 0.0, hi[2] + MAST_EYE_ABOVE_TILT_M])
    else:
        local = np.array(tilt["pose"]).reshape(4, 4)[:3, 3] + [0.0, 0.0, MAST_EYE_ABOVE_TILT_M]
    return (site.pose(p) @ np.r_[local, 1.0])[:3]


def visible_tags(spheres: list[dict], shot: Shot, width: int, height: int) -> list[str]:
    """Placements the camera sees or that shadow into what it sees (culling), the shot's
    target always: what a frame shows (`twin dataset`'s and `twin serve`'s alike).
    spheres: BuiltSite.spheres()."""
    k = intrinsics(shot.lens.hfov, width, height)
    sun = shot.sun_dir if shot.sun_elevation > 0 else None
    tags = {it["tag"] for it in cull(spheres, shot.cam_pose, k, shot.lens.near, shot.lens.far, sun)}
    if shot.target:
        tags.add(shot.target)
    return sorted(tags)


def switch_angles(manifest: dict, position: str) -> dict[str, float]:
    """Joint values of a switch: closed is each revolute joint at the value of its range
    nearest 0 (the pose it was modelled in), open at the limit farthest from 0."""
    out = {}
    for j in manifest.get("joints", []):
        if j["type"] != "revolute":
            continue
        lo, hi = float(j.get("lower", 0.0)), float(j.get("upper", 0.0))
        closed = min(max(0.0, lo), hi)
        far = lo if abs(lo) > abs(hi) else hi
        out[j["name"]] = far if position == "open" else closed
    return out


def appearance(look, seed: int, index: int, tags: list[str]) -> dict:
    """Frame `index`'s draw of a config's [appearance]: a stream of its own (the
    frame's other draws are those of a config without one), each instance's values
    drawn in tag order. {"instances": {tag: {tint: [r, g, b], offset (of its stains'
    noise, m), roughness, dirt, rust, oil_stains, weathering}}, "sky", "exposure_ev",
    "vignetting"}."""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, index, 2])))
    kinds = [k for k, _ in look.sky]
    weights = np.array([w for _, w in look.sky], float)
    sky = kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]
    exposure = float(rng.uniform(*look.exposure_ev))
    vignetting = float(rng.uniform(*look.vignetting))
    instances = {}
    for tag in sorted(tags):
        c, r = rng.uniform(*look.colour_jitter), rng.uniform(*look.roughness_jitter)
        instances[tag] = {"tint": [round(float(1.0 + v), 4) for v in rng.uniform(-c, c, 3)],
                          "offset": [round(float(v), 3) for v in rng.uniform(0.0, 100.0, 3)],
                          "roughness": round(float(rng.uniform(-r, r)), 4),
                          **{k: round(float(rng.uniform(*getattr(look, k))), 4)
                             for k in ("dirt", "rust", "oil_stains", "weathering")}}
    return {"instances": instances, "sky": sky, "exposure_ev": round(exposure, 4), "vignetting": round(vignetting, 4)}
