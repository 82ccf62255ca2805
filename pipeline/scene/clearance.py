"""Conductor clearances at maximum temperature, against a table of the sources
(sources/clearances.toml, schemas/clearances.schema.json), as findings:

WIRE001 a span's lowest point nearer the ground under it than its level's ground clearance
WIRE002 two spans of different electrical nodes nearer than the phase-to-phase clearance
WIRE003 a span's sag over its horizontal length beyond the table's limit

Each span is carried to its type's maximum temperature by the change-of-state
equation (hotter: longer, lower). An electrical node is what conducts without a
switch being opened: spans sharing a terminal, and every terminal of one placement
(a closed breaker, a CT, a bushing's two ends), join one node. A span without a
voltage level, or whose level is not in the table, is not checked (and counted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import config
from ..errors import UserError
from ..findings import Finding, finding
from ..geometry import catenary as cat
from ..geometry.wires import close_pairs
from .conductors import Span

GROUND_SAMPLES = 64  # points per span where the ground under it is looked up


@dataclass(frozen=True)
class Level:
    voltage_kv: float
    phase_to_ground_m: float
    phase_to_phase_m: float
    ground_m: float
    max_sag_ratio: float


def load_table(path: Path) -> dict[float, Level]:
    """voltage (kV) -> its clearances, from the table file."""
    data = config.read_toml(path)
    config.validate(data, "clearances", Path(path))
    out = {}
    for i, row in enumerate(data["levels"]):
        kv = float(row["voltage_kv"])
        if kv in out:
            raise UserError(path, f"levels[{i}].voltage_kv", f"{kv:g} kV is given twice")
        out[kv] = Level(kv, float(row["phase_to_ground_m"]), float(row["phase_to_phase_m"]), float(row["ground_m"]),
                        float(row.get("max_sag_ratio", math.inf)))
    return out


def hot(span: Span) -> cat.Catenary:
    """The span's curve at its type's maximum temperature."""
    c, t = span.curve, span.ctype
    if t.max_temperature_c == span.temperature_c or c.straight:
        return c
    H = cat.change_of_state(c.p0, c.p1, t.w, t.ea, t.alpha_per_k, span.tension_n, span.temperature_c, t.max_temperature_c)
    return cat.from_tension(c.p0, c.p1, H, t.w)


def nodes(spans: list[Span], tag_of_terminal=lambda ref: ref[0]) -> list[int]:
    """Electrical node (an integer) of each span: union-find over terminals, every
    span joining its ends and every placement joining its terminals."""
    parent: dict = {}

    def find(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def join(a, b):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)

    for s in spans:
        for end in (s.spec.start, s.spec.end):
            join(("terminal", end), ("placement", tag_of_terminal(end)))
        join(("terminal", s.spec.start), ("terminal", s.spec.end))
    roots = sorted({find(("terminal", s.spec.start)) for s in spans})
    index = {r: i for i, r in enumerate(roots)}
    return [index[find(("terminal", s.spec.start))] for s in spans]


def check(spans: list[Span], table: dict[float, Level], ground) -> tuple[list[Finding], dict]:
    """Findings of every span with a level in the table; `ground(en (k, 2)) -> z (k,)`
    the terrain height (NaN off the terrain). Returns the findings and counts."""
    levels = [table.get(float(s.spec.voltage_kv)) if s.spec.voltage_kv else None for s in spans]
    checked = [i for i, lv in enumerate(levels) if lv is not None]
    curves = {i: hot(spans[i]) for i in checked}
    points = {i: cat.points(curves[i], spans[i].lods[0].segments) for i in checked}
    dense = {i: cat.points(curves[i], max(spans[i].lods[0].segments, GROUND_SAMPLES)) for i in checked}
    heights = ground(np.concatenate([dense[i][:, :2] for i in checked])) if checked else np.zeros(0)
    at = np.cumsum([0] + [len(dense[i]) for i in checked])
    out: list[Finding] = []
    for k_, i in enumerate(checked):
        s, lv, c = spans[i], levels[i], curves[i]
        pts = dense[i]
        z = heights[at[k_]:at[k_ + 1]]
        above = pts[:, 2] - z
        k = int(np.nanargmin(above)) if np.isfinite(above).any() else -1
        if k >= 0 and above[k] < lv.ground_m:
            out.append(finding("WIRE001", f"conductor {s.id}",
                               f"{above[k]:.3f} m above the ground at {s.ctype.max_temperature_c:g} C, under the "
                               f"{lv.ground_m:g} m of {lv.voltage_kv:g} kV"))
        if c.L > 0 and cat.sag(c) / c.L > lv.max_sag_ratio:
            out.append(finding("WIRE003", f"conductor {s.id}",
                               f"sag {cat.sag(c):.3f} m over {c.L:.3f} m ({cat.sag(c) / c.L:.3f}) at "
                               f"{s.ctype.max_temperature_c:g} C, beyond {lv.max_sag_ratio:g} for {lv.voltage_kv:g} kV"))
    out += _phase_to_phase(spans, levels, checked, points)
    return sorted(out, key=lambda f: (f.code, f.site, f.message)), {"spans_checked": len(checked),
                                                                       "spans_without_level": len(spans) - len(checked)}


def _phase_to_phase(spans, levels, checked, points) -> list[Finding]:
    node = dict(zip(checked, nodes([spans[i] for i in checked])))
    reach = max(levels[i].phase_to_phase_m + 2.0 * spans[i].radius for i in checked) if checked else 0.0
    out = []
    for (p, q), d in sorted(close_pairs([points[i] for i in checked], reach).items()):
        i, j = checked[p], checked[q]
        if node[i] == node[j]:
            continue
        need = max(levels[i].phase_to_phase_m, levels[j].phase_to_phase_m) + spans[i].radius + spans[j].radius
        if d < need:
            a, b = sorted([spans[i].id, spans[j].id])
            out.append(finding("WIRE002", f"conductor {a}",
                               f"{d:.3f} m from conductor {b} (another node) at maximum temperature, under the "
                               f"{need:.3f} m phase-to-phase clearance (with the bundle radii)"))
    return out
