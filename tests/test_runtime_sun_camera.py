"""Sun model against pvlib's SPA, its documented edge cases, and the camera lens."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest

from pipeline.runtime import camera, nodes, sun

LAT, LON = -12.7, -38.3
UTC = dt.timezone.utc


def test_ephemeris_within_0_02_deg_of_spa_over_a_year():
    pd = pytest.importorskip("pandas")
    pvlib = pytest.importorskip("pvlib")
    times = pd.date_range("2025-01-01", "2025-12-31 23:00", freq="1h", tz="UTC")
    times = times[(times.dayofyear - 1) % 5 == 0]  # hourly, every 5th day
    ref = pvlib.solarposition.spa_python(times, LAT, LON, altitude=0)
    ours = np.array([sun.ephemeris(LAT, LON, t.to_pydatetime())[0] for t in times])
    day = ref["elevation"].to_numpy() > 0
    assert day.sum() > 800
    err = np.abs(ours - ref["elevation"].to_numpy())[day]
    assert err.max() < 0.02, err.max()


def test_irradiance_formula_and_horizon():
    e = math.radians(40.0)
    assert sun.irradiance(e, 0.2) == pytest.approx(1361 * math.exp(-0.2 / math.sin(e)) * math.sin(e))
    assert sun.irradiance(0.0, 0.2) == 0.0  # 0/0 in the limit: 0, documented
    assert sun.irradiance(-0.1, 0.2) == 0.0
    tiny = sun.irradiance(1e-300, 0.2)
    assert math.isfinite(tiny) and tiny == 0.0
    assert 0.0 < sun.irradiance(math.radians(1.0), 0.2) < sun.irradiance(math.radians(2.0), 0.2)


def test_study_model_is_90_sin_pi_tau_between_sunrise_and_sunset():
    import astral
    import astral.sun

    tz = dt.timezone(dt.timedelta(hours=-3))
    date = dt.date(2025, 3, 20)
    obs = astral.Observer(LAT, LON)
    rise, sset = astral.sun.sunrise(obs, date, tzinfo=tz), astral.sun.sunset(obs, date, tzinfo=tz)
    noon = rise + (sset - rise) / 2
    assert sun.study_elevation(LAT, LON, noon) == pytest.approx(90.0)
    quarter = rise + (sset - rise) / 4
    assert sun.study_elevation(LAT, LON, quarter) == pytest.approx(90 * math.sin(math.pi / 4))
    assert sun.study_elevation(LAT, LON, rise - dt.timedelta(hours=1)) == 0.0
    # The real noon elevation at the equinox is ~ 90 - |lat|: the study's model overshoots.
    assert sun.ephemeris(LAT, LON, noon)[0] == pytest.approx(90 - abs(LAT), abs=1.0)


@pytest.mark.parametrize("when, polar", [(dt.datetime(2025, 6, 21, 12, tzinfo=UTC), "polar_day"),
                                         (dt.datetime(2025, 12, 21, 12, tzinfo=UTC), "polar_night")])
def test_polar_day_and_night_give_finite_documented_values(when, polar):
    lat, lon = 78.2, 15.6  # Longyearbyen
    assert sun.day_fraction(lat, lon, when) == polar
    eph = sun.ephemeris(lat, lon, when)[0]
    assert math.isfinite(eph)
    study = sun.study_elevation(lat, lon, when)
    assert study == (eph if polar == "polar_day" else 0.0)
    assert (eph > 0) == (polar == "polar_day")
    ctx = nodes.Context(0, when, 1.0)
    out = nodes.Sun("s", {"lat": lat, "lon": lon, "model": "study"}, ctx).step(0.0, {})
    assert all(math.isfinite(v) for v in out.values())
    assert (out["irradiance"] > 0) == (polar == "polar_day")


def test_sun_direction_is_a_unit_enu_vector():
    d = sun.direction_enu(math.radians(30), math.radians(90))  # east, 30 deg up
    np.testing.assert_allclose(d, [math.cos(math.radians(30)), 0.0, 0.5], atol=1e-12)


@pytest.mark.parametrize("z, near, far, optical", [(1, 0.1, 1000, True), (10, 0.1, 1000, True),
                                                  (45, 0.45, 650, False), (100, 1.0, 100, False)])
def test_camera_zoom_mapping(z, near, far, optical):
    lens = camera.lens(z)
    assert lens.hfov == pytest.approx(1.047 / z)
    assert (lens.near, lens.far, lens.optical) == (pytest.approx(near), pytest.approx(far), optical)


@pytest.mark.parametrize("z", [0.99, 100.01, 0, -5, float("nan"), float("inf")])
def test_camera_rejects_zoom_outside_1_100(z):
    with pytest.raises(ValueError, match="outside"):
        camera.lens(z)
