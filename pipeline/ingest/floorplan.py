"""The CAD floor plan (DXF) -> ir.FloorPlan (DESIGN.md s.2, "Floor plan").

Every INSERT in modelspace is one placement: block name = asset id, insertion point =
plant-grid position, insertion z = height above its level, rotation = heading.
Attributes TAG (unique) and LEVEL are required, STATE optional. Closed LWPOLYLINEs on
layers PLATFORM_<level> are the terraces. Everything else is counted, never silently
dropped. Any problem is one UserError naming the file and the INSERT (TAG or handle).
"""

from __future__ import annotations

import math
import re
from collections import Counter
from pathlib import Path

import numpy as np

from .. import ir
from ..errors import UserError

# $INSUNITS code -> (unit name, metres per drawing unit)
UNITS = {4: ("mm", 0.001), 6: ("m", 1.0)}
UNITS_ASSUMED = "m (assumed: $INSUNITS is 0, unitless)"
PLATFORM_PREFIX = "PLATFORM_"
SAFE_TAG = re.compile(r"^(?!.*\.\.)[A-Za-z0-9_][A-Za-z0-9_.-]*$")
# Arcs in a platform outline are flattened to this chord error (drawing metres).
ARC_TOLERANCE_M = 0.01


def read_floorplan(path, known_assets: set[str] | None = None, levels: set[str] | None = None) -> ir.FloorPlan:
    """Read a DXF floor plan.

    known_assets: asset ids an INSERT may name (None: any block name is accepted).
    levels: level names from site.toml (None: any LEVEL is accepted).
    Returns placements sorted by TAG, platforms sorted by (level, handle), and the
    ignored modelspace entities as sorted (dxftype, count) pairs. Coordinates in metres.
    """
    path = Path(path)
    doc = _open(path)
    units, to_m = _units(doc, path)
    placements: list[ir.Placement] = []
    platforms: list[ir.Platform] = []
    ignored: Counter[str] = Counter()
    by_level = {lv.upper(): lv for lv in levels} if levels is not None else None

    for e in doc.modelspace():
        kind = e.dxftype()
        if kind == "INSERT":
            placements.append(_placement(e, path, to_m, known_assets, levels))
        elif kind == "LWPOLYLINE" and e.dxf.layer.upper().startswith(PLATFORM_PREFIX):
            platforms.append(_platform(e, path, to_m, by_level))
        else:
            ignored[kind] += 1

    seen: dict[str, ir.Placement] = {}
    for p in placements:
        if p.tag in seen:
            raise UserError(path, _name(p.tag, p.handle), f"duplicate TAG: INSERT #{seen[p.tag].handle} has it too")
        seen[p.tag] = p
    return ir.FloorPlan(
        path=str(path),
        units=units,
        placements=tuple(sorted(placements, key=lambda p: p.tag)),
        platforms=tuple(sorted(platforms, key=lambda p: (p.level, int(p.handle, 16) if p.handle else 0))),
        ignored=tuple(sorted(ignored.items())),
    )


def _open(path: Path):
    import ezdxf

    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise UserError(path, None, "file not found") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
    # ezdxf tolerates a file cut off after the last complete section; a cut-off floor
    # plan could lose placements, so demand the final EOF marker (ASCII DXF).
    if not raw.startswith(b"AutoCAD Binary DXF") and raw.rstrip().rsplit(None, 1)[-1:] != [b"EOF"]:
        raise UserError(path, None, "truncated DXF: no EOF marker at the end of the file")
    try:
        return ezdxf.readfile(path)
    except Exception as e:  # any parse failure of a corrupt file, reported without traceback
        raise UserError(path, None, f"not a readable DXF file ({type(e).__name__}: {e})") from None


def _units(doc, path: Path) -> tuple[str, float]:
    code = int(doc.header.get("$INSUNITS", 0))
    if code == 0:
        return UNITS_ASSUMED, 1.0
    if code not in UNITS:
        raise UserError(path, "$INSUNITS", f"unsupported drawing unit code {code}; use 4 (millimetres) or 6 (metres)")
    return UNITS[code]


def _name(tag: str | None, handle: str) -> str:
    return f"INSERT {tag} (#{handle})" if tag else f"INSERT #{handle}"


def _attribs(insert) -> dict[str, str]:
    out: dict[str, str] = {}
    for a in insert.attribs:
        out[a.dxf.tag.strip().upper()] = a.dxf.text.strip()
    return out


def _placement(insert, path: Path, to_m: float, known_assets, levels) -> ir.Placement:
    handle = insert.dxf.handle
    attrs = _attribs(insert)
    tag = attrs.get("TAG") or None
    where = _name(tag, handle)
    block = insert.dxf.name
    if tag is None:
        raise UserError(path, where, f"INSERT of block {block!r} has no TAG attribute")
    if not SAFE_TAG.match(tag):
        # TAGs become prim paths, world names and run-output file names
        raise UserError(path, where, "TAG may hold letters, digits, '-', '_' and '.', not a path (no '/', '\\' or '..')")
    level = attrs.get("LEVEL")
    if not level:
        raise UserError(path, where, "no LEVEL attribute")
    if levels is not None and level not in levels:
        raise UserError(path, where, f"LEVEL {level!r} is not a level of site.toml ({', '.join(sorted(levels))})")
    if known_assets is not None and block not in known_assets:
        raise UserError(path, where, f"block {block!r} is not a known asset (no sources/assets/{block}/)")
    if insert.mcount > 1:
        raise UserError(path, where, "array INSERT (MINSERT): explode it into single INSERTs with their own TAGs")
    scale = (insert.dxf.xscale, insert.dxf.yscale, insert.dxf.zscale)
    # A uniform positive scale only sizes the CAD symbol: the model has its own size.
    # Mirrored or stretched equipment cannot be built from the asset.
    if min(scale) <= 0 or not math.isclose(min(scale), max(scale), rel_tol=1e-9):
        raise UserError(path, where, f"INSERT scale {scale} is mirrored or non-uniform")
    normal = np.asarray(insert.dxf.extrusion, dtype=np.float64)
    if not np.allclose(normal, (0.0, 0.0, 1.0), atol=1e-9):
        raise UserError(path, where, f"INSERT extrusion {tuple(normal)} is not +Z (tilted or mirrored block)")
    x, y, z = insert.dxf.insert
    return ir.Placement(
        tag=tag,
        asset_id=block,
        level=level,
        x=float(x) * to_m,
        y=float(y) * to_m,
        z=float(z) * to_m,
        heading_deg=float(insert.dxf.rotation) % 360.0,
        state=attrs.get("STATE") or None,
        handle=handle,
    )


def _platform(poly, path: Path, to_m: float, by_level) -> ir.Platform:
    from ezdxf import path as dxfpath

    handle = poly.dxf.handle
    layer = poly.dxf.layer
    where = f"LWPOLYLINE #{handle} on layer {layer}"
    level = layer[len(PLATFORM_PREFIX) :]
    if by_level is not None:
        if level.upper() not in by_level:
            raise UserError(path, where, f"level {level!r} is not a level of site.toml ({', '.join(sorted(by_level.values()))})")
        level = by_level[level.upper()]  # DXF layer names are case-insensitive
    if not poly.closed:
        raise UserError(path, where, "platform outline is not closed")
    # make_path applies the OCS (elevation, extrusion) and the bulges (arcs).
    pts = np.array([(v.x, v.y) for v in dxfpath.make_path(poly).flattening(ARC_TOLERANCE_M / to_m)], dtype=np.float64)
    if len(pts) > 1 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    pts *= to_m
    if len(pts) < 3 or abs(_area(pts)) < 1e-6:
        raise UserError(path, where, "platform outline has no area")
    return ir.Platform(level=level, outline=pts, handle=handle)


def _area(outline: np.ndarray) -> float:
    """Signed area of a polygon. outline: (k, 2) float64, not closed."""
    x, y = outline[:, 0], outline[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def points_in_polygon(points, outline) -> np.ndarray:
    """Even-odd rule. points: (n, 2), outline: (k, 2) not closed -> (n,) bool."""
    p = np.asarray(points, dtype=np.float64)
    v = np.asarray(outline, dtype=np.float64)
    a, b = v, np.roll(v, -1, axis=0)
    px, py = p[:, 0:1], p[:, 1:2]
    crosses = (a[:, 1] > py) != (b[:, 1] > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (crosses & (px < xint)).sum(axis=1) % 2 == 1


# --- memo -------------------------------------------------------------------------

MEMO_NAME = ".floorplan.json"  # in a build folder: the planner writes it, the scene tasks reuse it


def read_floorplan_memo(path: Path, assets: set[str], levels: set[str], memo: Path | None) -> ir.FloorPlan:
    """read_floorplan, or its result from `memo` when the DXF's content, the known
    assets and levels and the reader's code are what they were. Only successful reads
    are kept (a bad plan raises its error every time), as JSON: a build folder may be
    shared, so nothing in it is unpickled."""
    import hashlib
    import json
    import os

    # one spelling of the path: the planner is handed a relative sources folder and the
    # scene tasks an absolute one, and each would otherwise miss the other's entry
    path = Path(path).resolve()
    key = None
    if memo is not None and path.is_file():
        h = hashlib.sha256(path.read_bytes())
        h.update(json.dumps([sorted(assets), sorted(levels), str(path)]).encode())
        for module in (Path(__file__), Path(ir.__file__)):  # the reader's code
            h.update(module.read_bytes())
        key = h.hexdigest()
        try:
            doc = json.loads(memo.read_text())
            if doc.get("key") == key:
                return _floorplan_from_json(doc["floorplan"])
        except (OSError, ValueError, KeyError, TypeError):
            pass
    fp = read_floorplan(path, known_assets=assets, levels=levels)
    if key is not None:
        memo.parent.mkdir(parents=True, exist_ok=True)
        tmp = memo.with_name(f"{memo.name}.tmp-{os.getpid()}")
        tmp.write_text(json.dumps({"key": key, "floorplan": _floorplan_to_json(fp)}, sort_keys=True))
        os.replace(tmp, memo)
    return fp


def _floorplan_to_json(fp: ir.FloorPlan) -> dict:
    from dataclasses import asdict

    return {"path": fp.path, "units": fp.units, "placements": [asdict(p) for p in fp.placements],
            "platforms": [{"level": p.level, "outline": p.outline.tolist(), "handle": p.handle} for p in fp.platforms],
            "ignored": [list(i) for i in fp.ignored]}


def _floorplan_from_json(d: dict) -> ir.FloorPlan:
    return ir.FloorPlan(path=d["path"], units=d["units"],
                        placements=tuple(ir.Placement(**p) for p in d["placements"]),
                        platforms=tuple(ir.Platform(p["level"], p["outline"], p["handle"]) for p in d["platforms"]),
                        ignored=tuple((str(k), int(n)) for k, n in d["ignored"]))
