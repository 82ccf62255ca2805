"""site.toml, asset.toml and scenario loading, validated against schemas/.

Every failure is a `UserError` naming the file and the key (e.g. `plan.crs`).
Defaults live in the JSON Schemas and are filled in here, so the schema is the one
place that documents them.

The loaders take an optional `PassedChecks`: keys (content hashes) of checks that
passed before, which they skip, and of those they pass. The planner keeps it in the
build folder, so a no-op build neither imports jsonschema and pyproj nor runs their
checks again on content they already passed.
"""

from __future__ import annotations

import copy
import datetime as dt
import fnmatch
import json
import math
import tomllib
import zoneinfo
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from .digest import sha256_json
from .errors import UserError, raise_all, read_input

SCHEMA_DIR = Path(__file__).resolve().parent.parent / "schemas"


@lru_cache(maxsize=None)
def schema(name: str) -> dict:
    return json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text())


def read_toml(path: Path) -> dict:
    path = Path(path)
    raw = read_input(path)
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise UserError(path, None, "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as e:
        raise UserError(path, None, f"TOML syntax error: {e}") from None


def read_config(path: Path, schema_name: str) -> dict:
    """A TOML config checked against schemas/<schema_name>.schema.json, with the
    schema's defaults filled in: every violation and every number that is not finite,
    at once, in one UserError (each naming its key). What a schema cannot say (an
    order, a real date, a name another key must use) the caller checks after."""
    path = Path(path)
    data = read_toml(path)
    problems = schema_problems(data, schema_name)
    problems += [(key, "not a finite number") for key, value in _numbers(data) if not math.isfinite(value)]
    raise_all(path, problems)
    return _defaults(schema(schema_name), data)


def _key_path(error) -> str:
    """`error`: a jsonschema.ValidationError."""
    parts = []
    for p in error.absolute_path:
        parts.append(f"[{p}]" if isinstance(p, int) else (("." if parts else "") + str(p)))
    return "".join(parts) or "(top level)"


class PassedChecks:
    """Keys of checks that passed: `known` from before, `met` by this load (the
    ones worth keeping: a key of a file since edited is not met again)."""

    def __init__(self, known=()):
        self.known, self.met = set(known), set()

    def __contains__(self, key: str) -> bool:
        if key in self.known:
            self.met.add(key)
            return True
        return False

    def add(self, key: str) -> None:
        self.known.add(key)
        self.met.add(key)


def validate(data: dict, schema_name: str, path: Path, passed: PassedChecks | None = None) -> None:
    """Raise one UserError holding every schema violation, each naming its key, in
    key order. `passed`: see the module's docstring."""
    key = sha256_json(["schema", schema(schema_name), data]) if passed is not None else None
    if key is not None and key in passed:
        return
    problems = schema_problems(data, schema_name)
    raise_all(path, problems)
    if key is not None:
        passed.add(key)


def schema_problems(data: dict, schema_name: str) -> list[tuple[str, str]]:
    """(key, what is wrong) of every violation of schemas/<schema_name>.schema.json."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(schema(schema_name))
    errors = sorted(validator.iter_errors(data), key=lambda e: (list(map(str, e.absolute_path)), e.message))
    return list(dict.fromkeys(p for e in errors for p in _problems(e)))


def _problems(e) -> list[tuple[str, str]]:
    """A jsonschema.ValidationError as (key, message) problems: a missing or unknown
    key is named itself; of alternatives (anyOf: a number or a pair), the violation
    of the one whose type the value has."""
    where = _key_path(e)
    within = (lambda k: k) if where == "(top level)" else (lambda k: f"{where}.{k}")
    if e.validator == "required":
        missing = e.message.split("'")[1] if "'" in e.message else e.message
        described = e.schema.get("properties", {}).get(missing, {}).get("description")
        return [(within(missing), "missing required key" + (f" ({described})" if described else ""))]
    if e.validator == "additionalProperties":
        known = e.schema.get("properties", {})
        return [(within(k), f"unknown key (known: {', '.join(sorted(known))})") for k in sorted(e.instance)
                if k not in known]
    context = e.context or ()
    other_type = {c.schema_path[0] for c in context if c.validator == "type"}  # the alternatives of another type
    typed = [c for c in context if c.validator != "type" and c.schema_path[0] not in other_type] or \
        [c for c in context if c.validator != "type"]
    if typed:
        return [p for c in typed for p in _problems(c)]
    described = e.schema.get("description") if e.validator == "pattern" else None  # a regex says little
    return [(where, e.message + (f" ({described})" if described else ""))]


def _defaults(node_schema: dict, data: Any) -> Any:
    """Fill schema defaults into `data` (objects only; arrays of objects recursively)."""
    if node_schema.get("type") == "object" and isinstance(data, dict):
        for key, sub in node_schema.get("properties", {}).items():
            if key not in data and "default" in sub:
                data[key] = copy.deepcopy(sub["default"])  # never the cached schema's own object
            if key in data:
                data[key] = _defaults(sub, data[key])
    elif node_schema.get("type") == "array" and isinstance(data, list) and "items" in node_schema:
        data = [_defaults(node_schema["items"], d) for d in data]
    return data


# --- site.toml -----------------------------------------------------------------


@dataclass(frozen=True)
class Level:
    name: str
    elevation: float


@dataclass(frozen=True)
class InspectionPoint:
    name: str
    position: tuple[float, float, float]
    level: str
    target: str | None = None


@dataclass(frozen=True)
class FloorplanOptions:
    """How the floor plan is read: [floorplan] and [plan] units of site.toml.

    blocks: (block name or fnmatch pattern, asset id) pairs in the order written.
    units: the drawing's length unit when site.toml names one (else $INSUNITS).
    """

    blocks: tuple[tuple[str, str], ...] = ()
    tag_attribute: str = "TAG"
    level_attribute: str = "LEVEL"
    state_attribute: str = "STATE"
    default_level: str | None = None
    insert_scale: str = "ignore"
    units: str | None = None
    max_placements: int = 100_000  # more from the drawing's INSERTs is refused before expanding them
    conductor_layers: tuple[str, ...] = ()  # upper case: their LINEs are conductors ([wiring] layers), not ignored


@dataclass(frozen=True)
class Site:
    """site.toml, validated, with defaults filled in. `path` is the file itself."""

    path: Path
    name: str
    crs: str
    grid_origin: tuple[float, float]
    grid_rotation_deg: float
    grid_scale: float
    origin: tuple[float, float, float] | None  # lat, lon, height; None: platform centre
    levels: tuple[Level, ...]
    slope_ratio: float
    natural_ground: float
    skirt_width: float
    screen_tolerance_px: float
    reference_hfov_rad: float
    reference_width_px: int
    inspection_points: tuple[InspectionPoint, ...]
    timezone: str  # IANA name: every local time of the site is in this zone
    floorplan: str = "floorplan/substation.dxf"
    date: str = "2025-03-20"
    description: str = ""
    floorplan_options: FloorplanOptions = FloorplanOptions()
    # [gazebo] moving_parts: "auto" (all within the world's parse budget, else none), "all"
    # (the switches' joints move in the world), "none" (drawn at rest), or tag patterns
    # (the switches that move): moves_in_gazebo
    moving_parts: str | tuple[str, ...] = "auto"
    raw: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def root(self) -> Path:
        return self.path.parent

    def level(self, name: str) -> Level:
        for lv in self.levels:
            if lv.name == name:
                return lv
        raise KeyError(name)

    @property
    def level_names(self) -> tuple[str, ...]:
        return tuple(lv.name for lv in self.levels)

    @property
    def zone(self) -> zoneinfo.ZoneInfo:
        return zoneinfo.ZoneInfo(self.timezone)


def terrain_model_name(site: Site) -> str:
    """The terrain package's model name (a scene output and a task's output folder)."""
    return f"{site.name.lower().replace('-', '_').replace('.', '_')}_terrain"


def check_crs(code: str, path: Path, key: str, passed: PassedChecks | None = None) -> None:
    known = sha256_json(["projected crs", code])
    if passed is not None and known in passed:
        return
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(code)
    except CRSError:
        raise UserError(path, key, f"unknown CRS {code!r} (no such EPSG code)") from None
    if not crs.is_projected:
        raise UserError(path, key, f"{code} ({crs.name}) is not a projected CRS")
    if passed is not None:
        passed.add(known)


def time_zone(name: str, path: Path, key: str) -> zoneinfo.ZoneInfo:
    """The IANA zone `name` from the system's tz database; a UserError naming the file
    and key when there is no such zone (or no database at all)."""
    try:
        return zoneinfo.ZoneInfo(name)
    except (zoneinfo.ZoneInfoNotFoundError, ValueError):
        pass
    if not zoneinfo.available_timezones():
        raise UserError(path, key, f"no time zone database to look up {name!r} in: apt-get install tzdata "
                                   "(or pip install tzdata)") from None
    raise UserError(path, key, f"unknown time zone {name!r}: an IANA name is expected, e.g. "
                               "\"America/Bahia\", \"Asia/Shanghai\", \"Europe/Berlin\" or \"UTC\"") from None


def local_time(wall: dt.datetime, zone: dt.tzinfo) -> dt.datetime:
    """The aware instant of the naive wall-clock time `wall` in `zone`. ValueError for
    a wall time the zone skips (clocks put forward) or shows twice (clocks put back):
    either needs its UTC offset written out."""
    first, second = wall.replace(tzinfo=zone, fold=0), wall.replace(tzinfo=zone, fold=1)
    if first.astimezone(dt.timezone.utc).astimezone(zone).replace(tzinfo=None) != wall:
        raise ValueError(f"{wall.isoformat()} does not exist in {zone} (the clocks skip it)")
    if first.utcoffset() != second.utcoffset():
        raise ValueError(f"{wall.isoformat()} happens twice in {zone}: write its UTC offset, "
                         f"{first.isoformat()} or {second.isoformat()}")
    return first


def load_site(path: Path, passed: PassedChecks | None = None) -> Site:
    path = Path(path)
    data = read_toml(path)
    validate(data, "site", path, passed)
    data = _defaults(schema("site"), data)
    check_crs(data["plan"]["crs"], path, "plan.crs", passed)
    time_zone(data["site"]["timezone"], path, "site.timezone")

    names = [lv["name"] for lv in data["levels"]]
    for i, n in enumerate(names):
        if names.index(n) != i:
            raise UserError(path, f"levels[{i}].name", f"duplicate level {n!r}")
    for i, p in enumerate(data.get("inspection_points", [])):
        if p["level"] not in names:
            raise UserError(path, f"inspection_points[{i}].level", f"level {p['level']!r} is not defined in [[levels]]")
    for key, value in _numbers(data):
        if not math.isfinite(value):
            raise UserError(path, key, "not a finite number")
    default_level = data.get("floorplan", {}).get("default_level")
    if default_level is not None and default_level not in names:
        raise UserError(path, "floorplan.default_level", f"level {default_level!r} is not defined in [[levels]]")

    levels = tuple(Level(lv["name"], float(lv["elevation"])) for lv in data["levels"])
    terrain = data.get("terrain", _defaults(schema("site")["properties"]["terrain"], {}))
    lod = data.get("lod", _defaults(schema("site")["properties"]["lod"], {}))
    origin = data.get("origin")
    return Site(
        path=path,
        name=data["site"]["name"],
        description=data["site"].get("description", ""),
        floorplan=data["site"]["floorplan"],
        date=data["site"]["date"],
        timezone=data["site"]["timezone"],
        crs=data["plan"]["crs"],
        grid_origin=tuple(float(v) for v in data["plan"]["grid_origin"]),
        grid_rotation_deg=float(data["plan"]["grid_rotation_deg"]),
        grid_scale=float(data["plan"]["grid_scale"]),
        origin=None if origin is None else (float(origin["lat"]), float(origin["lon"]), float(origin["height"])),
        levels=levels,
        slope_ratio=float(terrain["slope_ratio"]),
        natural_ground=float(terrain.get("natural_ground", min(lv.elevation for lv in levels) - 2.0)),
        skirt_width=float(terrain["skirt_width"]),
        screen_tolerance_px=float(lod["screen_tolerance_px"]),
        reference_hfov_rad=float(lod["reference_hfov_rad"]),
        reference_width_px=int(lod["reference_width_px"]),
        inspection_points=tuple(
            InspectionPoint(p["name"], tuple(float(v) for v in p["position"]), p["level"], p.get("target"))
            for p in data.get("inspection_points", [])
        ),
        floorplan_options=_floorplan_options(data, path),
        moving_parts=moving_parts_setting(
            data.get("gazebo", _defaults(schema("site")["properties"]["gazebo"], {}))["moving_parts"]),
        raw=data,
    )


def moving_parts_setting(value: str | list[str]) -> str | tuple[str, ...]:
    """[gazebo] moving_parts as site.toml or placements.json holds it: "all", "none", or
    its tag patterns as a tuple."""
    return value if isinstance(value, str) else tuple(value)


def moves_in_gazebo(moving_parts: str | tuple[str, ...], tag: str) -> bool:
    """Whether placement `tag`'s moving links hang on joints in the Gazebo world: under
    "all", under "none" never, else when the tag matches one of the patterns
    (fnmatchcase: `*`, `?` and `[...]`, case-sensitive as tags are). "auto" is decided
    by the scene (scene.world_sdf.write_within_budget), which records what it chose."""
    if moving_parts == "auto":
        raise ValueError('moving_parts "auto" is the scene\'s to decide: ask what it recorded')
    if isinstance(moving_parts, str):
        return moving_parts == "all"
    return any(fnmatch.fnmatchcase(tag, pattern) for pattern in moving_parts)


def _floorplan_options(data: dict, path: Path) -> FloorplanOptions:
    fp = data.get("floorplan", _defaults(schema("site")["properties"]["floorplan"], {}))
    attributes = fp.get("attributes") or _defaults(schema("site")["properties"]["floorplan"]["properties"]["attributes"], {})
    return FloorplanOptions(
        blocks=tuple((str(k), str(v)) for k, v in fp.get("blocks", {}).items()),
        tag_attribute=attributes["tag"],
        level_attribute=attributes["level"],
        state_attribute=attributes["state"],
        default_level=fp.get("default_level"),
        insert_scale=fp["insert_scale"],
        units=data["plan"].get("units"),
        max_placements=int(fp["max_placements"]),
        conductor_layers=tuple(sorted({lay["layer"].upper() for lay in data.get("wiring", {}).get("layers", [])})),
    )


def _numbers(data: Any, prefix: str = ""):
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _numbers(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from _numbers(v, f"{prefix}[{i}]")
    elif isinstance(data, float):
        yield prefix, data


# --- asset.toml ----------------------------------------------------------------


@dataclass(frozen=True)
class AssetConfig:
    """asset.toml of sources/assets/<id>/, validated, with defaults filled in.

    units, up_axis: None when asset.toml leaves them to the source file (the readers
    take the file's own); scale multiplies after units."""

    path: Path
    id: str
    category: str
    description: str
    source: Path
    units: str | None
    up_axis: str | None
    tessellation_tolerance_m: float
    triangle_budget: int
    mass_kg: float
    lod_budgets_m: tuple[float, ...]
    collision_mode: str
    bindings: tuple[dict, ...]
    scale: float = 1.0
    tessellation_max_triangles: int = 1_000_000
    terminals: tuple[tuple[str, tuple[float, float, float]], ...] = ()  # conductor attachment points, model frame
    raw: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def folder(self) -> Path:
        return self.path.parent

    @property
    def params(self) -> dict:
        """Everything in asset.toml that affects the build, as plain JSON data."""
        return self.raw


SAFE_ID = r"^[a-z0-9][a-z0-9_]*$"


def load_asset_config(path: Path, passed: PassedChecks | None = None) -> AssetConfig:
    import re

    path = Path(path)
    asset_id = path.parent.name
    if not re.match(SAFE_ID, asset_id):
        raise UserError(path.parent, asset_id, "asset id must be lower-case letters, digits and _")
    data = read_toml(path)
    validate(data, "asset", path, passed)
    data = _defaults(schema("asset"), data)
    for key, value in _numbers(data):
        if not math.isfinite(value):
            raise UserError(path, key, "not a finite number")
    budgets = tuple(float(b) for b in data.get("lod", {}).get("budgets_m", [0.005, 0.02, 0.08]))
    if list(budgets) != sorted(budgets):
        raise UserError(path, "lod.budgets_m", "budgets must ascend (LOD1 finest)")
    terminals = tuple((t["name"], tuple(float(v) for v in t["position"])) for t in data.get("terminals", []))
    names = [n for n, _ in terminals]
    for i, n in enumerate(names):
        if names.index(n) != i:
            raise UserError(path, f"terminals[{i}].name", f"duplicate terminal {n!r}")
    source = path.parent / data["source"]
    if not source.is_file():
        raise UserError(path, "source", f"source file {data['source']!r} not found in {path.parent}")
    return AssetConfig(
        path=path,
        id=asset_id,
        category=data["category"],
        description=data.get("description", ""),
        source=source,
        units=data.get("units"),
        up_axis=data.get("up_axis"),
        scale=float(data["scale"]),
        tessellation_tolerance_m=float(data["tessellation_tolerance_m"]),
        tessellation_max_triangles=int(data["tessellation_max_triangles"]),
        triangle_budget=int(data["triangle_budget"]),
        mass_kg=float(data["mass_kg"]),
        lod_budgets_m=budgets,
        collision_mode=data.get("collision", {}).get("mode", "hull_per_link"),
        bindings=tuple(data.get("bindings", [])),
        terminals=terminals,
        raw=data,
    )


def load_assets(sources: Path, passed: PassedChecks | None = None) -> tuple[dict[str, AssetConfig], list[UserError]]:
    """Every sources/assets/<id>/asset.toml; broken ones are returned as errors."""
    configs: dict[str, AssetConfig] = {}
    problems: list[UserError] = []
    folder = Path(sources) / "assets"
    for toml in sorted(folder.glob("*/asset.toml")):
        try:
            cfg = load_asset_config(toml, passed)
        except UserError as e:
            problems.append(e)
            continue
        configs[cfg.id] = cfg
    return configs, problems


def asset_ids(sources: Path) -> set[str]:
    """The id of every sources/assets/<id>/ that holds an asset.toml, readable or not:
    what a floor plan may place. An asset whose asset.toml is broken fails its own
    build; the plan still reads the same (and the planner and the scene tasks share
    one floor-plan memo entry)."""
    return {toml.parent.name for toml in (Path(sources) / "assets").glob("*/asset.toml")}
