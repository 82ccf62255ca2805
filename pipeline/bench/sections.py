"""The measuring sections: LOD simplifiers, georeferencing, sun, runtime, render. Each
returns plain JSON-able data; the harness guards each call, so a failing section
becomes an error entry.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from .context import Context
from .stats import summarize, timed


# --- LOD -----------------------------------------------------------------------------


def _sample_meshes(ctx: Context, count: int) -> dict:
    """LOD0 of the `count` built sample models with the most triangles (one mesh each,
    every visual of the model in the model frame)."""
    from . import glb

    built = ctx.built
    if built is None:
        return {}
    found = []
    for folder in sorted((built / "models").iterdir()):
        path = folder / f"{folder.name}.glb"
        if path.exists() and glb.lod_count(path) > 1:
            v, f = glb.triangles(path)
            found.append((len(f), folder.name, (v, f)))
    found.sort(key=lambda t: (-t[0], t[1]))
    return {f"sample:{name}": mesh for _, name, mesh in found[:count]}


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points (time, error) no other point beats on both (lower is better)."""
    front = []
    for i, (t, e) in enumerate(points):
        if not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for j, (t2, e2) in enumerate(points) if j != i):
            front.append(i)
    return front


def lod_section(ctx: Context) -> dict:
    from .meshes import insulator_mesh, noisy_sphere, sliver_mesh
    from .simplifiers import bench_simplifiers as bench

    if ctx.quick:
        hard = {"insulator": insulator_mesh(sheds=10, segments=48, target_faces=8_000),
                "noisy_sphere": noisy_sphere(subdivisions=4), "slivers": sliver_mesh(n=60)}
    else:
        hard = {"insulator": insulator_mesh(), "noisy_sphere": noisy_sphere(), "slivers": sliver_mesh()}
    meshes = {**hard, **_sample_meshes(ctx, ctx.pick(1, 2))}
    ratios = ctx.pick((0.1,), (0.1, 0.02))
    repeats = 1  # the 20-minute budget: one timing per run (2 repeats double the section)
    # bench_simplifiers times each run once in a child process; call it `repeats` times
    # and keep every duration, the error of the first (errors are deterministic).
    results = [bench(meshes=meshes, ratios=ratios) for _ in range(repeats)]
    runs = results[0]["runs"]
    for i, row in enumerate(runs):
        times = [r["runs"][i].get("seconds") for r in results]
        times = [t for t in times if t is not None]
        if times:
            row["time"] = summarize(times)
    for name in meshes:
        rows = [r for r in runs if r["mesh"] == name and not r["crashed"]]
        front = pareto([(r["time"]["median_s"], r["error_m"]) for r in rows])
        for k, r in enumerate(rows):
            r["pareto"] = k in front
    return {"runs": runs, "summary": results[0].get("summary", {}), "ratios": list(ratios),
            "meshes": {k: {"vertices": int(len(v)), "faces": int(len(f))} for k, (v, f) in meshes.items()}}


# --- georeferencing -------------------------------------------------------------------


def _site(sources: Path):
    from .. import config
    from ..georef import Georeferencer, default_origin
    from ..ingest.floorplan import read_floorplan

    site = config.load_site(Path(sources) / "site.toml")
    platforms = list(read_floorplan(site.root / site.floorplan, levels=set(site.level_names)).platforms)
    origin = site.origin or default_origin(site, platforms)
    return site, platforms, Georeferencer(site, origin)


def georef_section(ctx: Context) -> dict:
    from .georef import bench_georef

    site, platforms, g = _site(ctx.sources)
    n = ctx.pick(100_000, 1_000_000)
    data: dict = {}
    try:
        data["bench_georef"] = bench_georef(site=site, platforms=platforms, n=n)
    except Exception as e:  # keep our own figures below
        data["bench_georef_error"] = f"{type(e).__name__}: {e}"
    h0 = min(lv.elevation for lv in site.levels)
    pts = np.concatenate([np.asarray(p.outline) for p in platforms])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = 0.25 * (hi - lo)  # beyond the platforms: how the error grows off site
    lo, hi = lo - margin, hi + margin
    k = ctx.pick(40, 90)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], k), np.linspace(lo[1], hi[1], k))
    q = np.stack([gx.ravel(), gy.ravel()], axis=1)
    d = g.naive_enu(q, h0) - g.to_enu(q, h0)
    err3, errh = np.linalg.norm(d, axis=1), np.linalg.norm(d[:, :2], axis=1)
    rng = np.random.default_rng(0)
    xy = lo + rng.random((n, 2)) * (hi - lo)
    h = np.full(n, h0)
    repeats = ctx.pick(2, 5)
    exact, naive = timed(lambda: g.to_enu(xy, h), repeats), timed(lambda: g.naive_enu(xy, h), repeats)
    per_m = 1e6 / n
    data.update({
        "origin_llh": list(g.origin_llh), "plan_extent": [lo.tolist(), hi.tolist()], "grid_shape": [k, k],
        "grid_x": gx[0].round(3).tolist(), "grid_y": gy[:, 0].round(3).tolist(),
        "naive_error_3d_m": err3.reshape(k, k).round(5).tolist(),
        "naive_error_horizontal_m": errh.reshape(k, k).round(5).tolist(),
        "naive_error_max_m": float(err3.max()), "naive_error_median_m": float(np.median(err3)),
        "platforms": [{"level": p.level, "outline": np.asarray(p.outline).round(3).tolist()} for p in platforms],
        "points": n,
        "exact_per_million": {key: v * per_m if key.endswith("_s") else v for key, v in exact.items()},
        "naive_per_million": {key: v * per_m if key.endswith("_s") else v for key, v in naive.items()},
    })
    return data


# --- sun -----------------------------------------------------------------------------------


def sun_section(ctx: Context, runtime: dict | None) -> dict:
    """The study's theta = 90 sin(pi tau) against astral's ephemeris over a year at the
    site: our own day x hour map (for the plot), plus the runtime bench's figures."""
    from .. import sun

    site, _, g = _site(ctx.sources)
    lat, lon = g.origin_llh[0], g.origin_llh[1]
    tz = site.zone
    year = 2025
    days = list(range(0, 365, ctx.pick(15, 3)))
    minutes = list(range(0, 24 * 60, ctx.pick(60, 20)))
    err = np.full((len(days), len(minutes)), np.nan)
    for i, d in enumerate(days):
        for j, m in enumerate(minutes):
            when = dt.datetime(year, 1, 1, tzinfo=tz) + dt.timedelta(days=d, minutes=m)
            eph = sun.ephemeris(lat, lon, when)[0]
            study = sun.study_elevation(lat, lon, when)
            if eph > 0 or study > 0:
                err[i, j] = study - eph
    day = np.isfinite(err)
    absd = np.abs(err[day])
    data = {"lat": lat, "lon": lon, "timezone": site.timezone, "year": year, "days": days, "minutes": minutes,
            "error_deg": np.where(day, err, None).tolist(),
            "abs_error_deg": {"max": float(absd.max()), "mean": float(absd.mean()),
                              "p95": float(np.percentile(absd, 95))},
            "noon_error_deg": _noon_errors(sun, lat, lon, tz, year, days)}
    if runtime and isinstance(runtime.get("sun"), dict):
        data["runtime_bench"] = runtime["sun"]
    return data


def _noon_errors(sun, lat, lon, tz, year, days) -> list[float]:
    """Per day: study elevation minus ephemeris at the ephemeris' noon (max over the day)."""
    out = []
    for d in days:
        best = max(range(9 * 60, 15 * 60, 5), key=lambda m: sun.ephemeris(
            lat, lon, dt.datetime(year, 1, 1, tzinfo=tz) + dt.timedelta(days=d, minutes=m))[0])
        when = dt.datetime(year, 1, 1, tzinfo=tz) + dt.timedelta(days=d, minutes=best)
        out.append(float(sun.study_elevation(lat, lon, when) - sun.ephemeris(lat, lon, when)[0]))
    return out


# --- runtime ------------------------------------------------------------------------------------


def runtime_section(ctx: Context) -> dict:
    from .runtime import bench_runtime

    site, _, g = _site(ctx.sources)
    where = (g.origin_llh[0], g.origin_llh[1], site.zone)
    if ctx.quick:
        return bench_runtime(where, repeats=5, sizes=(100, 1_000))
    return bench_runtime(where)


# --- render --------------------------------------------------------------------------

RENDER_SCRIPT = ("import json, sys; from pathlib import Path; from pipeline.bench.render import bench_render; "
                 "r = bench_render(Path(sys.argv[1]), int(sys.argv[2]), sources=Path(sys.argv[3]), "
                 "setup=sys.argv[4], reference=Path(sys.argv[5])); print('BENCH_JSON ' + json.dumps(r))")


def render_section(ctx: Context) -> dict:
    """The study's gauge close-up (320x240) with our Cycles settings and with Blender's
    factory light paths at 16 raw samples, each in a fresh process, side by side; both
    measured against a 256-sample factory-light-path reference rendered first."""
    import json
    import subprocess
    import sys
    import tempfile

    built = ctx.built or ctx.out  # the build section's sample, else the user's build
    if not (built / "scene" / "placements.json").is_file() or not (built / "models" / "shunt_reactor").is_dir():
        return {"skipped": "no built shunt reactor (the study's target) in these sources"}
    out = {}
    with tempfile.TemporaryDirectory(prefix="twin_bench_render_") as tmp:
        reference = Path(tmp) / "reference.npy"
        for setup in ("reference", "ours", "blender_defaults"):
            proc = subprocess.run([sys.executable, "-c", RENDER_SCRIPT, str(built), str(ctx.pick(2, 5)),
                                   str(ctx.sources), setup, str(reference)], capture_output=True, text=True,
                                  timeout=1200)
            line = next((x for x in reversed(proc.stdout.splitlines()) if x.startswith("BENCH_JSON ")), None)
            if line is None:
                raise RuntimeError(f"render bench ({setup}) exited {proc.returncode}: {proc.stderr[-500:]}")
            out[setup] = json.loads(line[len("BENCH_JSON "):])
    return out

