"""Reader for STEP files: OpenCASCADE's tessellation through cascadio (ingest.tessellate).

Units: OpenCASCADE reads each representation context in its own declared length unit
(a file may mix centimetres and millimetres) and cascadio writes metres, so the file's
units need nothing more. asset.toml `units` overrides them for a file that declares
one length unit ("the numbers are inches, whatever the header says"); `scale`
multiplies after; `up_axis` turns the model (STEP has no up axis: Z by default).

The tessellation tolerance is asset.toml's `tessellation_tolerance_m`, the same
distance in every unit; a tolerance estimated to make more than
`tessellation_max_triangles` is refused before tessellating, and a tessellation that
runs out of memory is an error naming the asset, not a crash.
"""

from __future__ import annotations

import mmap
import re
import tempfile
from pathlib import Path

from .. import ir
from ..errors import UserError
from . import tessellate
from .mesh import _load, asset_from_trimesh
from .size import check_size
from .units import METRES, Frame, resolve

_PREFIX = {b"": 1.0, b"EXA": 1e18, b"PETA": 1e15, b"TERA": 1e12, b"GIGA": 1e9, b"MEGA": 1e6, b"KILO": 1e3,
           b"HECTO": 1e2, b"DECA": 1e1, b"DECI": 1e-1, b"CENTI": 1e-2, b"MILLI": 1e-3, b"MICRO": 1e-6,
           b"NANO": 1e-9, b"PICO": 1e-12}
_LENGTH_UNIT = re.compile(rb"#(\d+)\s*=\s*([^;]*\bLENGTH_UNIT\s*\(\s*\)[^;]*);")
_SI = re.compile(rb"SI_UNIT\s*\(\s*(?:\.(\w+)\.|\$)\s*,\s*\.METRE\.\s*\)")
_CONVERSION = re.compile(rb"CONVERSION_BASED_UNIT\s*\(\s*'[^']*'\s*,\s*#(\d+)\s*\)")
_MEASURE = re.compile(rb"#(\d+)\s*=\s*LENGTH_MEASURE_WITH_UNIT\s*\(\s*(?:LENGTH_MEASURE\s*\()?\s*"
                      rb"([-+0-9.eE]+)\s*\)?\s*,\s*#(\d+)\s*\)")
_CONTEXT = re.compile(rb"GLOBAL_UNIT_ASSIGNED_CONTEXT\s*\(\s*\(([^)]*)\)")
UNIT_NAMES = {1.0: "m", 0.01: "cm", 0.001: "mm", 0.0254: "in", 0.3048: "ft"}


def _unit_metres(uid: bytes, units: dict, measures: dict, depth: int = 0) -> float | None:
    body = units.get(uid)
    if body is None or depth > 8:
        return None
    si = _SI.search(body)
    if si:
        return _PREFIX.get((si.group(1) or b"").upper())
    conv = _CONVERSION.search(body)
    if conv and conv.group(1) in measures:
        value, base = measures[conv.group(1)]
        base_m = _unit_metres(base, units, measures, depth + 1)
        return None if base_m is None else value * base_m
    return None


def step_length_units(path: Path) -> tuple[float, ...]:
    """Metres per unit of every length unit the file's representation contexts use
    (GLOBAL_UNIT_ASSIGNED_CONTEXT), sorted; SI prefixes and conversion-based units
    (inch, foot, ...) through their measure."""
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as text:
        units = {m.group(1): m.group(2).upper() for m in _LENGTH_UNIT.finditer(text)}
        measures = {m.group(1): (float(m.group(2)), m.group(3)) for m in _MEASURE.finditer(text)}
        used = {uid.strip().lstrip(b"#") for m in _CONTEXT.finditer(text) for uid in m.group(1).split(b",")}
    found = {_unit_metres(uid, units, measures) for uid in used if uid in units}
    return tuple(sorted(round(m, 12) for m in found if m))


def _unit_name(metres: float) -> str:
    return UNIT_NAMES.get(metres, f"{metres:g} m")


def _frame(cfg, path: Path, declared: tuple[float, ...]) -> tuple[Frame, float]:
    """The asset's frame and the factor on cascadio's metres that realises it."""
    frame = resolve(cfg, declared[0] if len(declared) == 1 else None, None)
    if frame.units_from != "asset.toml":
        return Frame(1.0, "file", frame.up_axis, frame.up_from, frame.scale), frame.scale
    if len(declared) > 1:
        raise UserError(getattr(cfg, "path", path), "units",
                        f"{path.name} declares several length units ({', '.join(map(_unit_name, declared))}) and "
                        "OpenCASCADE reads each in its own: leave `units` out, or use `scale`")
    file_unit = declared[0] if declared else METRES["mm"]  # OpenCASCADE's reading of a file without one
    return frame, frame.metres_per_unit / file_unit * frame.scale


def _refusal(cfg, path: Path, tol_m: float, report: dict) -> UserError:
    where = getattr(cfg, "path", path)
    limit = int(getattr(cfg, "tessellation_max_triangles", 0))
    fits = report.get("fits_m")
    hint = (f"about {fits:.3g} m would stay within it" if fits else
            "no tolerance would: raise tessellation_max_triangles")
    return UserError(where, "tessellation_tolerance_m",
                     f"tessellating {path.name} at {tol_m:g} m would make about {report['estimate']:,.0f} triangles, "
                     f"over tessellation_max_triangles = {limit:,} ({hint}); nothing was tessellated")


def _failure(cfg, path: Path, tol_m: float, report: dict) -> UserError:
    where = getattr(cfg, "path", path)
    limit = tessellate.memory_limit()
    memory = f"the build's memory limit of {limit / 2**30:.1f} GB" if limit else "the machine's memory"
    if report.get("memory"):
        return UserError(where, "tessellation_tolerance_m",
                         f"tessellating {path.name} at {tol_m:g} m ran out of {memory}: raise tessellation_tolerance_m")
    if "died" in report:
        return UserError(where, "tessellation_tolerance_m",
                         f"OpenCASCADE crashed ({report['died']}) tessellating {path.name} at {tol_m:g} m: out of "
                         f"{memory} (raise tessellation_tolerance_m or twin build --memory-limit), or a file it "
                         "cannot read")
    if report.get("empty"):
        return UserError(path, None, "cannot read STEP file (OpenCASCADE found no shape)")
    return UserError(path, None, f"cannot read STEP file: {report.get('failed')}")


def read_cad(cfg) -> ir.Asset:
    """Read cfg.source (.step/.stp) into an ir.Asset in metres, Z up.

    Asset.metadata records the tolerance ("tessellation_tolerance_m"), the estimate
    ("tessellation_estimate"), the units the file declares ("step_units_m") and the
    frame (ingest.units.Frame.metadata)."""
    path = Path(cfg.source)
    check_size(path)
    if path.suffix.lower() not in (".step", ".stp"):
        raise UserError(path, None, f"not a STEP file: {path.suffix!r}")
    declared = step_length_units(path)
    frame, factor = _frame(cfg, path, declared)
    tol_m = float(cfg.tessellation_tolerance_m)
    max_triangles = int(getattr(cfg, "tessellation_max_triangles", 1_000_000))
    with tempfile.TemporaryDirectory() as tmp:
        glb = Path(tmp) / "model.glb"
        report = tessellate.run(path, glb, tol_m, max_triangles)
        if report.get("refused"):
            raise _refusal(cfg, path, tol_m, report)
        if "estimate" not in report:
            raise _failure(cfg, path, tol_m, report)
        try:
            loaded = _load(glb, "glb")
        except MemoryError:
            raise _failure(cfg, path, tol_m, {"memory": True}) from None
    metadata = (("tessellation_tolerance_m", repr(tol_m)),
                ("tessellation_estimate", str(round(report["estimate"]))),
                ("step_units_m", ", ".join(map(repr, declared)) or "none declared"), *frame.metadata())
    glb_frame = Frame(factor, frame.units_from, frame.up_axis, frame.up_from)
    return asset_from_trimesh(loaded, cfg, path, glb_frame, metadata)
