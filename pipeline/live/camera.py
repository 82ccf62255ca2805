"""The live camera: a site.toml inspection point, a PTZ preset of a dataset config
(`--sensor`; named "<mast>>TARGET" as `twin dataset` names them) or an explicit pose,
and a zoom in [1, 100] (the study's optical/digital split, runtime/camera.py)."""

from __future__ import annotations

import math

import numpy as np

from ..datasets.plan import aim, mast_eye
from ..geometry.pinhole import look_at
from ..runtime import camera as camera_model
from ..runtime.site import BuiltSite


class LiveCamera:
    def __init__(self, site: BuiltSite, presets: dict[str, tuple[str, str, float | None]] | None = None):
        """presets: name -> (mast tag, target tag, preset zoom or None)."""
        self.site = site
        self.presets = dict(presets or {})
        self.zoom = 1.0
        self.name, self.target, self.pose = "", "", np.eye(4)
        if site.inspection:
            self._point(sorted(site.inspection)[0])
        elif self.presets:
            self.zoom = self._preset(sorted(self.presets)[0]) or 1.0
        else:  # nothing named: over the scene from the south-west, 30 m up
            self.name, self.pose = "overview", look_at(np.array([-60.0, -60.0, 30.0]), np.zeros(3))

    def names(self) -> dict:
        return {"points": sorted(self.site.inspection), "presets": sorted(self.presets)}

    def lens(self) -> camera_model.Lens:
        return camera_model.lens(self.zoom)

    def state(self) -> dict:
        lens = self.lens()
        return {"name": self.name, "target": self.target, "pose": [float(v) for v in self.pose.reshape(16)],
                "zoom": lens.zoom, "hfov_deg": math.degrees(lens.hfov), "near": lens.near, "far": lens.far,
                "optical": lens.optical}

    def command(self, req: dict) -> None:
        """Apply a `camera` request (checked against the schema already); ValueError names
        the unknown point, preset or placement, or the bad pose or zoom. Nothing changes
        unless all of it is good."""
        zoom = self.zoom if req.get("zoom") is None else float(req["zoom"])
        camera_model.lens(zoom)  # ValueError outside [1, 100]
        chosen = [k for k in ("point", "preset", "pose", "eye") if k in req]
        if len(chosen) > 1:
            raise ValueError(f"give one of point, preset, pose or eye/look_at, not {' and '.join(chosen)}")
        target = req.get("target", "")
        if target and target not in {p["tag"] for p in self.site.placements}:
            raise ValueError(f"target {target!r} is not a placement of the scene")
        if "point" in req:
            if req["point"] not in self.site.inspection:
                raise ValueError(f"unknown inspection point {req['point']!r} (known: "
                                 f"{', '.join(sorted(self.site.inspection)) or 'none'})")
            self._point(req["point"])
        elif "preset" in req:
            if req["preset"] not in self.presets:
                raise ValueError(f"unknown PTZ preset {req['preset']!r} (known: {', '.join(sorted(self.presets)) or 'none'})")
            preset_zoom = self._preset(req["preset"])
            if req.get("zoom") is None and preset_zoom:
                zoom = preset_zoom
        elif "pose" in req:
            pose = np.array(req["pose"], dtype=np.float64).reshape(4, 4)
            if not np.all(np.isfinite(pose)) or not np.allclose(pose[3], [0, 0, 0, 1]) or \
                    not np.allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-6):
                raise ValueError("pose: not a rigid 4x4 transform (row-major, world-from-camera)")
            self.name, self.target, self.pose = "pose", target, pose
        elif "eye" in req:
            if "look_at" not in req:
                raise ValueError("eye needs look_at")
            eye, at = np.array(req["eye"], float), np.array(req["look_at"], float)
            if np.linalg.norm(at - eye) < 1e-6:
                raise ValueError("eye and look_at are the same point")
            self.name, self.target, self.pose = "pose", target, look_at(eye, at)
        self.zoom = zoom

    def _point(self, name: str) -> None:
        point = self.site.inspection[name]
        target = point.get("target") or ""
        at = aim(self.site, target) if target else np.asarray(point["enu"]) + [0.0, 10.0, 0.0]
        self.name, self.target, self.pose = f"inspection_point:{name}", target, look_at(point["enu"], at)

    def _preset(self, name: str) -> float | None:
        mast, target, zoom = self.presets[name]
        self.name, self.target = f"ptz:{name}", target
        self.pose = look_at(mast_eye(self.site, mast), aim(self.site, target))
        return zoom
