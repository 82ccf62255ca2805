"""Plant grid -> projected CRS -> geodetic -> local ENU (DESIGN.md s.2 and s.3).

The scene frame is the topocentric ENU frame at the site origin, the one SDF's
`<spherical_coordinates>` with `<world_frame_orientation>ENU` defines. A drawing point
goes through the site's similarity to the projected CRS, then pyproj's inverse
projection and datum transformation to WGS84 (SIRGAS 2000 -> WGS84 is a null shift at
this accuracy, but PROJ decides that, not us), then to ECEF and the topocentric frame.
"Easting minus origin easting" (`naive_enu`) is kept only as the reference the
benchmark compares against: it ignores grid convergence, scale and Earth curvature.

All arrays are float64. `xy` is always plant-grid metres, shape (n, 2).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Iterable, Sequence

import numpy as np
from pyproj import CRS, Transformer

from . import ir
from .errors import UserError

WGS84_3D = "EPSG:4979"  # WGS84 geographic 3D: lon, lat (deg), ellipsoidal height (m)
WGS84_ECEF = "EPSG:4978"

# Half-length of the finite step used to measure headings. The map's curvature over a
# metre changes a direction by < 1e-12 rad; a shorter step would only add round-off.
_HEADING_STEP_M = 0.5


def _xy(xy) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64)
    if a.ndim == 1 and a.shape == (2,):
        a = a.reshape(1, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"xy must have shape (n, 2), got {a.shape}")
    return a


def _per_point(h, n: int) -> np.ndarray:
    a = np.asarray(h, dtype=np.float64)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise ValueError(f"expected shape ({n},), got {a.shape}")
    return a


def _transform(t: Transformer, *cols: np.ndarray) -> list[np.ndarray]:
    """t.transform on (n,) float64 columns, returning (n,) arrays. pyproj sends size-1
    arrays down its scalar fast path (a numpy deprecation, and scalars back): pad them."""
    cols = [np.asarray(c, dtype=np.float64).reshape(-1) for c in cols]
    n = len(cols[0])
    if n == 1:
        cols = [np.repeat(c, 2) for c in cols]
    return [np.asarray(o, dtype=np.float64)[:n] for o in t.transform(*cols)]


def plan_to_crs(xy, site) -> np.ndarray:
    """Plant grid -> projected CRS: E = E0 + s (x cos r - y sin r), N = N0 + s (x sin r + y cos r).

    xy: (n, 2) float64 drawing metres. Returns (n, 2) float64 easting, northing.
    The offset is added last so the rotation works on small numbers (exact near 1e7 m).
    """
    p = _xy(xy)
    r = math.radians(site.grid_rotation_deg)
    s = site.grid_scale
    c, sn = math.cos(r), math.sin(r)
    e0, n0 = site.grid_origin
    out = np.empty_like(p)
    out[:, 0] = s * (p[:, 0] * c - p[:, 1] * sn) + e0
    out[:, 1] = s * (p[:, 0] * sn + p[:, 1] * c) + n0
    return out


def crs_to_plan(en, site) -> np.ndarray:
    """The inverse of `plan_to_crs`. en: (n, 2) float64 easting, northing -> (n, 2) plan xy."""
    q = _xy(en)
    r = math.radians(site.grid_rotation_deg)
    c, sn = math.cos(r), math.sin(r)
    de = (q[:, 0] - site.grid_origin[0]) / site.grid_scale
    dn = (q[:, 1] - site.grid_origin[1]) / site.grid_scale
    return np.stack([de * c + dn * sn, -de * sn + dn * c], axis=1)


def _crs3d(code: str) -> CRS:
    # A projected CRS is 2D; its 3D form carries the ellipsoidal height through the
    # datum transformation instead of dropping it.
    return CRS.from_user_input(code).to_3d()


# Made once per process and CRS: PROJ chooses each new Transformer's operation from its
# database, and one worker's tasks (the scene, the terrain, the viewer) each georeference
# the same site. A Transformer is safe to share between threads (pyproj gives each
# thread its own PROJ object).
@lru_cache(maxsize=None)
def _crs_to_wgs84(code: str) -> Transformer:
    return Transformer.from_crs(_crs3d(code), CRS.from_user_input(WGS84_3D), always_xy=True)


@lru_cache(maxsize=None)
def _wgs84_to_crs(code: str) -> Transformer:
    return Transformer.from_crs(CRS.from_user_input(WGS84_3D), _crs3d(code), always_xy=True)


def plan_to_llh(site, xy, h) -> np.ndarray:
    """xy: (n, 2) plan metres, h: (n,) or scalar ellipsoidal heights -> (n, 3) WGS84 lat,
    lon (deg), height, through the site's CRS (no scene origin needed)."""
    p = _xy(xy)
    en = plan_to_crs(p, site)
    lon, lat, hw = _transform(_crs_to_wgs84(site.crs), en[:, 0], en[:, 1], _per_point(h, len(p)))
    return np.stack([lat, lon, hw], axis=1)


def default_origin(site, platforms: Sequence[ir.Platform]) -> tuple[float, float, float]:
    """The scene origin when site.toml has no [origin]: the centre of the platforms'
    bounding box in the plan, as WGS84 (lat, lon) degrees, and height = the lowest
    level's elevation (metres above the ellipsoid)."""
    if not platforms:
        raise UserError(site.path, "origin", "no [origin] in site.toml and no platforms in the floor plan to centre it on")
    pts = np.concatenate([np.asarray(p.outline, dtype=np.float64) for p in platforms])
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    en = plan_to_crs(centre[None, :], site)[0]
    h = min(lv.elevation for lv in site.levels)
    lon, lat, hw = _transform(_crs_to_wgs84(site.crs), en[0:1], en[1:2], np.array([h]))
    return float(lat[0]), float(lon[0]), float(hw[0])


def enu_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """(3, 3) float64 rotation taking ECEF offsets to ENU at (lat, lon)."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    sla, cla, slo, clo = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
    return np.array(
        [
            [-slo, clo, 0.0],
            [-sla * clo, -sla * slo, cla],
            [cla * clo, cla * slo, sla],
        ]
    )


class Georeferencer:
    """Plan -> scene ENU for one site. Build it once: it caches the pyproj Transformers.

    origin: (lat, lon, height) WGS84 degrees and ellipsoidal metres; default site.origin.
    Without either, pass `default_origin(site, platforms)`.
    """

    def __init__(self, site, origin: tuple[float, float, float] | None = None):
        self.site = site
        if origin is None:
            origin = site.origin
        if origin is None:
            raise UserError(site.path, "origin", "no [origin]: build the Georeferencer with default_origin(site, platforms)")
        self.origin_llh: tuple[float, float, float] = tuple(float(v) for v in origin)
        lat0, lon0, h0 = self.origin_llh
        self._to_wgs84 = _crs_to_wgs84(site.crs)
        self._from_wgs84 = _wgs84_to_crs(site.crs)
        # lon, lat in degrees and height -> ECEF -> topocentric ENU, all inside PROJ.
        self._topocentric = Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad"
            " +step +proj=cart +ellps=WGS84"
            f" +step +proj=topocentric +ellps=WGS84 +lon_0={lon0!r} +lat_0={lat0!r} +h_0={h0!r}"
        )
        e, n, _ = _transform(self._from_wgs84, [lon0], [lat0], [h0])
        self.origin_en: tuple[float, float] = (float(e[0]), float(n[0]))

    def to_llh(self, xy, h) -> np.ndarray:
        """xy: (n, 2) plan metres, h: (n,) ellipsoidal heights -> (n, 3) WGS84 lat, lon (deg), height."""
        p = _xy(xy)
        en = plan_to_crs(p, self.site)
        lon, lat, hw = _transform(self._to_wgs84, en[:, 0], en[:, 1], _per_point(h, len(p)))
        return np.stack([lat, lon, hw], axis=1)

    def llh_to_enu(self, lat, lon, h) -> np.ndarray:
        """WGS84 lat, lon (deg), ellipsoidal h, each (n,) -> (n, 3) float64 topocentric ENU."""
        lon = np.asarray(lon, dtype=np.float64).reshape(-1)
        return np.stack(_transform(self._topocentric, lon, lat, _per_point(h, len(lon))), axis=1)

    def to_enu(self, xy, h) -> np.ndarray:
        """xy: (n, 2) plan metres, h: (n,) ellipsoidal heights -> (n, 3) float64 ENU metres."""
        llh = self.to_llh(xy, h)
        return self.llh_to_enu(llh[:, 0], llh[:, 1], llh[:, 2])

    def headings(self, xy, heading_deg) -> np.ndarray:
        """ENU yaw (rad, counter-clockwise from east, in (-pi, pi]) of each block's x axis.

        xy: (n, 2) plan metres; heading_deg: (n,) INSERT rotations in the plan grid.
        Measured by mapping a short step along the rotated x axis, so it includes the
        grid rotation, the projection's meridian convergence and the turn of north
        between the point and the ENU origin.
        """
        p = _xy(xy)
        a = np.radians(_per_point(heading_deg, len(p)))
        step = _HEADING_STEP_M * np.stack([np.cos(a), np.sin(a)], axis=1)
        h = np.full(len(p), self.origin_llh[2])
        d = self.to_enu(p + step, h) - self.to_enu(p - step, h)
        # libm's atan2 per point: numpy 1.26's arctan2 on strided columns rounds its
        # first call in a process differently from later ones (SVML vs libm), so the
        # yaw's bits would depend on what a worker ran before
        return np.array([math.atan2(y, x) for x, y in zip(d[:, 0].tolist(), d[:, 1].tolist())], dtype=np.float64)

    def naive_enu(self, xy, h) -> np.ndarray:
        """The reference method: (E - E_origin, N - N_origin, h - h_origin), (n, 3) float64.

        Ignores convergence, scale factor and curvature; for benchmarks only.
        """
        p = _xy(xy)
        en = plan_to_crs(p, self.site)
        out = np.empty((len(p), 3))
        out[:, 0] = en[:, 0] - self.origin_en[0]
        out[:, 1] = en[:, 1] - self.origin_en[1]
        out[:, 2] = _per_point(h, len(p)) - self.origin_llh[2]
        return out

    def placements_enu(self, placements: Iterable[ir.Placement]) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) ENU positions and (n,) yaw of placements: height = level elevation + z."""
        pl = list(placements)
        if not pl:
            return np.zeros((0, 3)), np.zeros(0)
        xy = np.array([(p.x, p.y) for p in pl], dtype=np.float64)
        h = np.array([self.site.level(p.level).elevation + p.z for p in pl], dtype=np.float64)
        return self.to_enu(xy, h), self.headings(xy, np.array([p.heading_deg for p in pl]))
