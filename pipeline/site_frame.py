"""Whether the site's frame holds together: the floor plan, put on the globe through
plan.crs and plan.grid_origin, lies at [origin], and [site] timezone keeps the time of
the site's longitude. A CRS of the other side of the world (UTM 50N for a site in
Bahia) otherwise builds every placement thousands of kilometres from the origin, and a
zone of another continent puts the scene's 13:00 sun at night, both without a word.

One UserError naming the file and the key; `check` is keyed for config.PassedChecks
by what it reads, so a no-op build neither imports pyproj nor checks again.
"""

from __future__ import annotations

import datetime as dt
import math

import numpy as np

from . import ir
from .digest import sha256_json
from .errors import UserError

# a substation spans a few kilometres: a point of the plan farther than this from
# [origin] is a wrong CRS, grid origin or [origin] (or a stray INSERT)
MAX_RADIUS_M = 10_000.0
# a zone's UTC offset against the longitude's solar time (lon / 15 hours): zones follow
# borders (China keeps UTC+8 at 75 E, Spain UTC+1 at 9 W), not meridians, but none is
# this far off; daylight saving is allowed on top (the offsets of January, July and
# the site's date are each tried)
MAX_ZONE_HOURS = 3.0
# zones that keep UTC wherever the site is: a choice of clock, not a place
UTC_NAMES = {"UTC", "UCT", "GMT", "GMT0", "GMT+0", "GMT-0", "Greenwich", "Universal", "Zulu"}


def check(site, floorplan: ir.FloorPlan, passed=None) -> None:
    """Raise a UserError when the plan is far from [origin] or the time zone contradicts
    the site's longitude (the origin's, or without [origin] the platforms' centre)."""
    points = _plan_points(floorplan)
    if not len(points):
        return
    lo, hi = points.min(axis=0), points.max(axis=0)
    key = sha256_json(["site frame", MAX_RADIUS_M, MAX_ZONE_HOURS, site.crs, list(site.grid_origin),
                       site.grid_rotation_deg, site.grid_scale, site.origin and list(site.origin), site.timezone,
                       site.date, lo.tolist(), hi.tolist()])
    if passed is not None and key in passed:
        return
    from pyproj import Geod

    from .georef import default_origin, plan_to_llh

    geod = Geod(ellps="WGS84")
    origin = site.origin
    if origin is not None:
        _check_extent(site, floorplan, points, lo, hi, origin, geod, plan_to_llh)
    else:
        origin = default_origin(site, floorplan.platforms) if floorplan.platforms else \
            tuple(plan_to_llh(site, (lo + hi)[None, :] / 2, 0.0)[0])
        _check_extent(site, floorplan, points, lo, hi, origin, geod, plan_to_llh)
    _check_zone(site, origin)
    if passed is not None:
        passed.add(key)


def _plan_points(fp: ir.FloorPlan) -> np.ndarray:
    """(n, 2) plan metres: every placement and every platform vertex."""
    parts = [np.array([(p.x, p.y) for p in fp.placements], dtype=np.float64).reshape(-1, 2)]
    parts += [np.asarray(pf.outline, dtype=np.float64).reshape(-1, 2) for pf in fp.platforms]
    return np.concatenate(parts)


def _distances(geod, origin, llh: np.ndarray) -> np.ndarray:
    """Metres on the ellipsoid from origin (lat, lon, h) to each (lat, lon, h) row."""
    n = len(llh)
    rows = np.repeat(llh, 2, axis=0) if n == 1 else llh  # pyproj's scalar path wants scalars
    m = len(rows)
    _, _, d = geod.inv(np.full(m, origin[1]), np.full(m, origin[0]), rows[:, 1], rows[:, 0])
    return np.asarray(d, dtype=np.float64).reshape(-1)[:: 2 if n == 1 else 1]


def _check_extent(site, fp, points, lo, hi, origin, geod, plan_to_llh) -> None:
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    if _distances(geod, origin, plan_to_llh(site, corners, 0.0)).max() <= MAX_RADIUS_M:
        return  # the whole plan is near the origin
    # the median point: one stray INSERT does not move it off the site
    centre = plan_to_llh(site, np.median(points, axis=0)[None, :], 0.0)
    far = _distances(geod, origin, centre)[0]
    if far > MAX_RADIUS_M or not fp.placements:
        raise UserError(site.path, "plan.crs", (
            f"the floor plan lands {_km(far)} from the scene origin: through plan.crs {site.crs} ({_crs_name(site.crs)}) "
            f"and plan.grid_origin {list(site.grid_origin)} its middle is at lat {centre[0, 0]:.4f}, lon "
            f"{centre[0, 1]:.4f}, the origin at lat {origin[0]:.4f}, lon {origin[1]:.4f} "
            f"({_utm_zone(origin)}); every placement would be that far away. A plan farther than "
            f"{_km(MAX_RADIUS_M)} from [origin] means a wrong plan.crs (or plan.grid_origin, or [origin])"))
    # the plan is where it should be but a placement is not: name the farthest
    xy = np.array([(p.x, p.y) for p in fp.placements], dtype=np.float64)
    d = _distances(geod, origin, plan_to_llh(site, xy, 0.0))
    worst = fp.placements[int(np.argmax(d))]
    if d.max() <= MAX_RADIUS_M:
        return  # a platform's corner, not a placement: the platform check of the scene says more
    handles = " > ".join(f"#{h}" for h in worst.dxf_handles)
    raise UserError(fp.path, f"INSERT {worst.tag} ({handles})", (
        f"at plan ({worst.x:.1f}, {worst.y:.1f}) m it lands {_km(float(d.max()))} from [origin], more than the "
        f"{_km(MAX_RADIUS_M)} a site spans: a stray INSERT or a wrong insertion point"))


def _check_zone(site, origin) -> None:
    """[site] timezone against the solar time of the origin's longitude."""
    if site.timezone.removeprefix("Etc/") in UTC_NAMES:
        return
    solar = origin[1] / 15.0
    date = dt.date.fromisoformat(site.date)
    offsets = []
    for day in (dt.date(date.year, 1, 1), dt.date(date.year, 7, 1), date):
        noon = dt.datetime.combine(day, dt.time(12, 0), tzinfo=site.zone)
        offsets.append(noon.utcoffset().total_seconds() / 3600.0)
    gaps = [abs((off - solar + 12.0) % 24.0 - 12.0) for off in offsets]
    if min(gaps) <= MAX_ZONE_HOURS:
        return
    where = "[origin]" if site.origin is not None else "the platforms' centre through plan.crs"
    raise UserError(site.path, "site.timezone", (
        f"{site.timezone} keeps UTC{_hours(offsets[-1])} on {site.date}, but the site's longitude "
        f"{origin[1]:.3f} ({where}) keeps solar time UTC{_hours(solar)}: {min(gaps):.1f} hours apart, more "
        f"than the {MAX_ZONE_HOURS:g} any zone is from its sun. The scene's 13:00 sun would be at the wrong "
        f"hour: name the site's own IANA zone (or fix {'[origin]' if site.origin is not None else 'plan.crs'})"))


def _km(metres: float) -> str:
    return f"{metres / 1000.0:,.0f} km" if metres >= 10_000 else f"{metres / 1000.0:.1f} km"


def _hours(h: float) -> str:
    sign = "+" if h >= 0 else "-"
    minutes = round(abs(h) * 60)
    return f"{sign}{minutes // 60}" + (f":{minutes % 60:02d}" if minutes % 60 else "")


def _utm_zone(origin) -> str:
    zone = int((origin[1] + 180.0) // 6.0) % 60 + 1
    return f"UTM zone {zone}{'S' if origin[0] < 0 else 'N'}"


def _crs_name(code: str) -> str:
    from pyproj import CRS

    return CRS.from_user_input(code).name
