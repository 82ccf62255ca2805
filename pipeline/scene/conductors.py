"""The conductors of a scene: terminals placed, floor-plan lines snapped to them, each
span solved as a catenary at the site's conductor temperature, its LOD polylines with
their measured chord error, the check that no two spans touch, and conductors.json.

Every problem (a missing terminal, a line end that snaps to nothing, a span with no
catenary, two spans that touch) names its conductor; all of them make one UserError.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import wiring as wsrc
from ..errors import UserError
from ..geometry import catenary as cat
from ..geometry.wires import bundle_paths, close_pairs
from ..export.names import SCENE_ROOT, safe_name
from .placements import Placed, screen_error_px

TOUCH_MARGIN_M = 0.0  # spans closer than the sum of their bundle radii (plus this) touch


@dataclass(frozen=True, eq=False)
class SpanLod:
    """One LOD of a span: its bundle-centre polyline (segments + 1, 3) ENU and the
    measured largest distance from it to the true curve (m)."""

    budget_m: float
    points: np.ndarray
    chord_error_m: float

    @property
    def segments(self) -> int:
        return len(self.points) - 1


@dataclass(frozen=True, eq=False)
class Span:
    spec: wsrc.SpanSpec
    ctype: wsrc.ConductorType
    curve: cat.Catenary
    tension_n: float  # horizontal, at temperature_c
    temperature_c: float
    lods: tuple[SpanLod, ...]
    lod: int = 0
    distance_m: float = math.inf

    @property
    def id(self) -> str:
        return self.spec.id

    @property
    def radius(self) -> float:
        """Radius of the bundle's envelope (a single conductor: half its diameter)."""
        offsets = self.ctype.bundle_offsets()
        return float(np.max(np.linalg.norm(offsets, axis=1))) + self.ctype.diameter_m / 2.0

    def paths(self, lod: int | None = None) -> list[np.ndarray]:
        """Each subconductor's polyline at `lod` (default: the chosen one)."""
        pts = self.lods[self.lod if lod is None else lod].points
        return bundle_paths(pts, self.curve.direction, self.ctype.bundle_offsets())


def terminal_points(placed: list[Placed], manifests: dict[str, dict]) -> dict[tuple[str, str], np.ndarray]:
    """(tag, terminal) -> (3,) ENU of every placed terminal."""
    out = {}
    for pl in placed:
        for t in manifests[pl.placement.asset_id].get("terminals", []):
            out[(pl.placement.tag, t["name"])] = pl.pose[:3, :3] @ np.asarray(t["position"], dtype=np.float64) + pl.pose[:3, 3]
    return out


def snap_lines(lines, wiring: wsrc.Wiring, georef, height: float,
               terminals: dict[tuple[str, str], np.ndarray], plan: str) -> tuple[list[wsrc.SpanSpec], list[str]]:
    """Spans of the floor plan's conductor lines: each vertex snaps to the nearest
    terminal within the snap tolerance (horizontal distance in the scene frame); each
    pair of consecutive vertices is a span with its layer's settings. `lines`: the
    floor plan's conductor_lines, (handle, layer, plan vertices)."""
    from scipy.spatial import cKDTree

    if not lines:
        return [], []
    keys = sorted(terminals)
    tree = cKDTree(np.array([terminals[k][:2] for k in keys])) if keys else None
    tol = wiring.snap_tolerance_m
    xy = np.array([v for _, _, vertices in lines for v in vertices], dtype=np.float64)
    enu = georef.to_enu(xy, np.full(len(xy), height))[:, :2]
    specs, problems, k = [], [], 0
    for handle, layer, vertices in lines:
        lay = wiring.layers[layer]
        refs = []
        for x, y in vertices:
            where = f"{plan}: {layer} {'LINE' if len(vertices) == 2 else 'LWPOLYLINE'} #{handle} end ({x:.3f}, {y:.3f})"
            point = enu[k]
            k += 1
            found = tree.query_ball_point(point, tol) if tree is not None else []
            if not found:
                near = "" if tree is None else f" (nearest {'.'.join(keys[tree.query(point)[1]])} at {tree.query(point)[0]:.3f} m)"
                problems.append(f"conductor {where}: snaps to no terminal within {tol:g} m{near}")
                refs.append(None)
                continue
            d = np.linalg.norm(np.array([terminals[keys[i]][:2] for i in found]) - point, axis=1)
            refs.append(keys[found[int(np.argmin(d))]])
        for i, (a, b) in enumerate(zip(refs[:-1], refs[1:])):
            if a is None or b is None:
                continue
            sid = wsrc.span_id(a, b)
            if a == b:
                problems.append(f"conductor {sid} ({plan}: #{handle} segment {i}): both ends snap to {'.'.join(a)}")
                continue
            specs.append(wsrc.SpanSpec(sid, a, b, lay["type"], float(lay.get("temperature_c", wiring.temperature_c)),
                                       lay.get("tension_n"), None, lay.get("sag_ratio"), lay.get("voltage_kv"),
                                       f"{plan}: {layer} #{handle}"))
    return specs, problems


def solve_curve(spec: wsrc.SpanSpec, ctype: wsrc.ConductorType, p0: np.ndarray, p1: np.ndarray,
                temperature_c: float) -> tuple[cat.Catenary, float]:
    """The span's curve and horizontal tension at `temperature_c`: from its tension
    or sag at its own reference temperature, carried over by the change-of-state
    equation."""
    w = ctype.w
    if spec.tension_n is not None:
        h_ref = float(spec.tension_n)
    else:
        sag = spec.sag_m if spec.sag_m is not None else spec.sag_ratio * float(np.hypot(*(p1 - p0)[:2]))
        h_ref = cat.from_sag(p0, p1, sag).a * w
    tension = cat.change_of_state(p0, p1, w, ctype.ea, ctype.alpha_per_k, h_ref, spec.temperature_c, temperature_c)
    return cat.from_tension(p0, p1, tension, w), tension


def with_lods(solved: list[tuple[wsrc.SpanSpec, wsrc.ConductorType, cat.Catenary, float]], temperature_c: float,
              budgets: tuple[float, ...]) -> list[Span]:
    """Spans of solved curves (spec, type, curve, tension), with a polyline per LOD
    budget: the fewest segments whose measured chord error is within it (all spans'
    counts measured together)."""
    curves = [c for _, _, c, _ in solved]
    levels = [cat.segments_for_many(curves, b) for b in budgets]
    return [Span(spec, ctype, c, tension, temperature_c,
                 tuple(SpanLod(b, cat.points(c, int(n[i])), float(e[i])) for b, (n, e) in zip(budgets, levels)))
            for i, (spec, ctype, c, tension) in enumerate(solved)]


def solve_span(spec: wsrc.SpanSpec, ctype: wsrc.ConductorType, p0: np.ndarray, p1: np.ndarray,
               temperature_c: float, budgets: tuple[float, ...]) -> Span:
    """One span at `temperature_c` with its LOD polylines (solve_curve, with_lods)."""
    curve, tension = solve_curve(spec, ctype, p0, p1, temperature_c)
    return with_lods([(spec, ctype, curve, tension)], temperature_c, budgets)[0]


def choose_lod(spans: list[Span], eyes: np.ndarray, site) -> list[Span]:
    """Per span the coarsest LOD whose chord error, seen from the nearest inspection
    point (to the nearest vertex of its finest polyline), stays under the site's
    screen tolerance; no inspection point: LOD 0."""
    import dataclasses

    if len(eyes) == 0:
        return spans
    out = []
    for s in spans:
        d = float(np.min(np.linalg.norm(s.lods[0].points[:, None, :] - eyes[None], axis=2)))
        lod = 0
        for k, level in enumerate(s.lods):
            px = screen_error_px(level.chord_error_m, d, site.reference_hfov_rad, site.reference_width_px)
            if px <= site.screen_tolerance_px:
                lod = k
        out.append(dataclasses.replace(s, lod=lod, distance_m=d))
    return out


def touching(spans: list[Span]) -> list[str]:
    """Pairs of spans (not sharing a terminal) closer than the sum of their bundle
    radii, measured segment to segment on their finest polylines."""
    if len(spans) < 2:
        return []
    reach = 2.0 * max(s.radius for s in spans) + TOUCH_MARGIN_M
    problems = []
    for (i, j), d in sorted(close_pairs([s.lods[0].points for s in spans], reach).items()):
        a, b = spans[i], spans[j]
        if {a.spec.start, a.spec.end} & {b.spec.start, b.spec.end} or d >= a.radius + b.radius + TOUCH_MARGIN_M:
            continue
        first, second = sorted([a.id, b.id])
        problems.append(f"conductor {first}: crosses conductor {second} ({d:.3f} m apart, "
                        f"bundle radii {a.radius:.3f} + {b.radius:.3f} m)")
    return sorted(problems)


def build(site, wiring: wsrc.Wiring, placed: list[Placed], manifests: dict[str, dict], georef,
          eyes: np.ndarray, lines=()) -> list[Span]:
    """Every span of the site, solved, LOD chosen, checked; UserError listing every
    problem. `lines`: the floor plan's conductor_lines. A site without conductors gives []."""
    if wiring.empty:
        return []
    terminals = terminal_points(placed, manifests)
    plan = site.floorplan
    height = georef.origin_llh[2]
    from_plan, problems = snap_lines(lines, wiring, georef, height, terminals, plan)
    by_tag = {pl.placement.tag: pl.placement.asset_id for pl in placed}
    solved, seen = [], {}
    for spec in (*wiring.specs, *from_plan):
        where = f"conductor {spec.id} ({spec.origin})"
        if spec.id in seen:
            problems.append(f"{where}: the same span as {seen[spec.id]}")
            continue
        seen[spec.id] = spec.origin
        ends = []
        for tag, name in (spec.start, spec.end):
            if (tag, name) in terminals:
                ends.append(terminals[(tag, name)])
            elif tag not in by_tag:
                problems.append(f"{where}: no placement is tagged {tag!r}")
            else:
                have = sorted(t["name"] for t in manifests[by_tag[tag]].get("terminals", []))
                problems.append(f"{where}: {tag} ({by_tag[tag]}) has no terminal {name!r} "
                                f"(it has: {', '.join(have) or 'none'})")
        if len(ends) < 2:
            continue
        try:
            ctype = wiring.types[spec.type]
            solved.append((spec, ctype, *solve_curve(spec, ctype, ends[0], ends[1], wiring.temperature_c)))
        except cat.CatenaryError as e:
            problems.append(f"{where}: {e}")
    spans = with_lods(solved, wiring.temperature_c, wiring.lod_chord_errors_m)
    problems += touching(spans)
    if problems:
        raise UserError(site.path, "conductors", wsrc._listing(problems))
    return choose_lod(sorted(spans, key=lambda s: s.id), eyes, site)


def prim_names(spans: list[Span]) -> dict[str, str]:
    """span id -> a USD/SDF-safe name, unique (a suffix where two ids spell alike)."""
    out, used = {}, set()
    for s in spans:
        name = base = safe_name(s.id)
        k = 1
        while name in used:
            k += 1
            name = f"{base}_{k}"
        used.add(name)
        out[s.id] = name
    return out


def _r(values, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in values]


def record(spans: list[Span], wiring: wsrc.Wiring) -> dict:
    """conductors.json: per span its ends, type, H, w, temperature, sag, length, the
    LOD chosen and every LOD's points with its measured chord error; lengths to the
    micrometre, tensions to the millinewton."""
    types = sorted({s.ctype.name for s in spans})
    names = prim_names(spans)
    return {
        "frame": "ENU metres at the scene origin (placements.json origin)",
        "temperature_c": wiring.temperature_c,
        "lod_chord_errors_m": list(wiring.lod_chord_errors_m),
        "types": {n: {"diameter_m": t.diameter_m, "mass_kg_per_m": t.mass_kg_per_m, "ea_n": t.ea_n,
                      "alpha_per_k": t.alpha_per_k, "bundle_count": t.bundle_count,
                      "bundle_spacing_m": t.bundle_spacing_m, "max_temperature_c": t.max_temperature_c,
                      "bundle_offsets_m": [_r(o) for o in t.bundle_offsets()], **_resistance(t)}
                  for n, t in ((n, wiring.types[n]) for n in types)},
        "spans": [{
            "id": s.id, "type": s.ctype.name, "source": s.spec.origin, "usd_path": f"{SCENE_ROOT}/Conductors/{names[s.id]}",
            "from": {"terminal": ".".join(s.spec.start), "enu": _r(s.curve.p0)},
            "to": {"terminal": ".".join(s.spec.end), "enu": _r(s.curve.p1)},
            **({"voltage_kv": s.spec.voltage_kv} if s.spec.voltage_kv else {}),
            "tension_n": round(s.tension_n, 3), "weight_n_per_m": round(s.ctype.w, 6),
            "temperature_c": s.temperature_c, "sag_m": round(cat.sag(s.curve), 6),
            "length_m": round(cat.arc_length(s.curve), 6),
            "span_m": round(math.hypot(s.curve.L, s.curve.h), 6),
            "lod": s.lod, "distance_m": None if not math.isfinite(s.distance_m) else round(s.distance_m, 3),
            "lods": [{"budget_m": lv.budget_m, "segments": lv.segments, "chord_error_m": round(lv.chord_error_m, 9),
                      "points": [_r(p) for p in lv.points]} for lv in s.lods],
        } for s in spans],
    }


def _resistance(t: wsrc.ConductorType) -> dict:
    """The type's AC resistances, for the live twin's thermal node, when conductors.toml gives them."""
    if t.resistance_ohm_per_km is None:
        return {}
    return {"r25_ohm_per_km": t.resistance_ohm_per_km[0], "r75_ohm_per_km": t.resistance_ohm_per_km[1]}


def write_record(path: Path, spans: list[Span], wiring: wsrc.Wiring, sdf_variants: list[dict] = ()) -> None:
    """conductors.json, a line per span (the file diffs by span); with the SDF sag
    variants (conductor_outputs.sdf_variants) when there are any."""
    data = record(spans, wiring)
    if sdf_variants:
        data["sdf_variants"] = list(sdf_variants)
    head = {k: v for k, v in data.items() if k != "spans"}
    lines = [json.dumps(s, sort_keys=True, separators=(",", ":")) for s in data["spans"]]
    text = json.dumps(head, sort_keys=True)[:-1] + ', "spans": [\n' + ",\n".join(lines) + "\n]}\n"
    Path(path).write_text(text)
