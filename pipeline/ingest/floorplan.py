"""The CAD floor plan (DXF) -> ir.FloorPlan (DESIGN.md s.2, "Floor plan").

An INSERT of a mapped block (site.toml [floorplan] blocks, or a block named by an asset
id) is one placement. An INSERT of any other block is exploded: the INSERTs in its
definition are considered with the composed transform, to any depth. A placement's
position is where the INSERT matrix chain (OCS, rotation, scale, insertion point, block
base point, as ezdxf composes them) takes the block's origin; its heading is the
direction of the block's x axis; insertion z is its height above its level.
Attributes (names from [floorplan] attributes): TAG, unique, derived from the handles
when missing; LEVEL, else an enclosing INSERT's, else [floorplan] default_level;
STATE, optional. Closed LWPOLYLINEs on layers PLATFORM_<level> are the terraces.
Everything else is counted, never silently dropped. Every INSERT or outline that cannot
be used is reported, all of them in one UserError naming the file and each handle.
"""

from __future__ import annotations

import difflib
import fnmatch
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import ir
from ..errors import UserError, read_input

# $INSUNITS code -> (unit name, metres per drawing unit), exact by the units'
# definitions: ezdxf.units rounds inches and feet to ten digits and has no factor for
# mils, microinches or US survey units. The names are [plan] units' values.
UNITS = {
    1: ("in", 0.0254), 2: ("ft", 0.3048), 3: ("mi", 1609.344), 4: ("mm", 1e-3), 5: ("cm", 1e-2),
    6: ("m", 1.0), 7: ("km", 1e3), 8: ("uin", 2.54e-8), 9: ("mil", 2.54e-5), 10: ("yd", 0.9144),
    11: ("angstrom", 1e-10), 12: ("nm", 1e-9), 13: ("um", 1e-6), 14: ("dm", 0.1), 15: ("dam", 10.0),
    16: ("hm", 100.0), 17: ("Gm", 1e9), 18: ("au", 149_597_870_700.0), 19: ("ly", 9_460_730_472_580_800.0),
    20: ("pc", 149_597_870_700.0 * 648_000.0 / math.pi), 21: ("us_ft", 1200.0 / 3937.0),
    22: ("us_in", 100.0 / 3937.0), 23: ("us_yd", 3600.0 / 3937.0), 24: ("us_mi", 6_336_000.0 / 3937.0),
}
UNIT_BY_NAME = {name: (name, metres) for name, metres in UNITS.values()}
PLATFORM_PREFIX = "PLATFORM_"
SAFE_TAG = re.compile(r"^(?!.*\.\.)[A-Za-z0-9_][A-Za-z0-9_.-]*$")
ASSET_ID = re.compile(r"^[a-z0-9][a-z0-9_]*$")  # config.SAFE_ID
# Arcs in a platform outline are flattened to this chord error (drawing metres).
ARC_TOLERANCE_M = 0.01
# An INSERT chain whose linear part has singular values within this (relative) of each
# other is a uniform scale times a rotation; CAD programs store scales like 1.26 with
# a few 1e-7 of noise.
UNIFORM_SCALE_REL = 1e-6
# A block whose z axis leans further than this (radians) from up cannot stand upright.
TILT_TOLERANCE = 1e-6
MAX_DEPTH = 64  # nesting deeper than this is a cycle in a malformed file


class _Unplaceable(Exception):
    """An INSERT chain no model can follow (mirrored, non-uniform, tilted)."""


@dataclass
class _Reading:
    """What one read gathers while it walks the modelspace."""

    path: Path
    options: object
    known_assets: set[str] | None
    levels: set[str] | None
    to_m: float
    placements: list[ir.Placement] = field(default_factory=list)
    problems: list[UserError] = field(default_factory=list)
    inserts: Counter = field(default_factory=Counter)  # block name -> INSERTs met
    left_out: Counter = field(default_factory=Counter)  # unmapped blocks with nothing placeable
    placeable: dict[str, bool] = field(default_factory=dict)  # block name -> holds a placement
    nested: dict[str, int] = field(default_factory=dict)  # block name -> INSERTs in it, any depth
    absorbed: Counter = field(default_factory=Counter)  # mapped block -> INSERTs inside its placements
    scaled: Counter = field(default_factory=Counter)  # scale factor -> placements drawn at it

    def problem(self, obj: str, message: str) -> None:
        self.problems.append(UserError(self.path, obj, message))


def read_floorplan(path, known_assets: set[str] | None = None, levels: set[str] | None = None,
                   options=None) -> ir.FloorPlan:
    """Read a DXF floor plan.

    known_assets: asset ids a block may name or be mapped to (None: every block is an
    asset, none is exploded). levels: level names from site.toml (None: any LEVEL is
    accepted). options: config.FloorplanOptions (None: the defaults).
    Returns placements sorted by TAG, platforms sorted by (level, handle), and the
    ignored modelspace entities as sorted (dxftype, count) pairs. Coordinates in metres.
    Raises one UserError listing every INSERT and outline that cannot be used.
    """
    fp, problems = scan_floorplan(path, known_assets, levels, options)
    if len(problems) == 1:
        raise problems[0]
    if problems:
        lines = "\n".join(f"  {p.obj}: {p.message}" if p.obj else f"  {p.message}" for p in problems)
        raise UserError(path, f"{len(problems)} problems", f"the floor plan cannot be used as drawn:\n{lines}")
    return fp


def scan_floorplan(path, known_assets: set[str] | None = None, levels: set[str] | None = None,
                   options=None) -> tuple[ir.FloorPlan, list[UserError]]:
    """read_floorplan's reading: the floor plan without what cannot be used, and a
    UserError for each INSERT or outline that cannot (in drawing order)."""
    if options is None:
        from ..config import FloorplanOptions

        options = FloorplanOptions()
    path = Path(path)
    doc = _open(path)
    units, to_m = _units(doc, path, options)
    r = _Reading(path, options, known_assets, levels, to_m)
    platforms: list[ir.Platform] = []
    ignored: Counter[str] = Counter()
    lines = []
    by_level = {lv.upper(): lv for lv in levels} if levels is not None else None

    _bound_expansion(r, doc)
    for e in doc.modelspace():
        kind = e.dxftype()
        if kind == "INSERT":
            _visit(r, e, None, (), (), None)
        elif kind == "LWPOLYLINE" and e.dxf.layer.upper().startswith(PLATFORM_PREFIX):
            try:
                platforms.append(_platform(e, path, to_m, by_level))
            except UserError as problem:
                r.problems.append(problem)
        elif kind in ("LINE", "LWPOLYLINE") and e.dxf.layer.upper() in options.conductor_layers:
            lines.append(_conductor_line(e, to_m))
        else:
            ignored[kind] += 1
    _duplicates(r)
    fp = ir.FloorPlan(
        path=str(path),
        units=units,
        placements=tuple(sorted(r.placements, key=lambda p: p.tag)),
        platforms=tuple(sorted(platforms, key=lambda p: (p.level, int(p.handle, 16) if p.handle else 0))),
        ignored=tuple(sorted(ignored.items())),
        inserts=tuple(sorted(r.inserts.items())),
        warnings=tuple(_warnings(r, doc, platforms, levels)),
        conductor_lines=tuple(lines),
        absorbed=tuple(sorted(r.absorbed.items())),
    )
    return fp, r.problems


def _conductor_line(e, to_m: float) -> tuple[str, str, tuple[tuple[float, float], ...]]:
    """(handle, layer, plan vertices in metres) of a conductor layer's LINE or
    LWPOLYLINE (in world coordinates: a polyline's OCS applied; closed ones close)."""
    if e.dxftype() == "LINE":
        pts = [tuple(e.dxf.start)[:2], tuple(e.dxf.end)[:2]]
    else:
        pts = [tuple(p)[:2] for p in e.vertices_in_wcs()]
        if e.closed and pts:
            pts.append(pts[0])
    return e.dxf.handle, e.dxf.layer.upper(), tuple((float(x) * to_m, float(y) * to_m) for x, y in pts)


def require_placements_and_platforms(fp: ir.FloorPlan) -> None:
    """A scene needs something to place and ground to stand on: one UserError saying
    which is missing and what the drawing holds instead."""
    missing = [w for w in fp.warnings if w.startswith(("no placements", "no platforms"))]
    if missing:
        raise UserError(fp.path, None, "; ".join(missing))


def _open(path: Path):
    import ezdxf

    raw = read_input(path)
    # ezdxf tolerates a file cut off after the last complete section; a cut-off floor
    # plan could lose placements, so demand the final EOF marker (ASCII DXF).
    if not raw.startswith(b"AutoCAD Binary DXF") and raw.rstrip().rsplit(None, 1)[-1:] != [b"EOF"]:
        raise UserError(path, None, "truncated DXF: no EOF marker at the end of the file")
    try:
        return ezdxf.readfile(path)
    except Exception as e:  # any parse failure of a corrupt file, reported without traceback
        raise UserError(path, None, f"not a readable DXF file ({type(e).__name__}: {e})") from None


def _units(doc, path: Path, options) -> tuple[str, float]:
    """(unit name, metres per drawing unit): [plan] units if site.toml gives them,
    else $INSUNITS."""
    code = int(doc.header.get("$INSUNITS", 0))
    if options.units is not None:
        name, to_m = UNIT_BY_NAME[options.units]
        if code in UNITS and UNITS[code][0] != name:
            return f"{name} ([plan] units; $INSUNITS says {UNITS[code][0]})", to_m
        return name, to_m
    if code == 0:
        raise UserError(path, "$INSUNITS", "the drawing is unitless ($INSUNITS 0): say its unit in "
                                           "site.toml [plan] units (m, mm, cm, in, ft, ...)")
    if code not in UNITS:
        raise UserError(path, "$INSUNITS", f"unknown drawing unit code {code}: say its unit in "
                                           "site.toml [plan] units (m, mm, cm, in, ft, ...)")
    return UNITS[code]


def _name(tag: str | None, chain: tuple[str, ...]) -> str:
    handles = " > ".join(f"#{h}" for h in chain)
    return f"INSERT {tag} ({handles})" if tag else f"INSERT {handles}"


def _attribs(insert, options) -> dict[str, str]:
    """The INSERT's tag, level and state attributes (keys "tag", "level", "state") under
    the names site.toml gives them; DXF attribute tags are case-insensitive."""
    wanted = {options.tag_attribute.upper(): "tag", options.level_attribute.upper(): "level",
              options.state_attribute.upper(): "state"}
    out: dict[str, str] = {}
    for a in insert.attribs:
        key = wanted.get(a.dxf.tag.strip().upper())
        if key is not None:
            out[key] = a.dxf.text.strip()
    return out


def _asset(r: _Reading, block: str) -> str | None:
    """The asset a block places: its [floorplan] blocks entry (exact name first, then
    the first pattern that matches, both case-insensitive as DXF block names are), else
    the block's own name if it is an asset id; None: the block is exploded."""
    folded = block.upper()
    for name, asset in r.options.blocks:
        if name.upper() == folded:
            return asset
    for name, asset in r.options.blocks:
        if fnmatch.fnmatchcase(folded, name.upper()):
            return asset
    if r.known_assets is None or block in r.known_assets:
        return block
    return None


def _visit(r: _Reading, insert, parent, chain: tuple[str, ...], blocks: tuple[str, ...], level: str | None) -> None:
    """One INSERT, `parent` the matrix of the INSERTs around it (None in modelspace):
    a placement, or its block's INSERTs visited in turn."""
    chain = (*chain, insert.dxf.handle)
    block = insert.dxf.name
    r.inserts[block] += 1
    # ezdxf matrices map row vectors: the inner INSERT's matrix applies first
    matrix = insert.matrix44() if parent is None else insert.matrix44() * parent
    attrs = _attribs(insert, r.options)
    level = attrs.get("level") or level
    asset = _asset(r, block)
    if asset is not None:
        _place(r, insert, matrix, chain, attrs, level or r.options.default_level, asset)
        return
    if not _holds_placements(r, block, insert.doc):
        if attrs.get("tag"):
            # a tagged INSERT is a piece of equipment: left out, it would be lost without a word
            r.problem(_name(attrs["tag"], chain), _no_asset(r, block))
        else:
            r.left_out[block] += 1
        return
    if insert.mcount > 1:
        r.problem(_name(attrs.get("tag"), chain), f"array INSERT (MINSERT) of block {block!r}, which holds "
                                                  "placements: explode it into single INSERTs")
        return
    if block in blocks or len(blocks) >= MAX_DEPTH:
        r.problem(_name(attrs.get("tag"), chain), f"block {block!r} contains itself")
        return
    for e in insert.block():
        if e.dxftype() == "INSERT":
            _visit(r, e, matrix, chain, (*blocks, block), level)


def _bound_expansion(r: _Reading, doc) -> None:
    """Refuse a drawing whose INSERTs would expand to more placements than [floorplan]
    max_placements, before expanding any: counted through the block tree (a block's
    count is the sum over its INSERTs, each one or its own block's count), so ten
    levels of ten nested INSERTs cost a hundred steps, not the 10^10 visits of
    expanding them (a 450 KB file that would otherwise grow memory for hours)."""
    counts: dict[str, int] = {}
    mapped: dict[str, bool] = {}

    def places(name: str) -> bool:
        if name not in mapped:
            mapped[name] = _asset(r, name) is not None
        return mapped[name]

    def through(block: str) -> int:
        """Placements that one INSERT of an unmapped `block` expands to."""
        if block not in counts:
            counts[block] = 0  # a block that contains itself adds nothing through itself
            layout = doc.blocks.get(block)
            inner = Counter(e.dxf.name for e in layout if e.dxftype() == "INSERT") if layout is not None else {}
            counts[block] = sum(n * (1 if places(name) else through(name))
                                for name, n in sorted(inner.items()))
        return counts[block]

    per_block = Counter()
    for e in doc.modelspace().query("INSERT"):
        name = e.dxf.name
        per_block[name] += 1 if places(name) else through(name)
    limit = r.options.max_placements
    total = sum(per_block.values())
    if total <= limit:
        return
    block, most = max(per_block.items(), key=lambda kv: (kv[1], kv[0]))
    where = None if places(block) else f"block {block!r}"
    what = f"{most:,} INSERTs of block {block!r} in the modelspace" if places(block) else \
        f"nested INSERTs of block {block!r} expand to {most:,} placements"
    if most < total:
        what = f"the drawing expands to {total:,} placements ({what})"
    raise UserError(r.path, where, f"{what}, more than the {limit:,} that site.toml [floorplan] max_placements "
                                   "allows (nested blocks multiply their INSERTs: check the block tree, or raise "
                                   "the limit for a site that has that many)")


def _no_asset(r: _Reading, block: str) -> str:
    folder = f" (no sources/assets/{block}/)" if ASSET_ID.match(block) else ""
    near = _near_asset(r, block)
    return (f"block {block!r} is not an asset{folder} and site.toml [floorplan] blocks maps it to none"
            + (f"; did you mean asset {near!r}?" if near else ""))


def _near_asset(r: _Reading, block: str) -> str | None:
    near = difflib.get_close_matches(block, sorted(r.known_assets or ()), n=1, cutoff=0.8)
    return near[0] if near else None


def _holds_placements(r: _Reading, block: str, doc) -> bool:
    """Whether an unmapped block's definition places anything, at any depth."""
    if block not in r.placeable:
        r.placeable[block] = False  # a block that contains itself places nothing through itself
        layout = doc.blocks.get(block) if doc is not None else None
        names = {e.dxf.name for e in layout if e.dxftype() == "INSERT"} if layout is not None else set()
        r.placeable[block] = any(_asset(r, n) is not None or _holds_placements(r, n, doc) for n in sorted(names))
    return r.placeable[block]


def _place(r: _Reading, insert, matrix, chain: tuple[str, ...], attrs: dict[str, str], level: str | None,
           asset: str) -> None:
    block = insert.dxf.name
    tag = attrs.get("tag") or None
    where = _name(tag, chain)
    if r.known_assets is not None and asset not in r.known_assets:
        r.problem(where, f"block {block!r} is mapped to {asset!r}, which is not a known asset (no "
                         f"sources/assets/{asset}/; see site.toml [floorplan] blocks)")
        return
    if insert.mcount > 1:
        r.problem(where, f"array INSERT (MINSERT) of block {block!r}: explode it into single INSERTs with their own tags")
        return
    try:
        origin, heading, scale = _pose(matrix)
    except _Unplaceable as e:
        r.problem(where, f"block {block!r}: {e}")
        return
    if abs(scale - 1.0) > UNIFORM_SCALE_REL:
        r.scaled[round(scale, 6)] += 1
    if tag is None:
        tag = "insert_" + "_".join(chain)  # handles are stable across saves of a drawing
    elif not SAFE_TAG.match(tag):
        # TAGs become prim paths, world names and run-output file names
        r.problem(where, f"{r.options.tag_attribute} may hold letters, digits, '-', '_' and '.', not a path "
                         "(no '/', '\\' or '..')")
        return
    if not level:
        r.problem(where, f"no {r.options.level_attribute} attribute on it or an INSERT around it, and no "
                         "[floorplan] default_level in site.toml")
        return
    if r.levels is not None and level not in r.levels:
        r.problem(where, f"{r.options.level_attribute} {level!r} is not a level of site.toml ({', '.join(sorted(r.levels))})")
        return
    x, y, z = origin * r.to_m
    absorbed = _nested_inserts(r, block, insert.doc)
    if absorbed:
        r.absorbed[block] += absorbed
    r.placements.append(ir.Placement(
        tag=tag,
        asset_id=asset,
        level=level,
        x=float(x),
        y=float(y),
        z=float(z),  # grid_scale is the projection's horizontal factor: a height takes the unit only
        heading_deg=heading,
        state=attrs.get("state") or None,
        handle=chain[-1],
        dxf_handles=chain,
        scale=scale if r.options.insert_scale == "apply" else 1.0,
    ))


def _nested_inserts(r: _Reading, block: str, doc) -> int:
    """INSERTs inside a block's definition, at any depth: what one placement of a mapped
    block absorbs (its model stands for them)."""
    if block not in r.nested:
        r.nested[block] = 0  # a block that contains itself counts once
        layout = doc.blocks.get(block) if doc is not None else None
        inner = [e.dxf.name for e in layout if e.dxftype() == "INSERT"] if layout is not None else []
        r.nested[block] = sum(1 + _nested_inserts(r, name, doc) for name in inner)
    return r.nested[block]


def _pose(matrix) -> tuple[np.ndarray, float, float]:
    """(block origin (3,) in drawing units, heading in degrees, uniform scale) of a block
    placed by an ezdxf Matrix44 (rows: the block's x, y and z axes and its origin).

    Mirrors are told by the determinant of the linear part, not by the signs of the
    scale factors: (-s, -s, s) is a half turn, and an OCS with extrusion (0, 0, -1)
    with a negative z scale stands upright."""
    m = np.array(list(matrix.rows()), dtype=np.float64)
    linear = m[:3, :3]
    sv = np.linalg.svd(linear, compute_uv=False)
    det = float(np.linalg.det(linear))
    uniform = sv[0] > 0 and sv[0] - sv[-1] <= UNIFORM_SCALE_REL * sv[0]
    if not uniform or det <= 0:
        what = [w for w, bad in (("mirrored (negative determinant)", det < 0),
                                 (f"non-uniform (axis scales {_fmt(sv)})", not uniform)) if bad]
        raise _Unplaceable(f"the INSERT chain is {' and '.join(what)}: a model can only be moved and turned")
    scale = float(np.cbrt(det))
    up = linear[2] / scale
    if math.hypot(up[0], up[1]) > TILT_TOLERANCE or up[2] <= 0:
        raise _Unplaceable(f"the INSERT chain turns the block's z axis to {_fmt(up)} in the drawing: a model "
                           "stands upright (only turns about the vertical can be placed)")
    # the chain's atan2 gives the INSERT's decimal angle back only to its last bits
    heading = round(math.degrees(math.atan2(linear[0, 1], linear[0, 0])), 9) % 360.0
    return m[3, :3], heading, scale


def _fmt(values) -> str:
    return "(" + ", ".join(f"{v:.10g}" for v in values) + ")"


def _duplicates(r: _Reading) -> None:
    seen: dict[str, ir.Placement] = {}
    kept = []
    for p in r.placements:
        first = seen.get(p.tag)
        if first is not None:
            r.problem(_name(p.tag, p.dxf_handles), f"duplicate {r.options.tag_attribute}: "
                                                   f"{_name(None, first.dxf_handles)} has it too")
            continue
        seen[p.tag] = p
        kept.append(p)
    r.placements = kept


def _warnings(r: _Reading, doc, platforms: list[ir.Platform], levels) -> list[str]:
    out = []
    if r.left_out:
        listed = ", ".join(f"{b} x{n}" for b, n in sorted(r.left_out.items(), key=lambda kv: (-kv[1], kv[0])))
        near = {b: _near_asset(r, b) for b in sorted(r.left_out)}
        hint = "".join(f"; did {b!r} mean asset {a!r}?" for b, a in near.items() if a)
        out.append(f"{sum(r.left_out.values())} INSERTs of {len(r.left_out)} blocks place nothing and are left "
                   f"out: {listed} (map a block to an asset in site.toml [floorplan] blocks to "
                   f"place it){hint}")
    if r.scaled and r.options.insert_scale == "ignore":
        factors = ", ".join(f"{k:g} x{n}" for k, n in sorted(r.scaled.items(), key=lambda kv: (-kv[1], kv[0])))
        out.append(f"{sum(r.scaled.values())} INSERTs are drawn scaled ({factors}) and placed at scale 1: "
                   'site.toml [floorplan] insert_scale = "ignore" (set "apply" to place them at their scale)')
    if not r.placements:
        met = ", ".join(f"{b} x{n}" for b, n in sorted(r.inserts.items(), key=lambda kv: (-kv[1], kv[0])))
        out.append(f"no placements: {sum(r.inserts.values())} INSERTs of {len(r.inserts)} blocks"
                   + (f" ({met})" if met else "") + " and none of a block mapped to an asset "
                   "(site.toml [floorplan] blocks) or named by one")
    if not platforms:
        wanted = ", ".join(f"{PLATFORM_PREFIX}{lv}" for lv in sorted(levels)) if levels else f"{PLATFORM_PREFIX}<level>"
        closed = Counter(e.dxf.layer for e in doc.modelspace().query("LWPOLYLINE") if e.closed)
        found = ", ".join(f"{layer} x{n}" for layer, n in sorted(closed.items(), key=lambda kv: (-kv[1], kv[0])))
        out.append(f"no platforms: the terrain is built from closed LWPOLYLINEs on layers {wanted}, one around "
                   "each terrace" + (f" (the drawing's closed LWPOLYLINEs are on layers {found}: put the terrace "
                                     "outlines on the PLATFORM_ layers)" if found else ""))
    return out


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


def read_floorplan_memo(path: Path, assets: set[str], levels: set[str], memo: Path | None,
                        options=None) -> ir.FloorPlan:
    """read_floorplan, or its result from `memo` when the DXF's content, the known
    assets and levels, the options and the reader's code are what they were. Only
    successful reads are kept (a bad plan raises its error every time), as JSON: a
    build folder may be shared, so nothing in it is unpickled."""
    import hashlib
    import json
    from dataclasses import asdict

    from ..files import atomic_write

    # one spelling of the path: the planner is handed a relative sources folder and the
    # scene tasks an absolute one. It is not in the key (the same drawing in a moved
    # sources folder reads the same); a remembered reading gets the path of this one.
    path = Path(path).resolve()
    key = None
    if memo is not None and path.is_file():
        h = hashlib.sha256(path.read_bytes())
        h.update(json.dumps([sorted(assets), sorted(levels), options and asdict(options)]).encode())
        for module in (Path(__file__), Path(ir.__file__)):  # the reader's code
            h.update(module.read_bytes())
        key = h.hexdigest()
        try:
            doc = json.loads(memo.read_text())
            if doc.get("key") == key:
                return _floorplan_from_json({**doc["floorplan"], "path": str(path)})
        except (OSError, ValueError, KeyError, TypeError):
            pass
    fp = read_floorplan(path, known_assets=assets, levels=levels, options=options)
    if key is not None:
        atomic_write(memo, json.dumps({"key": key, "floorplan": _floorplan_to_json(fp)}, sort_keys=True))
    return fp


def _floorplan_to_json(fp: ir.FloorPlan) -> dict:
    from dataclasses import asdict

    return {"path": fp.path, "units": fp.units, "placements": [asdict(p) for p in fp.placements],
            "platforms": [{"level": p.level, "outline": p.outline.tolist(), "handle": p.handle} for p in fp.platforms],
            "ignored": [list(i) for i in fp.ignored], "inserts": [list(i) for i in fp.inserts],
            "warnings": list(fp.warnings), "absorbed": [list(i) for i in fp.absorbed],
            "conductor_lines": [[h, layer, [list(v) for v in pts]] for h, layer, pts in fp.conductor_lines]}


def _floorplan_from_json(d: dict) -> ir.FloorPlan:
    return ir.FloorPlan(path=d["path"], units=d["units"],
                        placements=tuple(ir.Placement(**{**p, "dxf_handles": tuple(p["dxf_handles"])})
                                         for p in d["placements"]),
                        platforms=tuple(ir.Platform(p["level"], p["outline"], p["handle"]) for p in d["platforms"]),
                        ignored=tuple((str(k), int(n)) for k, n in d["ignored"]),
                        inserts=tuple((str(k), int(n)) for k, n in d["inserts"]),
                        warnings=tuple(str(w) for w in d["warnings"]),
                        absorbed=tuple((str(k), int(n)) for k, n in d.get("absorbed", ())),
                        conductor_lines=tuple((str(h), str(layer), tuple((float(x), float(y)) for x, y in pts))
                                              for h, layer, pts in d.get("conductor_lines", [])))
