"""A dataset config (sources/datasets/*.toml) as plain data: where the cameras stand,
what conditions and equipment states to sample, how many frames, and the seed.

    [dataset]    name, seed, count
    [sensor]     width, height, samples, render_denoise, tasks_per_worker
    [conditions] dates, local_time = [from, to], tau_atm = [lo, hi], aerosol = [lo, hi]
    [states]     oil_level = [lo, hi] (%), switch_open = probability
    [appearance] per instance: colour_jitter, roughness_jitter, dirt, rust, oil_stains,
                 weathering = [lo, hi]; per frame: sky = {clear, overcast, hazy} weights,
                 exposure_ev = [lo, hi], vignetting = [lo, hi] (optional: without it
                 every piece of equipment looks as its package made it)
    [[cameras]]  kind = "inspection_point" | "route" | "ptz", weight, zoom = [lo, hi], ...

Every error names the file and the key: a config is user input.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import UserError
from ..runtime import camera as camera_model

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
# frames a dataset may hold: a run plans its frames before the first render (the scene
# a worker loads is what they see), 17 ms each on the sample (culling, mostly), and
# renders one in 5 to 30 s: a hundred thousand is half an hour of planning ahead of
# weeks of rendering; a billion would be 200 days of planning before anything shows
MAX_COUNT = 100_000
KINDS = ("inspection_point", "route", "ptz")


@dataclass(frozen=True)
class Sensor:
    width: int = 640
    height: int = 480
    samples: int = 4
    render_denoise: str = "BALANCED"
    tasks_per_worker: int = 200  # frames a worker renders before it is replaced (memory)


@dataclass(frozen=True)
class Conditions:
    dates: tuple[dt.date, ...]
    local_time: tuple[dt.time, dt.time]
    tau_atm: tuple[float, float] = (0.2, 0.2)
    aerosol: tuple[float, float] = (1.0, 1.0)  # Cycles' sky aerosol (dust) density


@dataclass(frozen=True)
class States:
    oil_level: tuple[float, float] = (100.0, 100.0)
    switch_open: float = 0.0


@dataclass(frozen=True)
class Appearance:
    """How equipment and skies vary, drawn per frame (plan.py). Per instance:
    colour_jitter scales each base colour channel by 1 + U(-j, j); roughness_jitter adds
    U(-j, j) to roughness; dirt, rust, oil_stains, weathering: each an amount in 0..1
    drawn from its range (procedural masks in the materials, render/appearance.py).
    Per frame: a sky kind from the weights (overcast dims the sun behind cloud and
    greys the sky, hazy thickens the aerosol), an exposure compensation in EV on the
    metered gain, and the lens's vignetting (the corners' light lost, 0..0.6)."""

    colour_jitter: tuple[float, float] = (0.0, 0.0)
    roughness_jitter: tuple[float, float] = (0.0, 0.0)
    dirt: tuple[float, float] = (0.0, 0.0)
    rust: tuple[float, float] = (0.0, 0.0)
    oil_stains: tuple[float, float] = (0.0, 0.0)
    weathering: tuple[float, float] = (0.0, 0.0)
    sky: tuple[tuple[str, float], ...] = (("clear", 1.0),)
    exposure_ev: tuple[float, float] = (0.0, 0.0)
    vignetting: tuple[float, float] = (0.0, 0.0)


SKIES = ("clear", "overcast", "hazy")
INSTANCE_KEYS = ("colour_jitter", "roughness_jitter", "dirt", "rust", "oil_stains", "weathering")


@dataclass(frozen=True)
class Camera:
    """One camera family. inspection_point: `points` (site.toml names; all when empty)
    looking at their targets. route: a polyline `path` of plan (x, y) on `level`,
    `height` above it, looking at the nearest placement of `look_at` assets within
    `reach_m` (ahead along the path when none). ptz: the mast placement `mast`, each
    preset a target tag and a zoom."""

    kind: str
    weight: float = 1.0
    zoom: tuple[float, float] = (1.0, 1.0)
    points: tuple[str, ...] = ()
    path: tuple[tuple[float, float], ...] = ()
    level: str = ""
    height: float = 1.6
    look_at: tuple[str, ...] = ()
    reach_m: float = 30.0
    mast: str = ""
    presets: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class DatasetConfig:
    path: Path
    name: str
    seed: int
    count: int
    sensor: Sensor
    conditions: Conditions
    states: States
    cameras: tuple[Camera, ...]
    appearance: Appearance | None = None  # None: no [appearance] table, materials as imported
    digest: str = field(default="")  # sha256 of the file: what a resumed run must match


def load(path: str | Path) -> DatasetConfig:
    path = Path(path)
    try:
        raw = path.read_bytes()
        data = tomllib.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise UserError(path, None, "no such dataset config") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise UserError(path, None, f"not a TOML file: {e}") from None
    r = _Reader(path)
    head = r.table(data, "dataset")
    name = r.text(head, "dataset.name")
    if not NAME.match(name):
        raise UserError(path, "dataset.name", f"{name!r}: letters, digits, '_', '.', '-' (a folder name)")
    cams = data.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise UserError(path, "cameras", "at least one [[cameras]] table")
    return DatasetConfig(
        path=path, name=name, seed=r.integer(head, "dataset.seed"),
        count=_count(r, head),
        sensor=_sensor(r, data.get("sensor", {})), conditions=_conditions(r, r.table(data, "conditions")),
        states=_states(r, data.get("states", {})),
        cameras=tuple(_camera(r, c, f"cameras[{i}]") for i, c in enumerate(cams)),
        appearance=_appearance(r, data["appearance"]) if "appearance" in data else None,
        digest=hashlib.sha256(raw).hexdigest())


def _count(r: "_Reader", head: dict) -> int:
    count = r.integer(head, "dataset.count", lo=1)
    if count > MAX_COUNT:
        raise UserError(r.path, "dataset.count", f"{count:,} frames: a dataset holds at most {MAX_COUNT:,} (a run "
                                                 "plans its frames before the first render, and each takes seconds "
                                                 "to render): split it into datasets of their own, with other seeds")
    return count


def _sensor(r: "_Reader", t: dict) -> Sensor:
    d = Sensor()
    denoise = t.get("render_denoise", d.render_denoise)
    if denoise not in ("", "FAST", "BALANCED", "HIGH"):
        raise UserError(r.path, "sensor.render_denoise", f"{denoise!r}: one of '', FAST, BALANCED, HIGH")
    return Sensor(width=r.integer(t, "sensor.width", d.width, lo=16, hi=8192),
                  height=r.integer(t, "sensor.height", d.height, lo=16, hi=8192),
                  samples=r.integer(t, "sensor.samples", d.samples, lo=1, hi=4096), render_denoise=denoise,
                  tasks_per_worker=r.integer(t, "sensor.tasks_per_worker", d.tasks_per_worker, lo=1))


def _conditions(r: "_Reader", t: dict) -> Conditions:
    dates = t.get("dates")
    if not isinstance(dates, list) or not dates:
        raise UserError(r.path, "conditions.dates", "a list of dates, e.g. [\"2025-03-20\"]")
    parsed = []
    for i, d in enumerate(dates):
        try:
            parsed.append(d if isinstance(d, dt.date) else dt.date.fromisoformat(str(d)))
        except ValueError:
            raise UserError(r.path, f"conditions.dates[{i}]", f"{d!r} is not a date (YYYY-MM-DD)") from None
    times = r.pair(t, "conditions.local_time", None, kind=str)
    try:
        window = tuple(dt.time.fromisoformat(x) for x in times)
    except ValueError:
        raise UserError(r.path, "conditions.local_time", f"{times!r}: two local times HH:MM") from None
    if window[0] > window[1]:
        raise UserError(r.path, "conditions.local_time", "the window must not wrap past midnight")
    return Conditions(tuple(parsed), window, r.pair(t, "conditions.tau_atm", (0.2, 0.2), lo=0.0, hi=5.0),
                      r.pair(t, "conditions.aerosol", (1.0, 1.0), lo=0.0, hi=10.0))


def _states(r: "_Reader", t: dict) -> States:
    return States(r.pair(t, "states.oil_level", (100.0, 100.0), lo=0.0, hi=100.0),
                  r.number(t, "states.switch_open", 0.0, lo=0.0, hi=1.0))


def _appearance(r: "_Reader", t) -> Appearance:
    if not isinstance(t, dict):
        raise UserError(r.path, "appearance", "a [appearance] table")
    known = set(INSTANCE_KEYS) | {"sky", "exposure_ev", "vignetting"}
    for k in t:
        if k not in known:
            raise UserError(r.path, f"appearance.{k}", f"unknown key: one of {', '.join(sorted(known))}")
    ranges = {k: r.pair(t, f"appearance.{k}", (0.0, 0.0), lo=0.0, hi=1.0) for k in INSTANCE_KEYS}
    sky = t.get("sky", {"clear": 1.0})
    if not isinstance(sky, dict) or not sky:
        raise UserError(r.path, "appearance.sky", "a table of weights, e.g. {clear = 2, overcast = 1, hazy = 1}")
    weights = []
    for kind in sorted(sky):
        if kind not in SKIES:
            raise UserError(r.path, f"appearance.sky.{kind}", f"one of {', '.join(SKIES)}")
        weights.append((kind, r.number(sky, f"appearance.sky.{kind}", lo=0.0)))
    if sum(w for _, w in weights) <= 0:
        raise UserError(r.path, "appearance.sky", "the weights sum to 0")
    return Appearance(**ranges, sky=tuple(weights),
                      exposure_ev=r.pair(t, "appearance.exposure_ev", (0.0, 0.0), lo=-4.0, hi=4.0),
                      vignetting=r.pair(t, "appearance.vignetting", (0.0, 0.0), lo=0.0, hi=0.6))


def _camera(r: "_Reader", t: dict, key: str) -> Camera:
    if not isinstance(t, dict):
        raise UserError(r.path, key, "a table")
    kind = t.get("kind")
    if kind not in KINDS:
        raise UserError(r.path, f"{key}.kind", f"{kind!r}: one of {', '.join(KINDS)}")
    zoom = r.pair(t, f"{key}.zoom", (1.0, 1.0), lo=camera_model.ZOOM_MIN, hi=camera_model.ZOOM_MAX)
    common = dict(kind=kind, weight=r.number(t, f"{key}.weight", 1.0, lo=0.0), zoom=zoom)
    if kind == "inspection_point":
        points = t.get("points", [])
        if not isinstance(points, list) or not all(isinstance(p, str) for p in points):
            raise UserError(r.path, f"{key}.points", "a list of site.toml inspection point names")
        return Camera(**common, points=tuple(points))
    if kind == "route":
        path = t.get("path")
        if (not isinstance(path, list) or len(path) < 2
                or not all(isinstance(p, list) and len(p) == 2 and all(_is_number(v) for v in p) for p in path)):
            raise UserError(r.path, f"{key}.path", "a polyline of at least two plan points [x, y] (m)")
        look = t.get("look_at", [])
        if not isinstance(look, list) or not all(isinstance(a, str) for a in look):
            raise UserError(r.path, f"{key}.look_at", "a list of asset names")
        return Camera(**common, path=tuple((float(x), float(y)) for x, y in path), level=r.text(t, f"{key}.level"),
                      height=r.number(t, f"{key}.height", 1.6, lo=0.1, hi=50.0), look_at=tuple(look),
                      reach_m=r.number(t, f"{key}.reach_m", 30.0, lo=1.0))
    presets = t.get("presets")
    if not isinstance(presets, list) or not presets:
        raise UserError(r.path, f"{key}.presets", "a list of {target = TAG, zoom = Z}")
    out = []
    for i, p in enumerate(presets):
        pk = f"{key}.presets[{i}]"
        if not isinstance(p, dict):
            raise UserError(r.path, pk, "a table {target = TAG, zoom = Z}")
        out.append((r.text(p, f"{pk}.target"),
                    r.number(p, f"{pk}.zoom", 1.0, lo=camera_model.ZOOM_MIN, hi=camera_model.ZOOM_MAX)))
    return Camera(**common, mast=r.text(t, f"{key}.mast"), presets=tuple(out))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class _Reader:
    """Typed reads of one file's tables, each failure one UserError naming the key."""

    def __init__(self, path: Path):
        self.path = path

    @staticmethod
    def _leaf(key: str) -> str:
        return key.rsplit(".", 1)[-1]

    def table(self, data: dict, key: str) -> dict:
        t = data.get(key)
        if not isinstance(t, dict):
            raise UserError(self.path, key, f"a [{key}] table")
        return t

    def text(self, t: dict, key: str) -> str:
        v = t.get(self._leaf(key))
        if not isinstance(v, str) or not v:
            raise UserError(self.path, key, "a non-empty string")
        return v

    def integer(self, t: dict, key: str, default=None, lo=None, hi=None) -> int:
        v = t.get(self._leaf(key), default)
        if not isinstance(v, int) or isinstance(v, bool):
            raise UserError(self.path, key, f"{v!r} is not an integer")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise UserError(self.path, key, f"{v} is outside [{lo}, {hi}]")
        return v

    def number(self, t: dict, key: str, default=None, lo=None, hi=None) -> float:
        v = t.get(self._leaf(key), default)
        if not _is_number(v) or v != v:
            raise UserError(self.path, key, f"{v!r} is not a number")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise UserError(self.path, key, f"{v} is outside [{lo}, {hi}]")
        return float(v)

    def pair(self, t: dict, key: str, default, lo=None, hi=None, kind=float) -> tuple:
        v = t.get(self._leaf(key), default)
        if _is_number(v) and kind is float:
            v = [v, v]
        ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(
            (_is_number(x) and x == x) if kind is float else isinstance(x, kind) for x in v)
        if not ok:
            raise UserError(self.path, key, f"{v!r}: two values [from, to]")
        if kind is not float:
            return tuple(v)
        a, b = float(v[0]), float(v[1])
        if a > b or (lo is not None and a < lo) or (hi is not None and b > hi):
            raise UserError(self.path, key, f"[{a:g}, {b:g}] must be ordered and within [{lo}, {hi}]")
        return a, b
