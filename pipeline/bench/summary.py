"""The summary table: one row per comparison, our figure beside the peer's measured in
the same run, ratio = ours / peer (below 1 means ours is smaller: faster, lighter or
more accurate, as the row's unit says). Rows whose inputs are missing are left out."""

from __future__ import annotations

import statistics


def _row(section: str, metric: str, ours, peer, unit: str, peer_name: str, note: str = "") -> dict | None:
    if ours is None or peer is None:
        return None
    ratio = ours / peer if peer else None
    return {"section": section, "metric": metric, "ours": float(ours), "peer": float(peer), "unit": unit,
            "peer_name": peer_name, "ratio": None if ratio is None else float(ratio), "note": note}


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def rows(sections: dict) -> list[dict]:
    data = {k: v["data"] for k, v in sections.items() if v.get("ok")}
    out = []
    out += _lod_rows(data.get("lod"))
    out += _georef_rows(data.get("georef"))
    out += _sun_rows(data.get("sun"))
    out += _runtime_rows(data.get("runtime"), data.get("blender_reexport"))
    out += _blender_rows(data.get("blender"))
    out += _gltf_transform_rows(data.get("gltf_transform"))
    out += _render_rows(data.get("render"))
    out += _gazebo_rows(data.get("gazebo"))
    out += _moving_parts_rows(data.get("scale"))
    out += _viewer_rows(data.get("viewer"))
    out += _dataset_rows(data.get("dataset"))
    out += _live_rows(data.get("live"))
    return [r for r in out if r is not None]


def _live_rows(d):
    """A render on request from the live twin's kept scene against the dataset's steady
    frame (goal: at most 1.0x)."""
    r = (d or {}).get("render") or {}
    if not r.get("dataset_steady_frame_s"):
        return []
    return [_row("live", "s per render on request", r["render_median_s"], r["dataset_steady_frame_s"], "s",
                 "twin dataset, steady frame", f"{r['frame']}, after a warm-up")]


def _dataset_rows(d):
    """Seconds per labelled frame: dask against the local pool at the same worker count,
    two workers against one, and our scene kept between frames against the study's
    import-and-render per frame."""
    if not d or "runs" not in d:
        return []
    r = d["runs"]
    note = f"{d['frame']}, {r['local_1']['frames']} frames of {d['config']}"
    return [_row("dataset", "s per frame, dask 2 workers", r["dask_2"]["seconds_per_frame"],
                 r["local_2"]["seconds_per_frame"], "s", "local pool, 2 workers", note),
            _row("dataset", "s per frame, 2 workers", r["local_2"]["seconds_per_frame"],
                 r["local_1"]["seconds_per_frame"], "s", "1 worker", note),
            _row("dataset", "s per frame, scene kept", r["local_1"]["seconds_per_frame"],
                 r["per_frame"]["seconds_per_frame"], "s", "the study's method: import and render per frame", note),
            *_label_rows(d.get("labels"), r, note), *_sun_in_view_rows(d.get("sun_in_view"), d["frame"])]


def _label_rows(labels, r, note):
    """The label pass after issue 38 against the one before, measured in the same run."""
    if not labels or "labels_before" not in r:
        return []
    same = note + ("; identical files" if labels["identical"] else "; FILES DIFFER")
    return [_row("dataset", "s per frame, labels included", labels["after"]["steady_frame_median_s"],
                 labels["before"]["steady_frame_median_s"], "s", "the label pass sampled as light (before)", same),
            _row("dataset", "s per label pass", labels["after"]["labels_median_s"],
                 labels["before"]["labels_median_s"], "s", "the label pass sampled as light (before)", same)]


def _sun_in_view_rows(sun, note):
    """Labels where the sun is in the picture: annotations that are not their masks."""
    if not sun or "annotations" not in sun:
        return []
    return [_row("dataset", "annotations not their masks, sun in view", len(sun["problems"]), sun["annotations"],
                 "count", "annotations checked", f"{note}; {sun['rendered']} of {sun['sun_in_view']} frames "
                                                  f"with the sun in view of {sun['planned']} planned")]


def _viewer_rows(d):
    """The 3D Tiles against the scene .glb they are made from; the scene page against
    the globe page showing the tiles (both in headless Chromium on SwiftShader)."""
    if not d:
        return []
    size = d["sizes"]
    out = [_row("viewer", "tileset size", size["tileset_total"] / 2**20, size["scene_glb"] / 2**20, "MB",
                "the scene .glb", f"{size['tiles']} tiles, meshes stored once per model and level")]
    page, globe = d.get("page"), d.get("globe")
    if page and globe:
        width, height = page["size_px"]
        note = f"Chromium headless, WebGL on SwiftShader (CPU), {width}x{height}"
        out += [_row("viewer", "page load to first drawn frame", page["first_frame_s"], globe["first_frame_s"], "s",
                     "CesiumJS globe of the tiles", note),
                _row("viewer", "browser memory (PSS)", page["pss_mb"], globe["pss_mb"], "MB",
                     "CesiumJS globe of the tiles", note)]
    return out


def _gazebo_rows(d):
    """The world as written against one include per placement (the earlier layout)."""
    before = (d or {}).get("one_include_per_placement")
    if not before:
        return []
    note = f"sdf::Root::Load of the sample world, {d['placements']} placements (tools/gzprobe)"
    return [_row("gazebo", "world parse peak memory", d["world"]["peak_rss_mb"], before["peak_rss_mb"], "MB",
                 "one <include> per placement", note),
            _row("gazebo", "world parse time", d["world"]["parse_s"], before["parse_s"], "s",
                 "one <include> per placement", note)]


def _moving_parts_rows(d):
    """The large plan's Gazebo world with its switches on joints ([gazebo] moving_parts
    "all") against the same world with them drawn at rest ("none"), probed one after
    the other in the scale section."""
    sides = (d or {}).get("sides", {})
    moving, frozen = sides.get("moving_all"), sides.get("moving_none")
    if not moving or not frozen:
        return []
    peer = '[gazebo] moving_parts = "none"'
    note = (f"ours: \"all\"; {moving['placements']:,} placements (plans.at_scale), "
            f"{moving['elements'].get('joints', 0):,} joints against {frozen['elements'].get('joints', 0):,}; "
            f"tools/gzprobe; load {moving['load_avg'][0]:.1f} and {frozen['load_avg'][0]:.1f}")
    out = [_row("scale", "Gazebo world parse peak memory", moving["world"].get("peak_rss_mb"),
                frozen["world"].get("peak_rss_mb"), "MB", peer, note),
           _row("scale", "Gazebo world parse time", moving["world"].get("parse_s"), frozen["world"].get("parse_s"),
                "s", peer, note),
           _row("scale", "Gazebo world parse CPU time", moving["world"].get("parse_cpu_s"),
                frozen["world"].get("parse_cpu_s"), "s", peer, note)]
    rtf, rtf_peer = moving["physics"].get("real_time_factor"), frozen["physics"].get("real_time_factor")
    if rtf and rtf_peer:  # wall seconds per simulated second: below 1 is faster than real time
        out.append(_row("scale", "dartsim (bullet) wall s per simulated s", 1.0 / rtf, 1.0 / rtf_peer, "s", peer, note))
    return out


def _lod_rows(d):
    if not d:
        return []
    runs = [r for r in d["runs"] if not r["crashed"]]
    ref = {(r["mesh"], r["ratio"]): r for r in runs if r["method"] == "pymeshlab"}
    ours = [r for r in runs if r["method"] == "meshoptimizer" and (r["mesh"], r["ratio"]) in ref]
    if not ours:
        return []
    e = [r["error_m"] for r in ours]
    ep = [ref[(r["mesh"], r["ratio"])]["error_m"] for r in ours]
    t = [r["time"]["median_s"] for r in ours]
    tp = [ref[(r["mesh"], r["ratio"])]["time"]["median_s"] for r in ours]
    note = f"medians over {len(ours)} mesh x ratio pairs at matched triangle counts"
    return [_row("lod", "simplification error (Hausdorff)", statistics.median(e), statistics.median(ep), "m",
                 "pymeshlab quadric collapse", note),
            _row("lod", "simplification time", statistics.median(t), statistics.median(tp), "s",
                 "pymeshlab quadric collapse", note)]


def _georef_rows(d):
    if not d:
        return []
    return [_row("georef", "cost per million points", d["exact_per_million"]["median_s"],
                 d["naive_per_million"]["median_s"], "s", "naive E-E0, N-N0",
                 f"naive method's error up to {d['naive_error_max_m']:.3f} m over the plotted area; ours is the reference")]


def _sun_rows(d):
    rb = _get(d, "runtime_bench")
    if not rb:
        return []
    ours = _get(rb, "astral_vs_spa_deg", "max")
    peer = _get(rb, "study_vs_spa_deg", "max")
    return [_row("sun", "max elevation error vs pvlib SPA over a year", ours, peer, "deg",
                 "study's 90 sin(pi tau)", "ours: astral NOAA ephemeris")]


def _runtime_rows(rt, rex):
    ours_step = _get(rt, "sample", "sample_incremental_step", "median_s")
    apply = _get(rt, "usd", "usd_apply_state", "median_s")
    peer = _get(rex, "step", "median_s")
    if ours_step is None or peer is None:
        return []
    return [_row("runtime", "one state step (incremental step + USD apply)", ours_step + (apply or 0.0), peer, "s",
                 "Blender re-export of the model per step (the study)", f"Blender: {rex.get('asset')}")]


def _blender_rows(d):
    if not d:
        return []
    loads = d.get("loads", {})

    def load(prefix, suffix, what):
        for k, v in loads.items():
            if k.startswith(prefix) and k.endswith(suffix):
                return _get(v, what, "median" if what == "maxrss" else "median_s")
        return None

    scene = _get(d, "ours_scene_build", "median_s")
    out = [
        _row("blender", "whole-scene write (ours: terrain+scene build, CLI)", scene, _get(d, "export_gltf", "median_s"),
             "s", "Blender export_scene.gltf, one file"),
        _row("blender", "whole-scene write (ours: terrain+scene build, CLI)", scene, _get(d, "export_usd", "median_s"),
             "s", "Blender wm.usd_export, one file"),
        _row("blender", "scene .glb size", _ours_file(d, ".glb"),
             d.get("blender_glb_bytes"), "bytes", "Blender monolithic .glb"),
        _row("blender", "scene USD size (stage + referenced layers)",
             _ours_file(d, ".usda"),
             d.get("blender_usd_bytes"), "bytes", "Blender monolithic .usdc"),
        _row("blender", "load time in Blender (.glb)", load("ours:", ".glb", "time"),
             load("blender_monolithic", ".glb", "time"), "s", "Blender monolithic .glb"),
        _row("blender", "load time in Blender (USD)", load("ours:", ".usda", "time"),
             load("blender_monolithic", ".usdc", "time"), "s", "Blender monolithic .usdc"),
        _row("blender", "peak memory loading in Blender (.glb)", load("ours:", ".glb", "maxrss"),
             load("blender_monolithic", ".glb", "maxrss"), "bytes", "Blender monolithic .glb"),
        _row("blender", "peak memory loading in Blender (USD)", load("ours:", ".usda", "maxrss"),
             load("blender_monolithic", ".usdc", "maxrss"), "bytes", "Blender monolithic .usdc"),
    ]
    return out


def _ours_file(d, suffix):
    sizes = [v for k, v in sorted(d.get("ours_bytes", {}).items()) if k.endswith(suffix)]
    return sizes[0] if sizes else None


def _gltf_transform_rows(d):
    if not d:
        return []
    out = []
    simp = d.get("simplify", [])
    if simp:
        eo = [r["ours"]["error_m"] for r in simp]
        et = [r["gltf_transform"]["error_m"] for r in simp]
        out.append(_row("gltf_transform", "coarsest-LOD error at matched count (median over models)",
                        statistics.median(eo), statistics.median(et), "m", "gltf-transform weld+simplify",
                        f"{len(simp)} models; same metric for both"))
        to = [r["ours"]["lod_step_seconds"] for r in simp if r["ours"]["lod_step_seconds"] is not None]
        tt = [r["gltf_transform"]["time"]["median_s"] for r in simp if r["ours"]["lod_step_seconds"] is not None]
        if to:
            out.append(_row("gltf_transform", "LOD time per model (median; ours: every level, checked)",
                            statistics.median(to), statistics.median(tt), "s", "gltf-transform weld+simplify (one level)",
                            "theirs includes Node start-up"))
    for r in d.get("scene", []):
        if r["input"].startswith("ours:"):
            out.append(_row("gltf_transform", f"our scene .glb size vs after gltf-transform {r['op']}",
                            r["bytes_in"], r["bytes_out"], "bytes", f"gltf-transform {r['op']}",
                            "ratio near 1: nothing left to deduplicate or instance"))
    return out


def _render_rows(d):
    if not d or "ours" not in d:
        return []
    ours, peer = d["ours"], d["blender_defaults"]
    rows = [_row("render", "gauge close-up frame, Cycles CPU", ours["median_s"], peer["median_s"], "s",
                 "Cycles at Blender's factory light paths, 16 raw samples", f"{ours['frame']}; target under 2 s")]
    if "rmse_8bit" in ours and "rmse_8bit" in peer:
        rows.append(_row("render", "frame error vs converged reference (RMS, 8-bit levels, before ISP)",
                         ours["rmse_8bit"], peer["rmse_8bit"], "levels",
                         "Cycles at Blender's factory light paths, 16 raw samples", ours["reference"]))
    return rows

