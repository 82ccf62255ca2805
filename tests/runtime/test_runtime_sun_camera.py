"""Sun model against pvlib's SPA, its documented edge cases, and the camera lens."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest

from helpers import SOURCES
from pipeline.runtime import camera, nodes
from pipeline import sun

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


@pytest.mark.parametrize("refraction", [False, True])
def test_ephemeris_is_astrals_elevation_and_azimuth_to_the_bit(refraction):
    """One solar position for both angles gives what astral's elevation() and
    azimuth() give called one by one, on any latitude, longitude and time."""
    import random

    import astral
    import astral.sun

    rng = random.Random(7)
    for _ in range(2000):
        lat, lon = rng.uniform(-89.9, 89.9), rng.uniform(-180.0, 180.0)
        when = dt.datetime(2025, 1, 1, tzinfo=dt.timezone.utc) + dt.timedelta(seconds=rng.uniform(0.0, 3.2e7))
        observer = astral.Observer(latitude=lat, longitude=lon, elevation=0.0)
        alone = (astral.sun.elevation(observer, when, with_refraction=refraction), astral.sun.azimuth(observer, when))
        assert sun.ephemeris(lat, lon, when, refraction) == alone


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
    ctx = nodes.RunContext(0, when, 1.0)
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


# --- the site's time zone ------------------------------------------------------------------

SITE_IN = """
[site]
name = "s"
date = "{date}"
timezone = "{zone}"
[plan]
crs = "EPSG:31984"
grid_origin = [576000.0, 8595900.0]
[origin]
lat = {lat}
lon = {lon}
height = 10.0
[[levels]]
name = "L1"
elevation = 10.0
"""


def site_in(tmp_path, zone: str, lat: float, lon: float, date: str = "2025-06-21"):
    from pipeline import config

    path = tmp_path / "site.toml"
    path.write_text(SITE_IN.format(zone=zone, lat=lat, lon=lon, date=date))
    return config.load_site(path)


def test_a_site_in_china_has_its_13_00_sun_high_and_lit(tmp_path):
    """Asia/Shanghai (UTC+8): 13:00 local in June is 05:00 UTC, the sun near its
    highest at lat 31 (about 74 degrees); 13:00 UTC would be night there."""
    from pipeline.scene.assemble import scene_sun

    site = site_in(tmp_path, "Asia/Shanghai", 31.0, 121.0)
    sun_ = scene_sun(site, site.origin)
    assert sun_["time_local"] == "2025-06-21T13:00:00+08:00" and sun_["time_utc"] == "2025-06-21T05:00:00+00:00"
    assert sun_["elevation_deg"] > 60.0
    assert sun_["intensity"] > 0.5 and sun_["illuminance_lux"] > 50_000


def test_the_scene_sun_follows_daylight_saving_time(tmp_path):
    """Europe/Berlin: 13:00 is 12:00 UTC in winter (CET) and 11:00 UTC in summer
    (CEST); either way the sun stands near the same hour angle."""
    from pipeline.scene.assemble import scene_sun

    winter = scene_sun(site := site_in(tmp_path, "Europe/Berlin", 52.5, 13.4, "2025-01-15"), site.origin)
    summer = scene_sun(site := site_in(tmp_path, "Europe/Berlin", 52.5, 13.4, "2025-07-15"), site.origin)
    assert winter["time_utc"] == "2025-01-15T12:00:00+00:00" and winter["time_local"].endswith("+01:00")
    assert summer["time_utc"] == "2025-07-15T11:00:00+00:00" and summer["time_local"].endswith("+02:00")
    assert 160.0 < winter["azimuth_deg"] < 200.0 and 160.0 < summer["azimuth_deg"] < 220.0
    assert summer["elevation_deg"] > 55.0 and 10.0 < winter["elevation_deg"] < 20.0


def test_an_unknown_zone_is_one_error_naming_site_toml(tmp_path):
    from pipeline.errors import UserError

    for zone, words in (("Mars/Olympus_Mons", "unknown time zone 'Mars/Olympus_Mons'"),
                        ("../../etc/passwd", "unknown time zone"), ("UTC-3", "unknown time zone")):
        with pytest.raises(UserError) as e:
            site_in(tmp_path, zone, 0.0, 0.0)
        assert (e.value.file, e.value.obj) == (str(tmp_path / "site.toml"), "site.timezone")
        assert words in e.value.message and "IANA" in e.value.message
    (tmp_path / "site.toml").write_text(SITE_IN.replace('timezone = "{zone}"\n', "").format(lat=0, lon=0, date="2025-01-01"))
    from pipeline import config

    with pytest.raises(UserError) as e:
        config.load_site(tmp_path / "site.toml")
    assert e.value.obj == "site.timezone" and "missing required key" in e.value.message
    assert "IANA" in e.value.message and "America/Bahia" in e.value.message


def test_local_times_that_a_zone_skips_or_repeats_are_refused():
    from zoneinfo import ZoneInfo

    from pipeline import config

    berlin = ZoneInfo("Europe/Berlin")
    assert config.local_time(dt.datetime(2025, 3, 30, 1, 59), berlin).utcoffset() == dt.timedelta(hours=1)
    assert config.local_time(dt.datetime(2025, 3, 30, 3, 0), berlin).utcoffset() == dt.timedelta(hours=2)
    with pytest.raises(ValueError, match="does not exist"):
        config.local_time(dt.datetime(2025, 3, 30, 2, 30), berlin)
    with pytest.raises(ValueError, match="happens twice.*02:30:00\\+02:00 or .*02:30:00\\+01:00"):
        config.local_time(dt.datetime(2025, 10, 26, 2, 30), berlin)


def test_a_scenario_start_without_offset_is_on_the_sites_clock(tmp_path):
    """The start is kept as its UTC instant; the study model's day is the local date
    in the site's zone, across a DST change too."""
    from zoneinfo import ZoneInfo

    from pipeline.errors import UserError
    from pipeline.runtime import graph

    scenario = tmp_path / "s.toml"
    body = ('[scenario]\nname = "t"\nseed = 1\nduration_s = 7200.0\nstep_s = 3600.0\nstart = "{start}"\n'
            '[[nodes]]\nid = "sun"\ntype = "sun"\nparams = {{ lat = {lat}, lon = {lon}, model = "study" }}\n')
    scenario.write_text(body.format(start="2025-03-30T01:00:00", lat=52.5, lon=13.4))
    s = graph.load_scenario(scenario, ZoneInfo("Europe/Berlin"))
    assert s.start == dt.datetime(2025, 3, 30, 0, 0, tzinfo=UTC)
    ctx = graph.Graph(s).ctx
    assert [ctx.local(t).isoformat() for t in (0, 3600, 7200)] == [
        "2025-03-30T01:00:00+01:00", "2025-03-30T03:00:00+02:00", "2025-03-30T04:00:00+02:00"]
    with pytest.raises(UserError, match="scenario.start.*no UTC offset, and no site time zone"):
        graph.load_scenario(scenario)
    scenario.write_text(body.format(start="2025-03-30T02:30:00", lat=52.5, lon=13.4))
    with pytest.raises(UserError, match="does not exist in Europe/Berlin"):
        graph.load_scenario(scenario, ZoneInfo("Europe/Berlin"))
    scenario.write_text(body.format(start="2025-06-21T07:00:00+08:00", lat=31.0, lon=121.0))  # an instant
    s = graph.load_scenario(scenario, ZoneInfo("Asia/Shanghai"))
    assert s.start == dt.datetime(2025, 6, 20, 23, 0, tzinfo=UTC)
    # 07:00 in Shanghai, about 2 h after sunrise: the study's tau of the local date, not of the UTC one
    elevation = math.degrees(graph.Graph(s).nodes["sun"].step(0.0, {})["elevation"])
    local = dt.datetime(2025, 6, 21, 7, tzinfo=ZoneInfo("Asia/Shanghai"))
    assert elevation == pytest.approx(sun.study_elevation(31.0, 121.0, local)) and 30.0 < elevation < 55.0


def test_the_study_runs_on_the_sites_clock(tmp_path):
    from zoneinfo import ZoneInfo

    from pipeline.errors import UserError
    from pipeline.runtime import site as render_site
    from pipeline.render import study

    site = render_site.BuiltSite(tmp_path, [], {}, (31.0, 121.0, 0.0), "2025-06-21", zone=ZoneInfo("Asia/Shanghai"))
    cfg = study.load_study(SOURCES / "study.toml")
    times = dict(study.study_times(site, cfg))
    assert times["early_morning"].isoformat() == "2025-06-21T06:45:00+08:00"
    noon = times["solar_noon"]
    assert noon.utcoffset() == dt.timedelta(hours=8) and dt.time(11, 50) < noon.time() < dt.time(12, 5)
    assert sun.ephemeris(31.0, 121.0, noon)[0] > 80.0
    site.zone = None
    with pytest.raises(UserError, match=r"\[site\] timezone"):
        study.study_times(site, cfg)
