"""Speed and accuracy of exact against naive georeferencing (pipeline.georef), for
`twin bench`'s georef section."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Sequence

import numpy as np
from pyproj import CRS, Proj

from .. import ir
from ..georef import Georeferencer, default_origin


def _best_time(fn, repeats: int = 3) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_georef(site, platforms: Sequence[ir.Platform] | None = None, n: int = 1_000_000) -> dict:
    """Speed and accuracy of exact vs naive georeferencing.

    `site`: a loaded site.toml (its floor plan gives the platforms by default). Reports points
    per second of both methods on n points, and the naive method's error (3D and
    horizontal, metres) at the far corner of the platforms and over a 50 x 50 grid
    covering them (max and median).
    """
    if platforms is None:
        from ..ingest.floorplan import read_floorplan

        platforms = read_floorplan(site.root / site.floorplan, levels=set(site.level_names)).platforms
    origin = site.origin or default_origin(site, platforms)
    g = Georeferencer(site, origin)
    h0 = min(lv.elevation for lv in site.levels)

    pts = np.concatenate([np.asarray(p.outline) for p in platforms])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    rng = np.random.default_rng(0)
    xy = lo + rng.random((n, 2)) * (hi - lo)
    h = np.full(n, h0)
    t_exact = _best_time(lambda: g.to_enu(xy, h))
    t_naive = _best_time(lambda: g.naive_enu(xy, h))

    def err(q):
        d = g.naive_enu(q, h0) - g.to_enu(q, h0)
        return np.linalg.norm(d, axis=1), np.linalg.norm(d[:, :2], axis=1)

    exact = g.to_enu(pts, h0)
    far = pts[np.argmax(np.hypot(exact[:, 0], exact[:, 1]))][None, :]
    far_3d, far_h = err(far)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 50), np.linspace(lo[1], hi[1], 50))
    grid_3d, grid_h = err(np.stack([gx.ravel(), gy.ravel()], axis=1))
    f = Proj(CRS.from_user_input(site.crs)).get_factors(origin[1], origin[0])
    return {
        "points": n,
        "exact_points_per_s": n / t_exact,
        "naive_points_per_s": n / t_naive,
        "far_corner_distance_m": float(np.hypot(*g.to_enu(far, h0)[0, :2])),
        "naive_error_far_corner_m": float(far_3d[0]),
        "naive_error_far_corner_horizontal_m": float(far_h[0]),
        "naive_error_grid_max_m": float(grid_3d.max()),
        "naive_error_grid_median_m": float(np.median(grid_3d)),
        "grid_points": int(grid_3d.size),
        "meridian_convergence_deg": float(f.meridian_convergence),
        "scale_factor": float(f.meridional_scale),
    }
