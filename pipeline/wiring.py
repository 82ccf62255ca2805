"""Conductor sources: the types file (sources/conductors.toml), site.toml's
`[[conductors]]` and `[wiring]`, and the floor plan's conductor layers. Readers return
plain data; the spans are solved in scene.conductors, where the terminals are placed.

A terminal is named `TAG.terminal`: the placement's tag (which may hold dots) and one
of its asset's terminals (asset.toml `[[terminals]]`, carried in the manifest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import config
from .errors import UserError


@dataclass(frozen=True)
class ConductorType:
    """One conductor type: figures of one subconductor, and the bundle it is strung in.
    w is the weight of the whole bundle per metre (N/m); ea the bundle's E A (N)."""

    name: str
    diameter_m: float
    mass_kg_per_m: float
    ea_n: float
    alpha_per_k: float
    bundle_count: int = 1
    bundle_spacing_m: float = 0.0
    max_temperature_c: float = 75.0
    description: str = ""
    resistance_ohm_per_km: tuple[float, float] | None = None  # AC at 25 and 75 deg C, one subconductor

    @property
    def w(self) -> float:
        from .geometry.catenary import G

        return self.mass_kg_per_m * G * self.bundle_count

    @property
    def ea(self) -> float:
        return self.ea_n * self.bundle_count

    def bundle_offsets(self) -> np.ndarray:
        """(bundle_count, 2) offsets (across, up) of the subconductors from the bundle's
        centre: a regular polygon whose side is the spacing, flat at the bottom."""
        n = self.bundle_count
        if n == 1:
            return np.zeros((1, 2))
        radius = self.bundle_spacing_m / (2.0 * math.sin(math.pi / n))
        start = -math.pi / 2 - math.pi / n if n > 2 else 0.0  # two side by side; more: a flat bottom
        angles = start + 2.0 * math.pi * np.arange(n) / n
        return np.round(np.c_[np.cos(angles), np.sin(angles)] * radius, 12)


@dataclass(frozen=True)
class SpanSpec:
    """One span as the sources give it. `origin`: where it was written (a site.toml
    key or a DXF entity), for messages."""

    id: str
    start: tuple[str, str]  # (tag, terminal)
    end: tuple[str, str]
    type: str
    temperature_c: float
    tension_n: float | None = None
    sag_m: float | None = None
    sag_ratio: float | None = None
    voltage_kv: float | None = None
    origin: str = ""


@dataclass(frozen=True)
class Wiring:
    """[wiring] of site.toml with defaults, the types, and the spans written out."""

    types_path: Path
    types: dict
    temperature_c: float
    snap_tolerance_m: float
    lod_chord_errors_m: tuple[float, ...]
    collision: str
    layers: dict  # upper-case layer name -> its settings
    specs: tuple[SpanSpec, ...]
    sag_variants_c: tuple[float, ...] = ()  # conductor temperatures of the SDF world's sag variants

    @property
    def empty(self) -> bool:
        return not self.specs and not self.layers


def split_ref(ref: str) -> tuple[str, str]:
    """`TAG.terminal` -> (TAG, terminal): the terminal is after the last dot."""
    tag, _, terminal = ref.rpartition(".")
    return tag, terminal


def span_id(start: tuple[str, str], end: tuple[str, str]) -> str:
    return f"{start[0]}.{start[1]}~{end[0]}.{end[1]}"


def load_types(path: Path, passed: config.PassedChecks | None = None) -> dict[str, ConductorType]:
    """sources/conductors.toml, validated by schemas/conductors.schema.json."""
    path = Path(path)
    data = config.read_toml(path)
    config.validate(data, "conductors", path, passed)
    out = {}
    for name, t in sorted(data["types"].items()):
        for key, value in t.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise UserError(path, f"types.{name}.{key}", "not a finite number")
        count = int(t.get("bundle_count", 1))
        spacing = float(t.get("bundle_spacing_m", 0.0))
        if count > 1 and spacing <= float(t["diameter_m"]):
            raise UserError(path, f"types.{name}.bundle_spacing_m",
                            f"a bundle of {count} needs a spacing above the diameter ({t['diameter_m']} m)")
        out[name] = ConductorType(name, float(t["diameter_m"]), float(t["mass_kg_per_m"]), float(t["ea_n"]),
                                  float(t["alpha_per_k"]), count, spacing, float(t.get("max_temperature_c", 75.0)),
                                  t.get("description", ""), _resistance(t))
    return out


def _resistance(t: dict) -> tuple[float, float] | None:
    return (float(t["r25_ohm_per_km"]), float(t["r75_ohm_per_km"])) if "r25_ohm_per_km" in t else None


def load_wiring(site: config.Site) -> Wiring:
    """The site's conductors as written: [wiring], its types and [[conductors]]. Every
    problem (an unknown type, a malformed end, a span twice) in one UserError."""
    raw = site.raw
    options = config._defaults(config.schema("site")["properties"]["wiring"], dict(raw.get("wiring", {})))
    specs_raw = raw.get("conductors", [])
    types_path = site.root / options["types"]
    if not types_path.resolve().is_relative_to(site.root.resolve()):
        # sources are untrusted: a path in them reads nothing outside their folder
        raise UserError(site.path, "wiring.types", f"{options['types']!r} is outside the sources folder")
    if not specs_raw and not options.get("layers"):
        return Wiring(types_path, {}, float(options["temperature_c"]), float(options["snap_tolerance_m"]),
                      tuple(options["lod_chord_errors_m"]), options["collision"], {}, ())
    types = load_types(types_path)
    problems: list[str] = []
    budgets = [float(b) for b in options["lod_chord_errors_m"]]
    if budgets != sorted(budgets):
        problems.append("wiring.lod_chord_errors_m: budgets must ascend (LOD0 finest)")
    layers = {}
    for i, lay in enumerate(options.get("layers", [])):
        if lay["type"] not in types:
            problems.append(f"wiring.layers[{i}] ({lay['layer']}): unknown conductor type {lay['type']!r} "
                            f"(types in {types_path.name}: {', '.join(types)})")
        if lay["layer"].upper() in layers:
            problems.append(f"wiring.layers[{i}]: layer {lay['layer']!r} is given twice")
        layers[lay["layer"].upper()] = lay
    specs, seen = [], {}
    for i, c in enumerate(specs_raw):
        start, end = split_ref(c["from"]), split_ref(c["to"])
        sid = c.get("id") or span_id(start, end)
        where = f"conductors[{i}] ({sid})"
        if c["type"] not in types:
            problems.append(f"{where}: unknown conductor type {c['type']!r} (types in {types_path.name}: {', '.join(types)})")
        if start == end:
            problems.append(f"{where}: both ends are {c['from']}")
        if sid in seen:
            problems.append(f"{where}: id {sid!r} is also conductors[{seen[sid]}]'s")
        seen[sid] = i
        specs.append(SpanSpec(sid, start, end, c["type"], float(c.get("temperature_c", options["temperature_c"])),
                              c.get("tension_n"), c.get("sag_m"), None, c.get("voltage_kv"), f"site.toml conductors[{i}]"))
    if problems:
        raise UserError(site.path, "conductors", _listing(problems))
    return Wiring(types_path, types, float(options["temperature_c"]), float(options["snap_tolerance_m"]),
                  tuple(budgets), options["collision"], layers, tuple(specs),
                  tuple(float(t) for t in options.get("sag_variants_c", ())))


def _listing(problems: list[str]) -> str:
    if len(problems) == 1:
        return problems[0]
    return f"{len(problems)} problems:\n  " + "\n  ".join(problems)
