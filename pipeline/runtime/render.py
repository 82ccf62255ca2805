"""Render-in-the-loop image sets: `twin render SCENARIO` and `twin render --study`.

Cycles on the CPU renders the *built* packages (their .glb, through Blender's glTF
importer), never the sources. The runtime's own models drive everything: the sun node
(sun.py) gives direction and irradiance, the camera model (camera.py) gives FOV and clip
planes from the zoom, the render node's mapping (nodes.visual_states) gives the pointer
pose and oil-column shape weights from the state.

The phone camera is modelled outside Blender, on the linear (scene-referred) render:

    pixel = NR(sRGB(clip(gain * (wb * radiance + veil), 0, 1)))

- wb: grey-world auto white balance, metered with the exposure; NR: the phone ISP's
  noise reduction (3x3 median + non-local means; saturated areas stay at 255).

- gain: exposure locked once per scene (a condition, or a scenario) by centre-weighted
  metering of a first render to a mean of 0.18, clamped to the phone's longest exposure
  at its highest ISO (GAIN_MAX), so night stays dark instead of being lifted to grey.
- clip: the sensor saturates like a real one (a Standard transform; Filmic/AgX would
  compress highlights and hide exactly the saturation the study measures).
- veil: veiling glare of the lens, proportional to the direct sun irradiance reaching the
  lens and falling off with the sun's angle to the optical axis; zero when the sun is
  behind the lens, below the horizon or occluded. It is added after metering: a locked
  exposure does not react to it, which is what washes the crop out in low sun.

bpy is imported only inside the functions that render.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
import re
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import config
from . import camera as camera_model
from . import sun as sun_model

# --- the phone camera ----------------------------------------------------------------


@dataclass(frozen=True)
class PhoneCamera:
    """Exposure and glare of a phone camera (defaults: a Galaxy S23 class main camera).

    gain_max: the largest linear gain (about 1/10 s at ISO 3200, 15 stops above a sunny
    scene's exposure); radiance below ~0.003 W/m2/sr stays dark. veil_k and veil_width
    (rad) set the veiling glare: veil = veil_k * E_sun_at_lens * exp(-(theta/width)^2)
    in radiance units (W/m2/sr per W/m2): a few per cent of the sun's irradiance per
    steradian near the axis, negligible beyond ~40 degrees; a plausible phone lens with
    a smudged cover glass, not a device measurement.

    samples and render_denoise: the path tracer's budget. 4 samples through Cycles'
    OpenImageDenoise (albedo and normal guides, BALANCED quality, on the CPU) land
    closer to a converged render than 16 raw samples (8-bit RMS error 3.5 against 9.9 at
    noon, 7.6 against 25.7 at midnight, in 40 % of the time; bench_render measures it
    against a 256-sample reference); 8 samples came 2-12 % closer at 1.5-2x the time, and
    moved the study's C by at most 0.006 and H by at most 0.016 (S not at all). OIDN on the CPU gives the same pixels in
    every run and process, so frames stay a function of scenario and seed.
    """

    metering_target: float = 0.40
    gain_max: float = 60.0
    gain_min: float = 1e-5
    veil_k: float = 0.15
    veil_width: float = 0.35
    width: int = 320
    height: int = 240
    samples: int = 4
    render_denoise: str = "BALANCED"  # Cycles OIDN quality (FAST, BALANCED, HIGH); "" = off
    denoise: float = 10.0  # ISP noise reduction (3x3 median, then OpenCV NL-means h); 0 = off


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function on [0, 1] values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


def metered_gain(linear_rgb: np.ndarray, cam: PhoneCamera) -> float:
    """Centre-weighted average metering: the gain that brings the weighted mean
    luminance to the metering target, clamped to what the phone can do."""
    h, w = linear_rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
    mean = float((luminance(linear_rgb) * weight).sum() / weight.sum())
    if not mean > 0.0:
        return cam.gain_max
    return float(np.clip(cam.metering_target / mean, cam.gain_min, cam.gain_max))


def veil_radiance(sun_dir: np.ndarray, view_axis: np.ndarray, dni: float, visible: bool, cam: PhoneCamera) -> float:
    """Veiling-glare radiance added over the frame by the sun at `sun_dir` (ENU unit)."""
    cos_t = float(np.dot(sun_dir, view_axis))
    if not visible or dni <= 0.0 or cos_t <= 0.0:
        return 0.0
    theta = math.acos(min(1.0, cos_t))
    return cam.veil_k * dni * math.exp(-((theta / cam.veil_width) ** 2))


def metered_white_balance(linear_rgb: np.ndarray, cam: PhoneCamera) -> np.ndarray:
    """Grey-world auto white balance with the metering's centre weights: per-channel
    gains (luminance-neutral, each within [1/4, 4]) that make the weighted mean grey,
    as a phone does under a blue night sky or sodium-coloured floodlights."""
    h, w = linear_rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
    mean = (linear_rgb * weight[..., None]).sum(axis=(0, 1)) / weight.sum()
    if not (mean > 0).all():
        return np.ones(3)
    wb = np.clip(mean.mean() / mean, 0.25, 4.0)
    return wb / float(luminance(wb[None, :])[0])


def develop(linear_rgb: np.ndarray, gain: float, veil: float, wb=None, cam: PhoneCamera | None = None) -> np.ndarray:
    """(h, w, 3) linear radiance -> (h, w, 3) uint8 sRGB (RGB order): white balance,
    exposure gain, veiling glare, sensor clip, sRGB, then the phone ISP's noise
    reduction (non-local means; it also stands in for the many frames a phone merges)."""
    wb = np.ones(3) if wb is None else np.asarray(wb, float)
    out = np.round(srgb_encode(gain * (linear_rgb * wb + veil)) * 255.0).astype(np.uint8)
    strength = (cam or PhoneCamera()).denoise
    if strength > 0:
        import cv2

        out = cv2.medianBlur(np.ascontiguousarray(out), 3)  # path-tracing salt and pepper first
        clipped = (out == 255).all(axis=-1)  # a saturated area stays saturated (not a firefly)
        out = cv2.fastNlMeansDenoisingColored(out, None, strength, strength, 5, 15)
        out[clipped] = 255
    return out


# --- camera geometry -----------------------------------------------------------------


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) camera-to-world pose, Blender convention: looks down local -Z, +Y up."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(np.asarray(up, float), back)
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down: any right will do
        right = np.cross((0.0, 1.0, 0.0), back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def intrinsics(hfov: float, width: int, height: int) -> dict:
    """Pinhole intrinsics of a horizontal-fit camera, pixels; (0, 0) = top-left corner
    of the top-left pixel, so the image centre is (width / 2, height / 2)."""
    fx = (width / 2.0) / math.tan(hfov / 2.0)
    return {"fx": fx, "fy": fx, "cx": width / 2.0, "cy": height / 2.0, "width": width, "height": height,
            "hfov": hfov, "vfov": 2.0 * math.atan((height / 2.0) / fx)}


def project(points: np.ndarray, pose: np.ndarray, k: dict) -> np.ndarray:
    """(n, 3) world points -> (n, 2) pixel (u right, v down); NaN behind the camera."""
    p = (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]  # world -> camera axes
    depth = -p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.c_[k["cx"] + k["fx"] * p[:, 0] / depth, k["cy"] - k["fy"] * p[:, 1] / depth]
    uv[depth <= 0] = np.nan
    return uv


# The main-tank dial (sources/authoring/ASSETS.md): centre and facing in the model frame.
DIAL_CENTER = np.array([0.0, -1.80, 2.80])
DIAL_NORMAL = np.array([0.0, -1.0, 0.0])
DIAL_RADIUS = 0.15 * 1.12  # the bezel's outer radius
POINTER = "gauge_tank_pointer"


FACE_RADIUS = 0.15  # the dial face inside the bezel


def dial_outline(model_pose: np.ndarray, n: int = 32, radius: float = DIAL_RADIUS) -> np.ndarray:
    """(n, 3) world points on the bezel's rim (the dial lies in the model XZ plane)."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    local = DIAL_CENTER + radius * np.c_[np.cos(a), np.zeros(n), np.sin(a)]
    return local @ model_pose[:3, :3].T + model_pose[:3, 3]


def gauge_box(model_pose: np.ndarray, cam_pose: np.ndarray, k: dict) -> dict:
    """2D box of the dial projected from its 3D rim, clipped to the frame."""
    uv = project(dial_outline(model_pose), cam_pose, k)
    if np.isnan(uv).any():
        return {"box": None, "visible": False}
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    clipped = [max(0.0, lo[0]), max(0.0, lo[1]), min(k["width"], hi[0]), min(k["height"], hi[1])]
    inside = bool(lo[0] >= 0 and lo[1] >= 0 and hi[0] <= k["width"] and hi[1] <= k["height"])
    centre = project((model_pose @ np.r_[DIAL_CENTER, 1.0])[None, :3], cam_pose, k)[0]
    return {"box": [float(v) for v in clipped], "box_unclipped": [float(v) for v in (*lo, *hi)],
            "centre": [float(v) for v in centre], "inside_frame": inside,
            "visible": bool(clipped[2] > clipped[0] and clipped[3] > clipped[1])}


def dial_world(model_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return model_pose[:3, :3] @ DIAL_CENTER + model_pose[:3, 3], model_pose[:3, :3] @ DIAL_NORMAL


# --- what to load: frustum + shadow culling --------------------------------------------


def _frustum_planes(pose: np.ndarray, k: dict, near: float, far: float) -> list[tuple[np.ndarray, float]]:
    """Inward planes (n, d) with n.x + d >= 0 inside."""
    r, u, b, c = pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3]
    f = -b
    th, tv = math.tan(k["hfov"] / 2), math.tan(k["vfov"] / 2)
    normals = [f, -f, f * th + r, f * th - r, f * tv + u, f * tv - u]
    planes = []
    for i, n in enumerate(normals):
        n = n / np.linalg.norm(n)
        d = -float(n @ c) - (near if i == 0 else 0.0)
        if i == 1:
            d = float(f @ c) + far
            n = -f
        planes.append((n, d))
    return planes


def cull(items: list[dict], pose: np.ndarray, k: dict, near: float, far: float,
         sun_dir: np.ndarray | None, shadow_m: float = 60.0) -> list[dict]:
    """Items ({'centre', 'radius', ...}, world bounding spheres) that the camera sees or
    whose shadow can fall into what it sees: the sphere, swept `shadow_m` away from the
    sun, touches the frustum. Sampling the sweep every half radius (at least 1 m) is
    enough for a conservative sphere test."""
    planes = _frustum_planes(pose, k, near, far)
    keep = []
    for it in items:
        c, rad = np.asarray(it["centre"], float), float(it["radius"])
        sweep = [0.0]
        if sun_dir is not None and sun_dir[2] > 0:
            step = max(1.0, rad / 2)
            sweep = list(np.arange(0.0, shadow_m + step, step))
        for t in sweep:
            p = c - (sun_dir * t if t else 0.0)
            if all(n @ p + d >= -rad for n, d in planes):
                keep.append(it)
                break
    return keep


# --- the scene as the runtime sees it -----------------------------------------------------


@dataclass
class Site:
    """What the renderer reads from a build (placements.json, manifests) and site.toml."""

    build: Path
    placements: list[dict]
    manifests: dict[str, dict]
    origin: tuple[float, float, float]
    date: str
    inspection: dict[str, dict] = field(default_factory=dict)  # name -> {enu, target}
    terrain: str | None = None  # the terrain package (placed at the ENU origin)
    zone: dt.tzinfo | None = None  # site.toml [site] timezone, as site.toml or the build records it

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


def load_site(build: Path, sources: Path | None = None) -> Site:
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
    site = Site(build, data["placements"], manifests, origin, "2025-03-20")
    if data.get("timezone"):
        site.zone = config.time_zone(data["timezone"], index, "timezone")
    terrain = data.get("terrain")
    if terrain and (build / "models" / terrain / f"{terrain}.glb").is_file():
        site.terrain = terrain
    sources = Path(sources) if sources else Path(__file__).resolve().parents[2] / "sources"
    if (sources / "site.toml").is_file():
        _add_site_toml(site, sources / "site.toml")
    return site


def _add_site_toml(site: Site, path: Path) -> None:
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

    @property
    def sun_dir(self) -> np.ndarray:
        return sun_model.direction_enu(self.sun_elevation, self.sun_azimuth)

    @property
    def dni(self) -> float:
        s = math.sin(self.sun_elevation)
        return self.irradiance / s if s > 1e-6 else 0.0


def pointer_angle(level: float, binding: dict) -> float:
    """The binding's linear map of the tank level to the pointer angle (rad)."""
    (d0, d1), (r0, r1) = binding["domain"], binding["range"]
    x = min(max(level, min(d0, d1)), max(d0, d1))
    return r0 + (r1 - r0) * (x - d0) / (d1 - d0)


# --- the Blender side ---------------------------------------------------------------------


class _Blender:
    """One Cycles scene: imported packages, lights, camera. Packages are imported once
    per asset; more placements of it share its meshes (linked copies), except meshes with
    shape keys, which are per instance (their weights are)."""

    SKY_SCALE = 7.0  # Blender's sky texture -> W/m2/sr (clear-sky DHI ~120 W/m2 at 60 deg)
    NIGHT_AMBIENT = 2e-4  # W/m2/sr: airglow and light pollution
    MOON = {"elevation": math.radians(50.0), "azimuth": math.radians(80.0), "irradiance": 2.5e-3}
    LAMP_W = 5000.0  # W (radiant) per floodlight head, spot 70 degrees
    THREADS = 2

    def __init__(self, site: Site, cam: PhoneCamera, seed: int):
        import bpy

        self.bpy, self.site, self.cam = bpy, site, cam
        self.lamps: list = []
        bpy.ops.wm.read_factory_settings(use_empty=True)
        s = self.scene = bpy.context.scene
        s.render.engine = "CYCLES"
        s.cycles.device = "CPU"
        s.cycles.samples = cam.samples
        s.cycles.seed = int(seed) % (2**31)
        s.cycles.use_animated_seed = False
        s.cycles.use_adaptive_sampling = False
        s.cycles.use_denoising = bool(cam.render_denoise)
        if cam.render_denoise:
            s.cycles.denoiser = "OPENIMAGEDENOISE"
            s.cycles.denoising_quality = cam.render_denoise
            s.cycles.denoising_prefilter = "FAST"  # guides from the first hit: clean enough here
            s.cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            s.cycles.denoising_use_gpu = False  # same pixels on every machine
        # Blender's factory light paths (12 bounces, caustics, light tree): cutting them to
        # 2-4 bounces without caustics left the noon close-up 9 % darker than a converged
        # render (8-bit RMS error 10.8 against 3.5 at 4 samples + OIDN) and saved only a
        # tenth of the time. The floodlights are off while the sun is up (set_shot).
        s.render.threads_mode = "FIXED"
        s.render.threads = self.THREADS
        s.render.resolution_x, s.render.resolution_y = cam.width, cam.height
        s.render.resolution_percentage = 100
        # Cycles' persistent data would keep the BVH between frames (0.1-0.3 s a frame here),
        # but a night frame (lamps on, sun off) rendered after a day frame came out with other
        # pixels than the same frame rendered first: a frame must not depend on its history.
        s.render.use_persistent_data = False
        s.view_settings.view_transform = "Standard"
        s.render.image_settings.file_format = "OPEN_EXR"
        s.render.image_settings.color_depth = "32"
        self.roots: dict[str, object] = {}  # tag -> root object
        self.objects: dict[str, dict[str, object]] = {}  # tag -> visual name -> object
        self.prototypes: dict[str, str] = {}  # asset -> tag imported first
        self._world()
        self._camera()
        self.tmp = Path(tempfile.mkdtemp(prefix="twin_render_"))

    def close(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _world(self):
        bpy = self.bpy
        w = bpy.data.worlds.new("sky")
        self.scene.world = w
        w.use_nodes = True
        w.cycles.sampling_method = "MANUAL"  # the automatic 1024 map costs seconds per sky
        w.cycles.sample_map_resolution = 64
        nt = w.node_tree
        self.sky = nt.nodes.new("ShaderNodeTexSky")
        self.sky.sky_type = "MULTIPLE_SCATTERING"
        self.sky.sun_disc = False  # the sun lamp lights; the disc would only add noise
        amb = nt.nodes.new("ShaderNodeBackground")
        amb.inputs["Strength"].default_value = self.NIGHT_AMBIENT
        amb.inputs["Color"].default_value = (0.6, 0.7, 1.0, 1.0)
        bg = nt.nodes["Background"]
        nt.links.new(self.sky.outputs["Color"], bg.inputs["Color"])
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(bg.outputs[0], add.inputs[0])
        nt.links.new(amb.outputs[0], add.inputs[1])
        nt.links.new(add.outputs[0], nt.nodes["World Output"].inputs["Surface"])
        self.sky_bg = bg
        self.sun = self._sun_lamp("sun", 0.0093)  # the sun's angular diameter, rad
        self.moon = self._sun_lamp("moon", 0.009)

    def _sun_lamp(self, name: str, angle: float):
        bpy = self.bpy
        ob = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
        ob.data.angle = angle
        self.scene.collection.objects.link(ob)
        return ob

    def _camera(self):
        bpy = self.bpy
        self.camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        self.camera.data.sensor_fit = "HORIZONTAL"
        self.scene.collection.objects.link(self.camera)
        self.scene.camera = self.camera

    # -- content
    def load(self, tag: str) -> None:
        """Import a placement's built package (glTF) and put it at its ENU pose."""
        if tag in self.roots:
            return
        p = self.site.placement(tag)
        glb = self.site.build / "models" / p["asset"] / f"{p['asset']}.glb"
        if p["asset"] in self.prototypes:
            root, objs = self._copy(self.roots[self.prototypes[p["asset"]]])
        else:
            root, objs = self._import(glb)
            self.prototypes[p["asset"]] = tag
        root.matrix_world = _matrix(self.bpy, self.site.pose(p))
        # Children's world matrices are stale until the view layer updates; setting one
        # before that would be relative to the parent's old pose.
        self.bpy.context.view_layer.update()
        self.roots[tag], self.objects[tag] = root, objs

    def load_terrain(self) -> None:
        if self.site.terrain and "__terrain__" not in self.roots:
            root, objs = self._import(self.site.build / "models" / self.site.terrain / f"{self.site.terrain}.glb")
            self.roots["__terrain__"], self.objects["__terrain__"] = root, objs

    def _import(self, glb: Path):
        bpy = self.bpy
        before = set(bpy.data.objects)
        bpy.ops.import_scene.gltf(filepath=str(glb))
        new = [o for o in bpy.data.objects if o not in before]
        # Blender imports MSFT_lod's out-of-scene nodes as extra roots at the origin:
        # close-ups draw LOD 0, so the lower levels go
        lower = [o for o in new if LOD_NODE.search(_base_name(o.name))]
        new = [o for o in new if o not in lower]
        for o in lower:
            bpy.data.objects.remove(o, do_unlink=True)
        glass = {m.name for m in {sl.material for o in new for sl in o.material_slots if sl.material is not None}
                 if _tune_material(m)}
        for o in new:
            # A thin pane passes ~92 % of the light: shadow rays ignore it, so the dial
            # behind gets direct light (through a transparent shader they would be
            # sampled less well: twice the noise, half the light, measured at 16 samples).
            if any(sl.material is not None and sl.material.name in glass for sl in o.material_slots):
                o.visible_shadow = False
        root = next(o for o in new if o.parent is None)
        objs = {_base_name(o.name): o for o in new}
        return root, objs

    def _copy(self, root):
        """Linked duplicate of an imported hierarchy; shape-keyed meshes get own data."""
        mapping = {}
        for o in [root, *root.children_recursive]:
            c = o.copy()
            if o.type == "MESH" and o.data.shape_keys is not None:
                c.data = o.data.copy()
            self.scene.collection.objects.link(c)
            mapping[o] = c
        for o, c in mapping.items():
            if o.parent is not None:
                c.parent = mapping[o.parent]
                c.matrix_parent_inverse = o.matrix_parent_inverse.copy()
        return mapping[root], {_base_name(o.name): c for o, c in mapping.items()}

    def add_lamps(self, tags: list[str]) -> None:
        """Floodlights of the lighting poles as spot lights (the poles' meshes are loaded
        only if the camera sees them): one per emissive lens, shining out of its face."""
        bpy = self.bpy
        for tag in tags:
            p = self.site.placement(tag)
            m = self.site.manifests[p["asset"]]
            for link in m["links"]:
                for v in link["visuals"]:
                    if v["material"] != "lamp_white":
                        continue
                    pose = self.site.pose(p) @ np.array(link["pose"]).reshape(4, 4) @ np.array(v["pose"]).reshape(4, 4)
                    beam = pose[:3, :3] @ np.array([0.0, -1.0, 0.0])
                    light = bpy.data.lights.new(f"{tag}_{v['name']}", "SPOT")
                    light.energy = self.LAMP_W
                    light.spot_size = math.radians(70.0)
                    light.color = (1.0, 0.95, 0.85)
                    ob = bpy.data.objects.new(light.name, light)
                    ob.matrix_world = _matrix(bpy, look_at(pose[:3, 3] + beam * 0.05, pose[:3, 3] + beam))
                    self.scene.collection.objects.link(ob)
                    self.lamps.append(ob)

    # -- per frame
    def set_shot(self, shot: Shot, pointer_binding: dict | None) -> None:
        bpy = self.bpy
        cam = self.camera
        cam.matrix_world = _matrix(bpy, shot.cam_pose)
        cam.data.angle = shot.lens.hfov
        cam.data.clip_start, cam.data.clip_end = shot.lens.near, shot.lens.far
        self._set_sky(shot)
        for vs in shot.visual_states:
            objs = self.objects.get(vs.tag)
            if objs is None or vs.visual not in objs:
                continue
            ob = objs[vs.visual]
            link = self._link_pose(vs.tag, vs.link)
            ob.matrix_world = _matrix(bpy, self.site.pose(self.site.placement(vs.tag)) @ link @ vs.transform)
            for key, weight in vs.shape_weights.items():
                if ob.data.shape_keys is not None and key in ob.data.shape_keys.key_blocks:
                    ob.data.shape_keys.key_blocks[key].value = weight
            if vs.material is not None and vs.material in bpy.data.materials and ob.material_slots:
                ob.material_slots[0].material = bpy.data.materials[vs.material]

    def _link_pose(self, tag: str, link: str) -> np.ndarray:
        m = self.site.manifests[self.site.placement(tag)["asset"]]
        for rec in m["links"]:
            if rec["name"] == link:
                return np.array(rec["pose"]).reshape(4, 4)
        return np.eye(4)

    def _set_sky(self, shot: Shot) -> None:
        bpy = self.bpy
        self.sky.sun_elevation = shot.sun_elevation
        # Blender's sky rotation is counter-clockwise from +Y about +Z; azimuth is clockwise.
        self.sky.sun_rotation = -shot.sun_azimuth
        self.sky_bg.inputs["Strength"].default_value = self.SKY_SCALE
        up = shot.sun_elevation > 0
        self.sun.hide_render = not up
        self.sun.data.energy = shot.dni  # W/m2 normal to the rays: Cycles' sun unit
        self.sun.matrix_world = _matrix(bpy, look_at(shot.sun_dir, (0.0, 0.0, 0.0)))
        moon = self.MOON
        self.moon.hide_render = up
        for lamp in self.lamps:  # photocell floodlights: on from sunset to sunrise
            lamp.hide_render = up
        self.moon.data.energy = moon["irradiance"]
        mdir = sun_model.direction_enu(moon["elevation"], moon["azimuth"])
        self.moon.matrix_world = _matrix(bpy, look_at(mdir, (0.0, 0.0, 0.0)))

    def pointer_rows(self, tag: str, cam_pose: np.ndarray, k: dict) -> float | None:
        """Row extent (px) of the pointer's projected vertices: the true H numerator."""
        ob = self.objects.get(tag, {}).get(POINTER)
        if ob is None:
            return None
        self.bpy.context.view_layer.update()
        m = np.array(ob.matrix_world)
        v = np.array([tuple(x.co) for x in ob.data.vertices], float)
        uv = project(v @ m[:3, :3].T + m[:3, 3], cam_pose, k)
        return float(np.nanmax(uv[:, 1]) - np.nanmin(uv[:, 1]))

    def sun_visible(self, eye: np.ndarray, sun_dir: np.ndarray) -> bool:
        """Is the sun unobstructed from the lens (for the veiling glare)?"""
        from mathutils import Vector

        dg = self.bpy.context.evaluated_depsgraph_get()
        hit = self.scene.ray_cast(dg, Vector(eye + sun_dir * 0.01), Vector(sun_dir))[0]
        return not hit

    def render(self, width: int | None = None, height: int | None = None, samples: int | None = None) -> np.ndarray:
        """(h, w, 3) float32 linear radiance, top row first."""
        bpy, s = self.bpy, self.scene
        s.render.resolution_x = width or self.cam.width
        s.render.resolution_y = height or self.cam.height
        s.cycles.samples = samples or self.cam.samples
        path = self.tmp / "frame.exr"
        s.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        img = bpy.data.images.load(str(path))
        px = np.empty(len(img.pixels), dtype=np.float32)
        img.pixels.foreach_get(px)
        w, h = img.size
        bpy.data.images.remove(img)
        return px.reshape(h, w, 4)[::-1, :, :3].copy()


LOD_NODE = re.compile(r"__lod[1-9][0-9]*$")  # export/gltf.py names lower LODs so
GLASS_ALPHA_MAX = 0.5  # glTF alpha at or below which a material is a window, not a tint


def _tune_material(mat) -> bool:
    """Imported glTF materials for Cycles: window glass as clear glass (below); every
    Principled BSDF with single-scatter GGX (multiscatter cost a third of a 16-sample
    frame; bench_render's reference makes the same choice, so its error leaves this out)."""
    if not mat.node_tree:
        return False
    for n in mat.node_tree.nodes:
        if n.type == "BSDF_PRINCIPLED":
            n.distribution = "GGX"
    return _clear_glass(mat)


def _clear_glass(mat) -> bool:
    """A window material (glTF alpha <= GLASS_ALPHA_MAX, as the gauge glass's 0.25) as a
    thin clear pane of IOR 1.5, roughness 0: Fresnel-weighted specular reflection (4 %
    head-on, more at grazing angles) over full transmission without refraction offset
    (thin-walled). The glTF alpha blend keeps a 75 % diffuse share that greys the dial
    and pointer out; a refracting solid would need caustics to let the sun through.
    Transparent shadows let the sun reach the dial, as through real glass. Tinted
    see-through materials (the oil column, alpha 0.9) stay as imported."""
    if not mat.node_tree:
        return False
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None or bsdf.inputs["Alpha"].is_linked or bsdf.inputs["Alpha"].default_value > GLASS_ALPHA_MAX:
        return False
    nt = mat.node_tree
    rough = bsdf.inputs["Roughness"].default_value
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
    fresnel, mix = nt.nodes.new("ShaderNodeFresnel"), nt.nodes.new("ShaderNodeMixShader")
    fresnel.inputs["IOR"].default_value = 1.5
    clear, gloss = nt.nodes.new("ShaderNodeBsdfTransparent"), nt.nodes.new("ShaderNodeBsdfGlossy")
    gloss.inputs["Roughness"].default_value = 0.0 if rough <= 0.1 else rough
    nt.links.new(fresnel.outputs[0], mix.inputs[0])
    nt.links.new(clear.outputs[0], mix.inputs[1])
    nt.links.new(gloss.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return True


def _base_name(name: str) -> str:
    """Blender appends .001 to repeated names; the package's names are without it."""
    head, dot, tail = name.rpartition(".")
    return head if dot and tail.isdigit() else name


def _matrix(bpy, m: np.ndarray):
    from mathutils import Matrix

    return Matrix([list(map(float, row)) for row in np.asarray(m)])


# --- frames, labels, metrics ---------------------------------------------------------------


def frame_labels(shot: Shot, k: dict, site: Site, gain: float, veil: float, pointer_binding: dict | None) -> dict:
    """Labels of one frame: what was rendered, in numbers."""
    pose = shot.cam_pose
    target_pose = site.pose(site.placement(shot.target))
    levels = shot.states.get(shot.target, {})
    level = levels.get("oil_level_tank")
    gauges = {"gauge_tank": gauge_box(target_pose, pose, k)}
    return {
        "time": shot.when.isoformat(),
        "time_utc": shot.when.astimezone(dt.timezone.utc).isoformat(),
        "sun": {"azimuth_deg": math.degrees(shot.sun_azimuth), "elevation_deg": math.degrees(shot.sun_elevation),
                "irradiance_w_m2": shot.irradiance, "direct_normal_w_m2": shot.dni},
        "camera": {"zoom": shot.lens.zoom, "near": shot.lens.near, "far": shot.lens.far, **k,
                   "pose": [float(v) for v in pose.reshape(16)], "convention": "camera looks down -Z, +Y up; ENU",
                   "exposure_gain": gain, "veil": veil},
        "target": shot.target,
        "oil_levels": {v: float(x) for v, x in sorted(levels.items())},
        "pointer_angle_rad": pointer_angle(level, pointer_binding) if level is not None and pointer_binding else None,
        "gauges": gauges,
    }


def measure(bgr_crop: np.ndarray, bgr_face: np.ndarray) -> dict:
    """The study's C and S of a gauge crop and the pointer extent (px) on its dial face
    alone (runtime/perception.py): the crop's corners hold bezel and its shadows, which
    the region's convex hull would otherwise take for pointer pixels."""
    import cv2

    from . import perception

    gray = cv2.cvtColor(np.ascontiguousarray(bgr_crop), cv2.COLOR_BGR2GRAY)
    h, w = bgr_face.shape[:2]
    return {"C": perception.rms_contrast(gray), "S": perception.high_intensity_ratio(gray),
            "extent_px": float(perception.pointer_height(bgr_face, (0, 0, w, h)))}


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _write_png(path: Path, rgb: np.ndarray) -> str:
    """PNG without timestamps (OpenCV writes none), returns its sha256."""
    import cv2

    ok, buf = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    data = buf.tobytes()
    path.write_bytes(data)
    return _sha(data)


def _write_json(path: Path, data) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, sort_keys=True, indent=1, allow_nan=False) + "\n")
    tmp.replace(path)


# --- rendering a sequence of shots -------------------------------------------------------


def _pointer_binding(site: Site, tag: str) -> dict | None:
    m = site.manifests.get(site.placement(tag)["asset"], {})
    return next((b for b in m.get("bindings", []) if b["target"] == POINTER and b["effect"] == "rotate"), None)


def render_shots(site: Site, shots: list[Shot], folder: Path, *, cam: PhoneCamera, seed: int,
                 gain: float | None = None, names: list[str] | None = None, meter_each: bool = False) -> list[dict]:
    """Render shots into folder/<name>.png + <name>.json; one scene (loaded once, kept
    between frames), exposure locked at the first shot unless `gain` is given or
    `meter_each` (the phone re-meters every shot). Returns one record per frame."""
    folder.mkdir(parents=True, exist_ok=True)
    lock = (gain, (1.0, 1.0, 1.0)) if gain is not None else None
    bl = _Blender(site, cam, seed)
    try:
        _populate(bl, site, shots)
        records = []
        for i, shot in enumerate(shots):
            records.append(_one(bl, site, shot, folder, (names or [])[i] if names else f"frame_{i:04d}",
                                cam, lock))
            if lock is None and not meter_each:
                c = records[-1]["labels"]["camera"]
                lock = (c["exposure_gain"], c["white_balance"])
        return records
    finally:
        bl.close()


def _populate(bl: _Blender, site: Site, shots: list[Shot]) -> None:
    """Load what any shot's camera sees or what shadows into it, the targets at least,
    and the lighting poles near the targets as lamps."""
    spheres = site.spheres()
    wanted = {s.target for s in shots}
    for shot in shots:
        k = intrinsics(shot.lens.hfov, bl.cam.width, bl.cam.height)
        dist = float(np.linalg.norm(site.pose(site.placement(shot.target))[:3, 3] - shot.cam_pose[:3, 3]))
        far = min(shot.lens.far, dist + 15.0)  # beyond the target, its own tank hides the rest
        sun = shot.sun_dir if shot.sun_elevation > 0 else None
        wanted |= {it["tag"] for it in cull(spheres, shot.cam_pose, k, shot.lens.near, far, sun)}
    for tag in sorted(wanted):
        bl.load(tag)
    bl.load_terrain()  # the ground: shadows, bounce light, what the gauge glass reflects
    centres = [site.pose(site.placement(t))[:3, 3] for t in {s.target for s in shots}]
    poles = [p["tag"] for p in site.placements if p["asset"] == "lighting_pole" and p["asset"] in site.manifests
             and min(np.linalg.norm(np.array(p["enu"]) - c) for c in centres) < 120.0]
    bl.add_lamps(sorted(poles))


def _one(bl: _Blender, site: Site, shot: Shot, folder: Path, name: str, cam: PhoneCamera, lock) -> dict:
    """One frame; `lock` = (gain, white balance) of a locked exposure, or None to meter."""
    binding = _pointer_binding(site, shot.target)
    bl.set_shot(shot, binding)
    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    t0 = time.perf_counter()
    linear = bl.render()
    seconds = time.perf_counter() - t0
    if lock is None:
        gain, wb = metered_gain(linear, cam), metered_white_balance(linear, cam)
    else:
        gain, wb = lock[0], np.asarray(lock[1], float)
    view_axis = -shot.cam_pose[:3, 2]
    visible = shot.sun_elevation > 0 and bl.sun_visible(shot.cam_pose[:3, 3], shot.sun_dir)
    veil = veil_radiance(shot.sun_dir, view_axis, shot.dni, visible, cam)
    rgb = develop(linear, gain, veil, wb, cam)
    labels = frame_labels(shot, k, site, gain, veil, binding)
    labels["pointer_rows_px"] = bl.pointer_rows(shot.target, shot.cam_pose, k)
    labels["camera"]["white_balance"] = [float(v) for v in wb]
    labels["render_s"] = seconds
    labels["frame_s"] = time.perf_counter() - t0  # render + develop (ISP)
    digest = _write_png(folder / f"{name}.png", rgb)
    labels["image"] = f"{name}.png"
    labels["sha256"] = digest
    _write_json(folder / f"{name}.json", {k2: v for k2, v in labels.items() if k2 not in ("render_s", "frame_s")})
    return {"name": name, "image": f"{name}.png", "sha256": digest, "labels": labels, "rgb": rgb}


# --- scenarios ----------------------------------------------------------------------------------


def scenario_shots(scenario_path: Path, site: Site, every: int = 1) -> tuple[object, list[Shot]]:
    """Run the scenario's graph and turn each (every-th) step into a Shot: camera at the
    inspection point whose target is the placement the render node drives, looking at
    its main-tank gauge; zoom, sun and states from the graph's nodes."""
    from ..errors import UserError
    from . import graph, run

    scenario = graph.load_scenario(scenario_path, site.zone)
    observed = run.load_observed(site.build)
    data, records = run.simulate(scenario, observed)
    fed = sorted({vs.tag for frame in data.frames for vs in frame})
    if not fed:
        raise UserError(scenario.path, "edges", "the render node drives no built placement")
    target = fed[0]
    point = next((p for p in site.inspection.values() if p["target"] == target), None)
    if point is None:
        raise UserError(scenario.path, target, "no inspection point in site.toml targets this placement")
    centre, _ = dial_world(site.pose(site.placement(target)))
    pose = look_at(point["enu"], centre)
    cams = sorted(n["id"] for n in scenario.nodes if n["type"] == "camera")
    shots = []
    for i, (t, frame, rec) in enumerate(zip(data.times, data.frames, records)):
        if i % every:
            continue
        out = rec["outputs"]
        zoom = out.get(f"{cams[0]}.zoom", 1.0) if cams else 1.0
        el, az, irr = data.sun[i] if data.sun else (-1.0, 0.0, 0.0)
        states = {}
        for ob in observed:
            vals = {o.binding["variable"]: o.value for vs in frame if vs.tag == ob.tag for o in vs.outputs}
            if vals:
                states[ob.tag] = vals
        when = (scenario.start + dt.timedelta(seconds=t)).astimezone(scenario.zone)
        shots.append(Shot(when, pose, camera_model.lens(zoom), el, az, irr,
                          states, frame, target))
    return scenario, shots


def render_scenario(scenario_path, out, *, cam: PhoneCamera | None = None, every: int = 1,
                    sources: Path | None = None) -> Path:
    """`twin render SCENARIO`: frames, labels and a dataset manifest in
    out/runs/<scenario>/render/. Returns the manifest's path."""
    cam = cam or PhoneCamera()
    site = load_site(Path(out), sources)
    scenario, shots = scenario_shots(Path(scenario_path), site, every)
    folder = Path(out) / "runs" / scenario.name / "render"
    records = render_shots(site, shots, folder, cam=cam, seed=scenario.seed)
    return _dataset_manifest(folder, scenario.name, scenario.seed, cam, records)


def _dataset_manifest(folder: Path, name: str, seed: int, cam: PhoneCamera, records: list[dict]) -> Path:
    data = {"dataset": name, "seed": seed, "renderer": "blender-cycles-cpu", "camera": cam.__dict__,
            "frames": [{"image": r["image"], "labels": r["image"][:-4] + ".json", "sha256": r["sha256"],
                        "time": r["labels"]["time"]} for r in records]}
    _write_json(folder / "dataset.json", data)
    return folder / "dataset.json"


# --- the study ----------------------------------------------------------------------------------

STUDY_TARGET = "RE-B3"  # bank B faces ENE: its reader looks WSW, into the late sun
STUDY_ZOOM = 45.0
STUDY_DISTANCE_M = 25.0  # at 45x the 0.34 m dial spans about half of the frame's width
STUDY_MAX_OBLIQUITY = math.radians(45.0)  # beyond, the glass's Fresnel reflection hides the dial
# Local times (site.toml [site] timezone) on the site's date (sunrise ~05:40, sunset ~17:45): early night at the end of
# civil twilight, late afternoon 40 min before sunset. The sequence runs in a day's
# order from the first light in which the pointer is visible (the study's H_ref is its
# first image): morning, noon, late afternoon, then the three night conditions.
CONDITIONS = (("early_morning", "06:45"), ("solar_noon", None), ("late_afternoon", "17:05"),
              ("early_night", "18:05"), ("midnight", "23:59"), ("late_night", "04:00"))
LATE = "late_afternoon"


def study_times(site: Site) -> list[tuple[str, dt.datetime]]:
    import astral
    import astral.sun

    from ..errors import UserError

    if site.zone is None:
        raise UserError(site.build / "scene" / "placements.json", "timezone",
                        "the study's local times need the site's time zone: site.toml [site] timezone, then rebuild")
    date = dt.date.fromisoformat(site.date)
    noon = astral.sun.noon(astral.Observer(site.origin[0], site.origin[1]), date, tzinfo=site.zone)
    out = []
    for name, hhmm in CONDITIONS:
        if hhmm is None:
            out.append((name, noon.replace(microsecond=0)))
        else:
            h, m = map(int, hhmm.split(":"))
            out.append((name, config.local_time(dt.datetime.combine(date, dt.time(h, m)), site.zone)))
    return out


def _ray_hits_box(origin: np.ndarray, direction: np.ndarray, length: float, pose: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray) -> bool:
    """Does the segment origin + t direction, t in [0, length], cross the box [lo, hi]
    of the model at `pose` (slab test in the model frame)?"""
    o = pose[:3, :3].T @ (origin - pose[:3, 3])
    d = pose[:3, :3].T @ direction
    t0, t1 = 0.0, length
    for i in range(3):
        if abs(d[i]) < 1e-12:
            if o[i] < lo[i] or o[i] > hi[i]:
                return False
            continue
        a, b = (lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        if t0 > t1:
            return False
    return True


def _blocked(site: Site, origin: np.ndarray, direction: np.ndarray, length: float, skip: str = "") -> bool:
    """Does a built placement's bounding box (other than `skip`) cut the segment?"""
    for p in site.placements:
        m = site.manifests.get(p["asset"])
        if m is None or p["tag"] == skip or m.get("kind") == "terrain" or p["asset"].endswith("_terrain"):
            continue
        pose = site.pose(p)
        if np.linalg.norm(pose[:3, 3] - origin) > length + 40.0:
            continue
        if _ray_hits_box(origin, direction, length, pose, np.array(m["bounds"][0]), np.array(m["bounds"][1])):
            return True
    return False


def study_viewpoint(site: Site, late_sun: np.ndarray) -> np.ndarray:
    """The study's camera pose: STUDY_DISTANCE_M from the main-tank dial, at a phone's
    height (1.6 m above the reactor's level), turned from the dial's normal towards the
    late-afternoon sun as far as STUDY_MAX_OBLIQUITY allows, so that the low sun faces
    the lens as much as the dial's orientation permits, while the line of sight to the
    dial and the sun itself stay clear of the built models' bounding boxes (a sun hidden
    behind the reactor would make no glare)."""
    p = site.placement(STUDY_TARGET)
    centre, normal = dial_world(site.pose(p))
    candidates = []
    for a in np.linspace(-STUDY_MAX_OBLIQUITY, STUDY_MAX_OBLIQUITY, 91):
        c, s = math.cos(a), math.sin(a)
        u = np.array([c * normal[0] - s * normal[1], s * normal[0] + c * normal[1], 0.0])
        eye = centre + STUDY_DISTANCE_M * u
        eye[2] = p["enu"][2] + 1.6
        dist = float(np.linalg.norm(centre - eye))
        axis = (centre - eye) / dist
        if _blocked(site, eye, axis, dist - 1.0, skip=STUDY_TARGET):
            continue
        sun_clear = late_sun[2] > 0 and not _blocked(site, eye, late_sun, 300.0)
        candidates.append((sun_clear, float(axis @ late_sun), -abs(a), eye))
    if not candidates:
        raise RuntimeError(f"no clear view of {STUDY_TARGET}'s gauge from {STUDY_DISTANCE_M} m")
    best = max(candidates, key=lambda c: c[:3])
    return look_at(best[3], centre)


def study_shots(site: Site, *, tau_atm: float = sun_model.DEFAULT_TAU_ATM) -> list[tuple[str, Shot]]:
    """Six shots of the study (PAPER_NOTES.md): same camera, six instants; the tank level
    follows the study's leak trace over the sequence so H has something to follow."""
    times = study_times(site)
    lat, lon = site.origin[0], site.origin[1]
    suns = []
    for _, when in times:
        el, az = sun_model.ephemeris(lat, lon, when)
        e = math.radians(el)
        suns.append((e, math.radians(az), sun_model.irradiance(e, tau_atm)))
    late = next(sun_model.direction_enu(e, a) for (n, _), (e, a, _) in zip(times, suns) if n == LATE)
    pose = study_viewpoint(site, late)
    lens = camera_model.lens(STUDY_ZOOM)
    shots = []
    for i, ((name, when), (e, a, g)) in enumerate(zip(times, suns)):
        level = 100.0 - 12.0 * i  # 100, 88, ... 40 %: a slow leak between the conditions
        shots.append((name, _tank_shot(site, when, pose, lens, e, a, g, level)))
    return shots


def _tank_shot(site, when, pose, lens, e, a, g, level) -> Shot:
    from . import nodes

    p = site.placement(STUDY_TARGET)
    ob = nodes.Observed(p["tag"], p.get("state"), p["asset"], site.manifests[p["asset"]])
    values = {p.get("state"): {"oil_level_tank": level}}
    return Shot(when, pose, lens, e, a, g, {p["tag"]: {"oil_level_tank": level}},
                nodes.visual_states(values, [ob]), STUDY_TARGET)


def study_roi(record: dict) -> tuple[int, int, int, int]:
    """The fixed ROI: the dial's projected box (the same for every frame: one camera)."""
    x0, y0, x1, y1 = record["labels"]["gauges"]["gauge_tank"]["box"]
    return int(math.floor(x0)), int(math.floor(y0)), int(math.ceil(x1)), int(math.ceil(y1))


def face_only(bgr_crop: np.ndarray, site: Site, shot: Shot, cam: PhoneCamera, offset) -> np.ndarray:
    """The crop with everything outside the projected dial face set to a neutral grey
    (neither red, white nor dark for the H masks)."""
    import cv2

    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    uv = project(dial_outline(site.pose(site.placement(shot.target)), 64, FACE_RADIUS * 0.97), shot.cam_pose, k)
    poly = np.round(uv - np.asarray(offset, float)).astype(np.int32)
    mask = np.zeros(bgr_crop.shape[:2], np.uint8)
    cv2.fillPoly(mask, [poly], 1)
    out = bgr_crop.copy()
    out[mask == 0] = 128
    return out


def render_study(out, *, cam: PhoneCamera | None = None, sources: Path | None = None) -> Path:
    """`twin render --study`: the six conditions, metrics C, S, H on the gauge ROI,
    out/reports/study.html + study.json, frames in out/reports/study/."""
    cam = cam or PhoneCamera()
    out = Path(out)
    site = load_site(out, sources)
    shots = study_shots(site)
    folder = out / "reports" / "study"
    seed = 20250920
    rows = []
    h_ref = true_ref = None
    # One scene for the six conditions (loaded once, kept between frames); the phone
    # re-meters at each condition.
    records = render_shots(site, [s for _, s in shots], folder, cam=cam, seed=seed,
                           names=[n for n, _ in shots], meter_each=True)
    for (name, shot), rec in zip(shots, records):
        x0, y0, x1, y1 = study_roi(rec)
        crop = rec["rgb"][y0:y1, x0:x1, ::-1]
        m = measure(crop, face_only(crop, site, shot, cam, (x0, y0)))
        m["H"] = m["extent_px"] / h_ref if h_ref else 0.0
        if h_ref is None:
            h_ref = m["extent_px"] or None
            m["H"] = 1.0 if h_ref else 0.0
        lab = rec["labels"]
        rows_px = lab.get("pointer_rows_px")
        true_ref = true_ref or rows_px
        h_true = rows_px / true_ref if rows_px and true_ref else None
        rows.append({"condition": name, "time": lab["time"], "image": f"study/{rec['image']}",
                     "sun_elevation_deg": lab["sun"]["elevation_deg"], "sun_azimuth_deg": lab["sun"]["azimuth_deg"],
                     "irradiance_w_m2": lab["sun"]["irradiance_w_m2"], "oil_level_tank": lab["oil_levels"]["oil_level_tank"],
                     "exposure_gain": lab["camera"]["exposure_gain"], "veil": lab["camera"]["veil"],
                     "roi": [x0, y0, x1, y1], "C": m["C"], "S": m["S"], "H": m["H"], "H_true": h_true,
                     "render_s": lab["render_s"], "frame_s": lab["frame_s"]})
    report = {"target": STUDY_TARGET, "zoom": STUDY_ZOOM, "seed": seed, "h_ref_px": h_ref,
              "camera": cam.__dict__, "conditions": rows}
    (out / "reports").mkdir(parents=True, exist_ok=True)
    _write_json(out / "reports" / "study.json", report)
    (out / "reports" / "study.html").write_text(_study_html(report))
    return out / "reports" / "study.html"


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _study_html(report: dict) -> str:
    import html

    head = "<tr><th>condition</th><th>time</th><th>sun el / az (deg)</th><th>G (W/m2)</th><th>oil %</th>" \
           "<th>gain</th><th>C</th><th>S</th><th>H</th><th>H true</th><th>frame</th></tr>"
    rows = "".join(
        f"<tr><td>{html.escape(r['condition'])}</td><td>{html.escape(r['time'])}</td>"
        f"<td>{r['sun_elevation_deg']:.1f} / {r['sun_azimuth_deg']:.1f}</td><td>{r['irradiance_w_m2']:.0f}</td>"
        f"<td>{r['oil_level_tank']:.0f}</td><td>{r['exposure_gain']:.3g}</td><td>{r['C']:.3f}</td>"
        f"<td>{r['S']:.3f}</td><td>{r['H']:.2f}</td><td>{_fmt(r['H_true'])}</td><td><img src=\"{html.escape(r['image'])}\" width=\"240\"></td></tr>"
        for r in report["conditions"])
    return ("<!doctype html><html><head><meta charset=\"utf-8\"><title>Gauge study</title>"
            "<style>body{font-family:sans-serif}td,th{padding:4px 8px;border-bottom:1px solid #ccc}</style></head>"
            f"<body><h1>Main-tank gauge of {html.escape(report['target'])} at {report['zoom']:g}x: six conditions</h1>"
            "<p>C: RMS contrast, S: share of grey levels above 240, H: pointer extent / first frame's "
            f"(H_ref = {report['h_ref_px']} px), on the dial's fixed ROI; H true: the same ratio of the "
            "pointer's projected geometry (what H should read while the pointer is visible). Conditions in "
            "a day's order from the first light in which the pointer is visible.</p>"
            f"<table>{head}{rows}</table></body></html>\n")


# --- benchmark -----------------------------------------------------------------------------------


# _Blender renders at Blender's factory light paths; the peer and the reference differ
# from ours only in their samples and denoiser.
PEER_CAMERA = PhoneCamera(samples=16, render_denoise="")  # what one would try first: raw samples
REFERENCE_CAMERA = PhoneCamera(samples=256, render_denoise="")  # converged enough to stand for the truth


def frame_error(linear: np.ndarray, reference: np.ndarray, cam: PhoneCamera) -> float:
    """RMS difference in 8-bit sRGB levels between a frame and a converged reference,
    both developed with the reference's exposure and white balance and without the
    ISP's noise reduction: what the renderer gets wrong, before the phone hides it."""
    raw = PhoneCamera(denoise=0.0)
    gain, wb = metered_gain(reference, cam), metered_white_balance(reference, cam)
    a = develop(linear, gain, 0.0, wb, raw).astype(np.float64)
    b = develop(reference, gain, 0.0, wb, raw).astype(np.float64)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def bench_render(out="build", repeats: int = 5, threads: int | None = None, sources: Path | None = None,
                 setup: str = "ours", reference: Path | None = None) -> dict:
    """Seconds per 320x240 frame of the study's gauge close-up at solar noon: the scene is
    loaded once (load_s), then `repeats` frames re-render it (render_s: Cycles alone;
    frame_s: with the phone's develop).

    setup: "ours" (PhoneCamera's samples and denoiser), "blender_defaults" (the peer: 16
    raw samples) or "reference" (256 raw samples, saved to `reference` as .npy, timed
    once); all at Blender's factory light paths. With a saved `reference`, the frame's
    error against it is reported too (frame_error)."""
    site = load_site(Path(out), sources)
    cam = {"ours": PhoneCamera(), "blender_defaults": PEER_CAMERA, "reference": REFERENCE_CAMERA}[setup]
    shot = dict(study_shots(site))["solar_noon"]
    bl = _Blender(site, cam, 1)
    if threads:
        bl.scene.render.threads = threads
    if setup == "reference":
        repeats = 1
    try:
        t0 = time.perf_counter()
        _populate(bl, site, [shot])
        bl.set_shot(shot, _pointer_binding(site, shot.target))
        load_s = time.perf_counter() - t0
        times, frames = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            linear = bl.render()
            times.append(time.perf_counter() - t)
            develop(linear, metered_gain(linear, cam), 0.0, metered_white_balance(linear, cam), cam)
            frames.append(time.perf_counter() - t)
        import bpy

        objects = sum(o.type == "MESH" for o in bpy.data.objects)
        lights = sum(o.type == "LIGHT" for o in bpy.data.objects)
    finally:
        bl.close()
    result = {"frame": f"{cam.width}x{cam.height} {cam.samples} spp"
                       f"{' + OIDN ' + cam.render_denoise if cam.render_denoise else ''}, solar_noon, {STUDY_TARGET}",
              "setup": setup, "load_s": load_s, "loaded": sorted(t for t in bl.roots), "mesh_objects": objects,
              "lights": lights, "threads": threads or _Blender.THREADS, "samples": cam.samples,
              "render_denoise": cam.render_denoise, "median_s": statistics.median(times), "min_s": min(times),
              "max_s": max(times), "frame_median_s": statistics.median(frames), "repeats": repeats}
    if reference is not None:
        reference = Path(reference)
        if setup == "reference":
            np.save(reference, linear)
        else:
            result["rmse_8bit"] = frame_error(linear, np.load(reference), cam)
            result["reference"] = f"{REFERENCE_CAMERA.samples} spp, factory light paths, no denoiser"
    return result
