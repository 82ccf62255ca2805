"""The runtime's sun for the page, and the site's clock.

The page does not compute the sun: it interpolates a table of the runtime's own
ephemeris (sun.ephemeris, astral's NOAA model, geometric elevation) sampled
at the site origin over the site's year. Samples are unit vectors towards the sun in
ENU (float32, little-endian, (n, 3)); the page interpolates them with the cubic
through the four nearest samples and normalises, which stays smooth where azimuth
is not (the zenith, north). `STEP_S` keeps that interpolation within a thousandth
of a degree of the ephemeris (tests/viewer/test_viewer.py measures it in the browser).

The clock: wall times in the site's `[site] timezone` become UTC through the zone's
offsets over the table's span, taken from Python's zoneinfo, so the page and the
runtime agree on every local time (DST included) whatever the browser's own tz data.
"""

from __future__ import annotations

import datetime as dt
import zoneinfo

import numpy as np

STEP_S = 1800  # seconds between samples
MARGIN = dt.timedelta(days=2)  # beyond the year: any zone's local year, and the stencil


def span(year: int) -> tuple[dt.datetime, int]:
    """(first sample instant, sample count) covering `year` on any clock."""
    start = dt.datetime(year, 1, 1, tzinfo=dt.timezone.utc) - MARGIN
    end = dt.datetime(year + 1, 1, 1, tzinfo=dt.timezone.utc) + MARGIN
    return start, int((end - start).total_seconds()) // STEP_S + 1


def directions(lat: float, lon: float, start: dt.datetime, count: int) -> np.ndarray:
    """(count, 3) float64 ENU unit vectors towards the sun at start + k STEP_S."""
    from .. import sun

    out = np.empty((count, 3))
    for k in range(count):
        elevation, azimuth = sun.ephemeris(lat, lon, start + dt.timedelta(seconds=k * STEP_S))
        out[k] = sun.direction_enu(np.radians(elevation), np.radians(azimuth))
    return out


def table_bytes(lat: float, lon: float, year: int) -> bytes:
    start, count = span(year)
    return directions(lat, lon, start, count).astype("<f4").tobytes()


def offsets(zone: zoneinfo.ZoneInfo, start: dt.datetime, end: dt.datetime) -> list[list]:
    """The zone's UTC offsets over [start, end): [[from (UTC seconds), offset (s),
    abbreviation], ...], the first from `start`. A change is found hour by hour and
    placed to the second by bisection (zones change on whole seconds)."""

    def at(t: int) -> tuple[int, str]:
        local = dt.datetime.fromtimestamp(t, dt.timezone.utc).astimezone(zone)
        return int(local.utcoffset().total_seconds()), local.tzname() or ""

    t0, t1 = int(start.timestamp()), int(end.timestamp())
    out = [[t0, *at(t0)]]
    for t in range(t0 + 3600, t1 + 3600, 3600):
        if at(t) == tuple(out[-1][1:]):
            continue
        lo, hi = t - 3600, t  # at(lo) is the current period, at(hi) the next
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if at(mid) == tuple(out[-1][1:]) else (lo, mid)
        out.append([hi, *at(hi)])
    return out


def describe(lat: float, lon: float, year: int, zone: zoneinfo.ZoneInfo) -> dict:
    """What twin.json says about the table (file written beside it) and the clock."""
    from .. import sun

    start, count = span(year)
    end = start + dt.timedelta(seconds=(count - 1) * STEP_S)
    return {"sun": {"file": "sun.bin", "latitude_deg": lat, "longitude_deg": lon, "start_utc_s": int(start.timestamp()),
                    "step_s": STEP_S, "count": count, "year": year, "tau_atm": sun.DEFAULT_TAU_ATM, "g0_w_m2": sun.G0},
            "clock": {"zone": zone.key, "offsets": offsets(zone, start, end)}}
