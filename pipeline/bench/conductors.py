"""The conductors' bench: spans solved per second on a site of 5,000 placements (the
sample's spans tiled), chord error against segment count for typical spans (speed
against error), and the time of the clearance check.

Terminals are read from the sources' asset.toml files (what the manifests carry), so
the section needs no build.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .context import Context

TARGET_PLACEMENTS = 5000
TILE_PITCH_M = 300.0  # copies of the sample side by side along east


def sample_spans(sources: Path):
    """(site, wiring, specs with their end points (spec, p0, p1), placements) of the
    sources, as the scene task would string them."""
    from .. import config, wiring
    from ..georef import Georeferencer, default_origin
    from ..ingest.floorplan import read_floorplan
    from ..scene import conductors, placements as placing

    site = config.load_site(Path(sources) / "site.toml")
    assets = config.asset_ids(Path(sources))
    fp = read_floorplan(site.root / site.floorplan, assets, set(site.level_names), site.floorplan_options)
    georef = Georeferencer(site, site.origin or default_origin(site, fp.platforms))
    placed = placing.place(site, list(fp.placements), georef)
    manifests = {a: {"terminals": [{"name": n, "position": list(p)} for n, p in
                                   config.load_asset_config(Path(sources) / "assets" / a / "asset.toml").terminals]}
                 for a in assets}
    w = wiring.load_wiring(site)
    spans = conductors.build(site, w, placed, manifests, georef, np.zeros((0, 3)), fp.conductor_lines)
    return site, w, [(s.spec, s.ctype, s.curve.p0, s.curve.p1) for s in spans], len(placed)


def tiled(ends, placements: int, target: int):
    """The sample's spans copied side by side until the copies hold `target` placements:
    ((spec, type, p0, p1) with ids made unique, copies)."""
    import dataclasses

    copies = max(1, math.ceil(target / max(placements, 1)))
    out = []
    for k in range(copies):
        shift = np.array([k * TILE_PITCH_M, 0.0, 0.0])
        for spec, ctype, p0, p1 in ends:
            start, end = (f"{spec.start[0]}@{k}", spec.start[1]), (f"{spec.end[0]}@{k}", spec.end[1])
            out.append((dataclasses.replace(spec, id=f"{spec.id}@{k}", start=start, end=end), ctype, p0 + shift, p1 + shift))
    return out, copies


def solve_all(ends, w):
    """Every span solved, LOD polylines measured, the touch check run: (spans, seconds
    of each stage)."""
    from ..scene import conductors

    t0 = time.perf_counter()
    solved = [(spec, ctype, *conductors.solve_curve(spec, ctype, p0, p1, w.temperature_c)) for spec, ctype, p0, p1 in ends]
    t1 = time.perf_counter()
    spans = conductors.with_lods(solved, w.temperature_c, w.lod_chord_errors_m)
    t2 = time.perf_counter()
    touching = conductors.touching(spans)
    t3 = time.perf_counter()
    return spans, {"curves_s": t1 - t0, "lods_s": t2 - t1, "touch_check_s": t3 - t2, "total_s": t3 - t0,
                   "touching": len(touching)}


def chord_curve(spans, counts=(1, 2, 4, 8, 16, 32, 64, 128), repeats: int = 20) -> list[dict]:
    """For the longest strung span, a dropper and the slackest span of the sample:
    measured chord error and the time to make and measure the polyline, per segment
    count."""
    from ..geometry import catenary as cat

    picks = {}
    if spans:
        picks["longest"] = max(spans, key=lambda s: s.curve.L)
        picks["slackest"] = max(spans, key=lambda s: cat.sag(s.curve) / max(s.curve.L, 1e-9))
        drops = [s for s in spans if s.spec.sag_ratio is not None]
        if drops:
            picks["dropper"] = sorted(drops, key=lambda s: s.id)[len(drops) // 2]
    rows = []
    for kind, s in picks.items():
        for n in counts:
            times = []
            for _ in range(repeats):  # the median: a shared machine's hiccups stay out
                t = time.perf_counter()
                cat.points(s.curve, n)
                err = cat.chord_error(s.curve, n)
                times.append(time.perf_counter() - t)
            rows.append({"span": kind, "id": s.id, "span_m": round(math.hypot(s.curve.L, s.curve.h), 3),
                         "sag_m": round(cat.sag(s.curve), 4), "segments": n, "chord_error_m": err,
                         "microseconds": float(np.median(times)) * 1e6})
    return rows


def conductor_section(ctx: Context) -> dict:
    from ..scene import clearance

    site, w, ends, placements = sample_spans(ctx.sources)
    if not ends:
        return {"spans": 0, "note": "the sources string no conductor"}
    target = ctx.pick(1000, TARGET_PLACEMENTS)
    many, copies = tiled(ends, placements, target)
    runs = [solve_all(many, w) for _ in range(ctx.pick(1, 3))]
    spans, _ = runs[0]
    best = min(runs, key=lambda r: r[1]["total_s"])[1]
    out = {"placements": placements * copies, "copies_of_sample": copies, "spans": len(many),
           "sample_spans": len(ends), "seconds": best, "spans_per_s": len(many) / best["total_s"],
           "goal_s": 2.0, "goal_met": best["total_s"] <= 2.0,
           "chord_vs_segments": chord_curve(spans[:len(ends)]),
           "segments_per_lod": [int(sum(s.lods[k].segments for s in spans)) for k in range(len(w.lod_chord_errors_m))]}
    table_path = site.root / site.raw.get("wiring", {}).get("clearances", "clearances.toml")
    if table_path.is_file():
        table = clearance.load_table(table_path)
        ground = -float(site.origin[2] - min(lv.elevation for lv in site.levels)) if site.origin else 0.0
        t = time.perf_counter()
        found, counts = clearance.check(spans, table, lambda en: np.full(len(en), ground))
        out["clearance"] = {"seconds": time.perf_counter() - t, "findings": len(found), **counts,
                            "ground": "flat at the lowest level (the scene reads the built terrain instead)"}
    return out
