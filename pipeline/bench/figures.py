"""The bench page's plots: each function takes a section's data and returns
(PNG bytes, one sentence saying what the plot means), or None when there is nothing
to draw. matplotlib runs headless (Agg)."""

from __future__ import annotations

import io

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    _plt().close(fig)
    return buf.getvalue()


def _no_minor_labels(ax) -> None:
    """Log axes label their minor ticks when the range is short: unreadable in small plots."""
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_minor_formatter(NullFormatter())


MARKERS = {"meshoptimizer": "o", "pymeshlab": "s", "fast_simplification": "^"}


def lod(d: dict):
    plt = _plt()
    meshes = list(d["meshes"])
    cols = min(3, len(meshes))
    rows = -(-len(meshes) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax, name in zip(axes.ravel(), meshes):
        runs = [r for r in d["runs"] if r["mesh"] == name and not r["crashed"]]
        for r in runs:
            ax.scatter(r["time"]["median_s"], max(r["error_m"], 1e-7), marker=MARKERS.get(r["method"], "x"),
                       s=50 if r["pareto"] else 25, facecolors="none" if not r["pareto"] else None,
                       edgecolors="C%d" % list(MARKERS).index(r["method"]) if r["method"] in MARKERS else "k",
                       color="C%d" % list(MARKERS).index(r["method"]) if r["method"] in MARKERS else "k")
            ax.annotate(f"{r['ratio']:g}", (r["time"]["median_s"], max(r["error_m"], 1e-7)), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
        front = sorted((r["time"]["median_s"], max(r["error_m"], 1e-7)) for r in runs if r["pareto"])
        if front:
            ax.step(*zip(*front), where="post", color="grey", lw=0.8, ls="--")
        crashed = [r["method"] for r in d["runs"] if r["mesh"] == name and r["crashed"]]
        ax.set_title(name + (f" (crashed: {', '.join(sorted(set(crashed)))})" if crashed else ""), fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        _no_minor_labels(ax)
        ax.set_xlabel("time (s)", fontsize=7)
        ax.set_ylabel("Hausdorff error (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[len(meshes):]:
        ax.axis("off")
    handles = [plt.Line2D([], [], marker=m, ls="", color=f"C{i}", label=k) for i, (k, m) in enumerate(MARKERS.items())]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=7, bbox_to_anchor=(0.5, -0.02))
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return _png(fig), ("Each simplifier's time against its measured two-sided Hausdorff error at matched triangle "
                       "counts (labels: kept fraction); filled markers on the dashed line are the Pareto front, "
                       "the choices no other run beats on both time and error.")


def georef(d: dict):
    plt = _plt()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1.6, 1]})
    err = np.array(d["naive_error_3d_m"], dtype=float)
    x, y = np.array(d["grid_x"]), np.array(d["grid_y"])
    im = ax.pcolormesh(x, y, err, shading="auto", cmap="viridis")
    fig.colorbar(im, ax=ax, label="naive error (m)")
    for p in d["platforms"]:
        o = np.array(p["outline"] + p["outline"][:1])
        ax.plot(o[:, 0], o[:, 1], color="w", lw=1)
        ax.text(o[:, 0].mean(), o[:, 1].mean(), p["level"], color="w", fontsize=8, ha="center")
    ax.set_aspect("equal")
    ax.set_xlabel("plan x (m)")
    ax.set_ylabel("plan y (m)")
    ax.set_title("naive (E-E0, N-N0, h-h0) minus exact ENU, 3D", fontsize=8)
    labels = ["exact (pyproj ENU)", "naive"]
    vals = [d["exact_per_million"]["median_s"], d["naive_per_million"]["median_s"]]
    lo = [v - d[k]["min_s"] for v, k in zip(vals, ("exact_per_million", "naive_per_million"))]
    hi = [d[k]["max_s"] - v for v, k in zip(vals, ("exact_per_million", "naive_per_million"))]
    bx.bar(labels, vals, yerr=[lo, hi], color=["C0", "C1"], capsize=4)
    bx.set_ylabel("seconds per million points")
    bx.set_title("cost (median, min-max)", fontsize=8)
    fig.tight_layout()
    return _png(fig), (f"Left: how far the naive easting/northing offset puts a point from its exact position, over the "
                       f"plan (white: platforms), up to {d['naive_error_max_m']:.3f} m; right: what each method costs per "
                       f"million points.")


def sun(d: dict):
    plt = _plt()
    err = np.array([[np.nan if v is None else v for v in row] for row in d["error_deg"]], dtype=float)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8))
    hours = np.array(d["minutes"]) / 60.0
    lim = np.nanmax(np.abs(err)) if np.isfinite(err).any() else 1.0
    im = ax.pcolormesh(hours, d["days"], err, shading="auto", cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, label="study - ephemeris (deg)")
    ax.set_xlabel(f"local time ({d['timezone']}) (h)")
    ax.set_ylabel(f"day of {d['year']}")
    ax.set_title(f"elevation error at lat {d['lat']:.2f}, lon {d['lon']:.2f}", fontsize=8)
    bx.plot(d["days"], d["noon_error_deg"], color="C3")
    bx.axhline(0, color="k", lw=0.5)
    bx.set_xlabel(f"day of {d['year']}")
    bx.set_ylabel("error at solar noon (deg)")
    bx.set_title("study model at noon: 90 deg vs the real noon elevation", fontsize=8)
    fig.tight_layout()
    return _png(fig), (f"The study's 90 sin(pi tau) elevation minus the real ephemeris over a year at the site "
                       f"(daytime only): up to {d['abs_error_deg']['max']:.1f} deg off, worst at noon, where it always "
                       f"puts the sun at the zenith.")


def build_times(d: dict):
    plt = _plt()
    items = [("cold, 1 worker", d["cold_j1"]), ("cold, 2 workers", d["cold_j2"]),
             ("one-asset edit, source file", d["one_asset_source_edit"]),
             ("one-asset edit, source saved again", d["one_asset_resave"]),
             ("one-asset edit, LOD budget", d["one_asset_geometry_edit"]),
             ("LOD budget edit, each asset", d["every_asset_geometry_edit"]),
             ("one-asset edit, metadata", d["one_asset_edit"]), ("no-op", d["noop"])]
    colors = ["C0", "C0", "C1", "C1", "C1", "C1", "C1", "C2"]
    large = d["large_plan"]
    for label, key, color in (("cold, 1 worker", "cold_j1", "C0"), ("cold, 2 workers", "cold_j2", "C0"),
                              ("one-asset edit, source file", "one_asset_source_edit", "C1"),
                              ("one-asset edit, LOD budget", "one_asset_geometry_edit", "C1"),
                              ("one-asset edit, metadata", "one_asset_edit", "C1"), ("no-op", "noop", "C2")):
        if large.get(key):
            items.append((f"{large['multiple']}x plan: {label}", large[key]))
            colors.append(color)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    vals = [s["time"]["median_s"] for _, s in items]
    err = [[v - s["time"]["min_s"] for v, (_, s) in zip(vals, items)], [s["time"]["max_s"] - v for v, (_, s) in zip(vals, items)]]
    ax.barh([k for k, _ in items], vals, xerr=err, color=colors, capsize=3)
    ax.set_xscale("log")
    ax.set_xlabel("wall time of `twin build` (s, log)")
    for i, v in enumerate(vals):
        ax.text(v, i, f" {v:.2f} s", va="center", fontsize=7)
    fig.tight_layout()
    return _png(fig), ("What a `twin build` costs in each situation (median bars, min-max whiskers): a cold build, the "
                       "same with both cores, rebuilding after one asset's edit (of its source file: the whole chain; the "
                       "source saved again unchanged: its read and package, the LOD search cut off; of an "
                       "LOD budget: the LOD search, the package and the scene, also for every asset in turn, whiskers "
                       "from the smallest to the largest; of its metadata: the package and the scene), and rebuilding "
                       "with nothing changed; then the same on the plan with "
                       f"{large['multiple']}x the placements.")


def build_scaling(d: dict):
    plt = _plt()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.6))
    for a, key, xlab, label in ((ax, "placements", "placements", "terrain+scene rebuild, assets cached"),
                                (bx, "unique_assets", "unique assets", "cold build")):
        series = sorted(d[key].values(), key=lambda s: len(s.get("assets", [])) or s.get("placements", 0))
        xs = [s.get("placements") if key == "placements" else len(s["assets"]) for s in series]
        ts = [s["time"]["median_s"] for s in series]
        ms = [max(r["maxrss_bytes"] for r in s["runs"]) / 1e9 for s in series]
        tp = [max(r["tree_peak_bytes"] for r in s["runs"]) / 1e9 for s in series]
        a.plot(xs, ts, "o-", color="C0", label=f"time ({label})")
        a.set_xlabel(xlab)
        a.set_ylabel("seconds", color="C0")
        a2 = a.twinx()
        a2.plot(xs, ms, "s--", color="C3", label="largest process peak RSS")
        a2.plot(xs, tp, "^:", color="C1", label="whole tree peak RSS (sampled)")
        a2.set_ylabel("GB", color="C3")
        a2.set_ylim(bottom=0)
        a.set_ylim(bottom=0)
        h1, l1 = a.get_legend_handles_labels()
        h2, l2 = a2.get_legend_handles_labels()
        a.legend(h1 + h2, l1 + l2, fontsize=6, loc="upper left")
    if "cold_j2" in d:
        cold = d["cold_j2"]["time"]["median_s"]
        ax.axhline(cold, color="grey", lw=0.7, ls="--")
        ax.set_ylim(top=max(ax.get_ylim()[1], 1.15 * cold))  # the line and its label inside the axes
        ax.text(ax.get_xlim()[0], cold, " cold build of the sample", fontsize=6, va="bottom")
    fig.tight_layout()
    return _png(fig), ("Left: time and peak memory as the plan grows to more placements with the asset packages cached "
                       "(only the terrain and scene work grows); right: cold-build time and memory against the number "
                       "of distinct assets placed.")


def runtime(d: dict, reexport: dict | None):
    plt = _plt()
    graphs = d.get("graphs", {})
    if not graphs:
        return None
    sizes = sorted(int(k.split("_")[1]) for k in graphs)
    full = [graphs[f"graph_{n}"]["full_step"]["median_s"] for n in sizes]
    inc = [graphs[f"graph_{n}"]["incremental_step"]["median_s"] for n in sizes]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.loglog(sizes, full, "o-", label="full step")
    ax.loglog(sizes, inc, "s-", label="incremental step (one input changed)")
    usd = d.get("usd", {}).get("usd_apply_state", {}).get("median_s")
    if usd:
        ax.axhline(usd, color="C2", ls="--", label="apply one state to USD (sample)")
    if reexport:
        ax.axhline(reexport["step"]["median_s"], color="C3", ls=":",
                   label=f"Blender re-export per step ({reexport['asset']}, the study)")
    ax.set_xlabel("graph nodes")
    ax.set_ylabel("seconds per step")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig), ("Runtime step latency against graph size, for a full step and an incremental one, beside the cost "
                       "of applying a state to USD and of the study's approach, re-exporting the model from Blender at "
                       "every step.")


def blender(d: dict):
    plt = _plt()
    loads = {k: v for k, v in d.get("loads", {}).items() if not k.startswith("empty")}
    if not loads:
        return None
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.4))
    names = list(loads)
    t = [loads[k]["time"]["median_s"] for k in names]
    m = [loads[k]["maxrss"]["median"] / 1e9 for k in names]
    colors = ["C1" if k.startswith("blender") else "C0" for k in names]
    ax.barh(names, t, color=colors)
    ax.set_xlabel("load time in a fresh Blender (s)")
    bx.barh(names, m, color=colors)
    base = d["loads"].get("empty (bpy baseline)")
    if base:
        bx.axvline(base["maxrss"]["median"] / 1e9, color="k", ls="--", lw=0.8)
        bx.text(base["maxrss"]["median"] / 1e9, -0.6, " empty Blender", fontsize=6)
    bx.set_xlabel("peak RSS of the loading Blender (GB)")
    fig.tight_layout()
    return _png(fig), ("How long a fresh Blender takes to open the scene and how much memory it needs: our modular "
                       "files (blue) against the one-file scene Blender's own exporters wrote (orange).")


def gltf_transform(d: dict):
    plt = _plt()
    rows = d.get("simplify", [])
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for i, r in enumerate(rows):
        o, g = r["ours"], r["gltf_transform"]
        ax.scatter(o["triangles"], max(o["error_m"], 1e-7), color="C0", marker="o", label="ours" if i == 0 else None)
        ax.scatter(g["triangles"], max(g["error_m"], 1e-7), color="C1", marker="s",
                   label="gltf-transform weld+simplify" if i == 0 else None)
        ax.plot([o["triangles"], g["triangles"]], [max(o["error_m"], 1e-7), max(g["error_m"], 1e-7)], color="grey", lw=0.5)
        ax.annotate(r["asset"], (o["triangles"], max(o["error_m"], 1e-7)), fontsize=6, xytext=(3, 3),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _no_minor_labels(ax)
    ax.set_xlabel("triangles of the coarsest level")
    ax.set_ylabel("Hausdorff error vs LOD0 (m)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig), ("For each model, our coarsest LOD and glTF-Transform's simplification asked for the same triangle "
                       "count, both measured against LOD0 with the same metric: lower is more faithful.")
