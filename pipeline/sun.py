"""Sun position and direct irradiance at the site (PAPER_NOTES.md, "Sun and sky").

Two elevation models:

- `ephemeris`: astral 3.2's NOAA solar position for the site's latitude/longitude at
  the UTC instant. Geometric (no refraction) by default, because that is what the
  renderer's light direction and pvlib's `elevation` column mean; `refraction=True`
  gives astral's apparent elevation (about +0.5 deg at the horizon).
- `study`: the source study's theta = 90 sin(pi tau), tau = (t - sunrise) / (sunset -
  sunrise) from astral's sunrise/sunset of the local date. Outside the day (tau not in
  [0, 1]) it returns 0 (the study does not model night; the sun is "at the horizon" and
  its irradiance is 0). Polar days and nights, where astral's sunrise raises, return a
  documented constant: 0 for polar night, the ephemeris elevation for polar day.

Azimuth is always the ephemeris one (the study model has none): degrees clockwise
from north, so the ENU direction to the sun is (cos e sin a, cos e cos a, sin e).

Irradiance G = G0 exp(-tau_atm / sin theta) sin theta for theta > 0, else 0. As theta ->
0+ the exponential wins and G -> 0; at theta exactly 0 the formula is 0/0, so the
function returns 0 there, its limit (and IEEE underflow gives 0 just above it too).
"""

from __future__ import annotations

import datetime as dt
import math
from functools import lru_cache

import numpy as np

G0 = 1361.0  # W/m2, solar constant used by the study
DEFAULT_TAU_ATM = 0.2  # clear-sky optical depth; the study leaves it to the scenario


def _observer(lat: float, lon: float):
    import astral

    return astral.Observer(latitude=float(lat), longitude=float(lon), elevation=0.0)


def ephemeris(lat: float, lon: float, when: dt.datetime, refraction: bool = False) -> tuple[float, float]:
    """(elevation, azimuth) in degrees at the aware datetime `when`."""
    import astral.sun

    if when.tzinfo is None:
        raise ValueError("when must be timezone-aware")
    # one solar position for both: astral's elevation and azimuth each compute it (its
    # azimuth is taken before the refraction, which changes the zenith only)
    zenith, azimuth = astral.sun.zenith_and_azimuth(_observer(lat, lon), when, with_refraction=refraction)
    return float(90.0 - zenith), float(azimuth)


@lru_cache(maxsize=64)
def _day(lat: float, lon: float, date: dt.date, tz: dt.tzinfo) -> tuple[dt.datetime, dt.datetime] | str:
    """Sunrise and sunset of a local date, or "polar_day" / "polar_night"."""
    import astral.sun

    obs = _observer(lat, lon)
    try:
        return astral.sun.sunrise(obs, date, tzinfo=tz), astral.sun.sunset(obs, date, tzinfo=tz)
    except ValueError:
        # astral raises for both cases; the sign of the noon elevation tells them apart.
        noon = astral.sun.noon(obs, date, tzinfo=tz)
        return "polar_day" if astral.sun.elevation(obs, noon, with_refraction=False) > 0 else "polar_night"


def day_fraction(lat: float, lon: float, when: dt.datetime) -> float | str:
    """tau of the study at `when` (local date of `when`'s offset), or the polar case."""
    day = _day(float(lat), float(lon), when.date(), when.tzinfo)
    if isinstance(day, str):
        return day
    rise, sset = day
    return (when - rise).total_seconds() / (sset - rise).total_seconds()


def study_elevation(lat: float, lon: float, when: dt.datetime) -> float:
    """The study's simplified elevation in degrees (see module docstring)."""
    tau = day_fraction(lat, lon, when)
    if tau == "polar_night":
        return 0.0
    if tau == "polar_day":
        return ephemeris(lat, lon, when)[0]
    if not 0.0 <= tau <= 1.0:
        return 0.0
    return 90.0 * math.sin(math.pi * tau)


def irradiance(elevation_rad: float, tau_atm: float = DEFAULT_TAU_ATM, g0: float = G0) -> float:
    """Direct horizontal irradiance in W/m2; 0 at and below the horizon."""
    s = math.sin(elevation_rad)
    if not s > 0.0:
        return 0.0
    return g0 * math.exp(-tau_atm / s) * s


def direction_enu(elevation_rad: float, azimuth_rad: float) -> np.ndarray:
    """(3,) unit vector from the site towards the sun, ENU."""
    ce = math.cos(elevation_rad)
    return np.array([ce * math.sin(azimuth_rad), ce * math.cos(azimuth_rad), math.sin(elevation_rad)])
