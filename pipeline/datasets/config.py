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

Read through `config.read_config` against schemas/dataset.schema.json (the keys, their
types, bounds and defaults), then checked for what a schema cannot say; every problem
is reported at once, each naming the file and the key: a config is user input.
"""

from __future__ import annotations

import datetime as dt
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

from .. import config
from ..errors import raise_all

# frames a dataset may hold: a run plans each frame it renders (17 ms on the sample,
# culling mostly) and renders it in 5 to 30 s, so a hundred thousand frames is weeks of
# rendering; a billion is a typo, refused before anything is planned
MAX_COUNT = 100_000


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


INSTANCE_KEYS = ("colour_jitter", "roughness_jitter", "dirt", "rust", "oil_stains", "weathering")
RANGE_KEYS = (*INSTANCE_KEYS, "exposure_ev", "vignetting")


@dataclass(frozen=True)
class CameraFamily:
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
    cameras: tuple[CameraFamily, ...]
    appearance: Appearance | None = None  # None: no [appearance] table, materials as imported
    digest: str = field(default="")  # sha256 of the file: what a resumed run must match


def load(path: str | Path) -> DatasetConfig:
    """Read a dataset config: every problem the schema (schemas/dataset.schema.json)
    or the checks after it find, at once, in one UserError naming the file and each key."""
    path = Path(path)
    data = config.read_config(path, "dataset")
    raise_all(path, _problems(data))
    head, sensor, cond, states = data["dataset"], data["sensor"], data["conditions"], data["states"]
    return DatasetConfig(
        path=path, name=head["name"], seed=head["seed"], count=head["count"],
        sensor=Sensor(**sensor),
        conditions=Conditions(tuple(dt.date.fromisoformat(d) for d in cond["dates"]),
                              tuple(dt.time.fromisoformat(x) for x in cond["local_time"]),
                              _pair(cond["tau_atm"]), _pair(cond["aerosol"])),
        states=States(_pair(states["oil_level"]), float(states["switch_open"])),
        cameras=tuple(_camera(c) for c in data["cameras"]),
        appearance=_appearance(data["appearance"]) if "appearance" in data else None,
        digest=hashlib.sha256(path.read_bytes()).hexdigest())


def _problems(data: dict) -> list[tuple[str, str]]:
    """What the schema cannot say: the count's bound (a message that says why), real
    dates and times, a window within one day, every range [lo, hi] in order."""
    out = []
    count = data["dataset"]["count"]
    if count > MAX_COUNT:
        out.append(("dataset.count", f"{count:,} frames: a dataset holds at most {MAX_COUNT:,} (each takes seconds "
                                     "to render): split it into datasets of their own, with other seeds"))
    cond = data["conditions"]
    for i, d in enumerate(cond["dates"]):
        try:
            dt.date.fromisoformat(d)
        except ValueError:
            out.append((f"conditions.dates[{i}]", f"{d!r} is not a date (YYYY-MM-DD)"))
    times = []
    for i, x in enumerate(cond["local_time"]):
        try:
            times.append(dt.time.fromisoformat(x))
        except ValueError:
            out.append((f"conditions.local_time[{i}]", f"{x!r} is not a local time HH:MM"))
    if len(times) == 2 and times[0] > times[1]:
        out.append(("conditions.local_time", "the window must not wrap past midnight"))
    ranges = [("conditions.tau_atm", cond["tau_atm"]), ("conditions.aerosol", cond["aerosol"]),
              ("states.oil_level", data["states"]["oil_level"])]
    ranges += [(f"cameras[{i}].zoom", c["zoom"]) for i, c in enumerate(data["cameras"])]
    look = data.get("appearance")
    if look is not None:
        ranges += [(f"appearance.{k}", look[k]) for k in RANGE_KEYS]
        if sum(look["sky"].values()) <= 0:
            out.append(("appearance.sky", "the weights sum to 0: give at least one sky a weight above 0"))
    for key, value in ranges:
        lo, hi = _pair(value)
        if lo > hi:
            out.append((key, f"[{lo:g}, {hi:g}]: a range [lo, hi] must be in order"))
    return out


def _pair(value) -> tuple[float, float]:
    """A range as the schema allows it: one number (lo = hi) or [lo, hi]."""
    lo, hi = (value, value) if isinstance(value, (int, float)) else value
    return float(lo), float(hi)


def _appearance(t: dict) -> Appearance:
    return Appearance(**{k: _pair(t[k]) for k in RANGE_KEYS},
                      sky=tuple((kind, float(t["sky"][kind])) for kind in sorted(t["sky"])))


def _camera(t: dict) -> CameraFamily:
    common = dict(kind=t["kind"], weight=float(t["weight"]), zoom=_pair(t["zoom"]))
    if t["kind"] == "inspection_point":
        return CameraFamily(**common, points=tuple(t["points"]))
    if t["kind"] == "route":
        return CameraFamily(**common, path=tuple((float(x), float(y)) for x, y in t["path"]), level=t["level"],
                            height=float(t["height"]), look_at=tuple(t["look_at"]), reach_m=float(t["reach_m"]))
    return CameraFamily(**common, mast=t["mast"],
                        presets=tuple((p["target"], float(p["zoom"])) for p in t["presets"]))
