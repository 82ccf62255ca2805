"""Plan -> CRS -> geodetic -> ENU, checked against pyproj and plain geodesy."""

from __future__ import annotations

import dataclasses
import math

import ezdxf
import numpy as np
import pytest
from pyproj import Proj, Transformer

from helpers import ROOT, SOURCES
from pipeline import ir
from pipeline.bench.georef import bench_georef
from pipeline.config import load_site
from pipeline.errors import UserError
from pipeline.georef import Georeferencer, crs_to_plan, default_origin, plan_to_crs
from pipeline.ingest.floorplan import read_floorplan

SITE_TOML = SOURCES / "site.toml"
A_WGS84, F_WGS84 = 6378137.0, 1 / 298.257223563


@pytest.fixture(scope="module")
def sample_site():
    return load_site(SITE_TOML)


def site_at(base, crs, lat, lon, h=50.0, rotation=0.0, scale=1.0):
    """A site whose drawing (0, 0) and ENU origin are the geodetic point (lat, lon, h)."""
    e, n = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    return dataclasses.replace(base, crs=crs, grid_origin=(e, n), grid_rotation_deg=rotation, grid_scale=scale, origin=(lat, lon, h))


def ecef(lat, lon, h):
    """Geodetic WGS84 -> ECEF by the textbook formula (independent of PROJ). (n, 3)."""
    la, lo = np.radians(lat), np.radians(lon)
    e2 = F_WGS84 * (2 - F_WGS84)
    nrad = A_WGS84 / np.sqrt(1 - e2 * np.sin(la) ** 2)
    return np.stack([(nrad + h) * np.cos(la) * np.cos(lo), (nrad + h) * np.cos(la) * np.sin(lo), (nrad * (1 - e2) + h) * np.sin(la)], axis=-1)


def reference_enu(lat, lon, h, origin):
    """ENU by the textbook ECEF rotation: (n, 3)."""
    lat0, lon0, h0 = origin
    d = ecef(lat, lon, h) - ecef(lat0, lon0, h0)
    la, lo = math.radians(lat0), math.radians(lon0)
    r = np.array([
        [-math.sin(lo), math.cos(lo), 0],
        [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
        [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
    ])
    return d @ r.T


def test_plan_to_crs_rotation_and_scale(sample_site):
    unit = np.array([[1.0, 0.0], [0.0, 1.0]])
    e0, n0 = 500000.0, 9999000.0
    for rot, ex, ey in ((0.0, (1, 0), (0, 1)), (90.0, (0, 1), (-1, 0)), (180.0, (-1, 0), (0, -1))):
        s = dataclasses.replace(sample_site, grid_origin=(e0, n0), grid_rotation_deg=rot, grid_scale=2.0)
        en = plan_to_crs(unit, s)
        assert np.allclose(en - (e0, n0), 2.0 * np.array([ex, ey]), rtol=0, atol=1e-9)
        assert np.allclose(crs_to_plan(en, s), unit, rtol=0, atol=1e-9)


def test_to_enu_matches_pyproj_and_textbook_geodesy(sample_site):
    g = Georeferencer(sample_site)
    xy = np.array([[0.0, 0.0], [104.0, 206.0], [212.75, 0.0], [-300.0, 450.0], [5000.0, -3000.0]])
    h = np.array([48.0, 56.0, 52.5, 40.0, 120.0])
    en = plan_to_crs(xy, sample_site)
    lon, lat = Transformer.from_crs("EPSG:31984", "EPSG:4326", always_xy=True).transform(en[:, 0], en[:, 1])
    expected = reference_enu(lat, lon, h, sample_site.origin)
    got = g.to_enu(xy, h)
    assert got.dtype == np.float64 and got.shape == (5, 3)
    assert np.abs(got - expected).max() < 1e-6
    # PROJ's topocentric step and the numpy ECEF rotation agree, origin maps to zero.
    via_pyproj_ecef = np.stack(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(lon, lat, h), axis=1)
    assert np.abs(ecef(lat, lon, h) - via_pyproj_ecef).max() < 1e-6
    o = crs_to_plan(np.array([g.origin_en]), sample_site)
    assert np.abs(g.to_enu(o, sample_site.origin[2])).max() < 1e-6


def test_curvature_and_naive_error_at_300_m(sample_site):
    g = Georeferencer(sample_site)
    o = crs_to_plan(np.array([g.origin_en]), sample_site)[0]
    a = np.radians(np.arange(0, 360, 30))
    xy = o + 300.0 * np.stack([np.cos(a), np.sin(a)], axis=1)
    h0 = sample_site.origin[2]
    exact = g.to_enu(xy, np.full(len(xy), h0))
    # Curvature: 300 m away the ground is d^2 / 2R ~ 7 mm below the tangent plane.
    assert np.all((exact[:, 2] < -6.5e-3) & (exact[:, 2] > -7.5e-3))
    # Grid distance = ellipsoid distance x scale factor k (about 0.99967 here); at height
    # h the ground distance is (R + h) / R longer again (the elevation factor).
    k = Proj("EPSG:31984").get_factors(sample_site.origin[1], sample_site.origin[0]).meridional_scale
    ground = 300.0 / k * (1.0 + h0 / 6.37e6)
    assert np.allclose(np.hypot(exact[:, 0], exact[:, 1]), ground, rtol=0, atol=3e-4)
    # Naive: convergence 0.154 deg (0.81 m at 300 m) and scale (0.1 m): 0.7 .. 0.9 m.
    err = np.linalg.norm(g.naive_enu(xy, h0) - exact, axis=1)
    assert np.all((err > 0.7) & (err < 0.9))


def _reference_yaw(site, xy, heading_deg):
    """Yaw of a block x axis from the meridian convergence and the ENU frame's turn."""
    proj = Proj(site.crs)
    en = plan_to_crs(xy, site)
    lon, lat = proj(en[:, 0], en[:, 1], inverse=True)
    gamma = np.asarray(proj.get_factors(lon, lat).meridian_convergence)
    # Grid bearing counter-clockwise from grid east -> true direction at the point.
    true = np.radians(heading_deg + site.grid_rotation_deg - gamma)
    la, lo = np.radians(lat), np.radians(lon)
    east = np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=1)
    north = np.stack([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)], axis=1)
    d = np.cos(true)[:, None] * east + np.sin(true)[:, None] * north  # ECEF direction
    lat0, lon0, _ = site.origin
    a, b = math.radians(lat0), math.radians(lon0)
    e0 = np.array([-math.sin(b), math.cos(b), 0])
    n0 = np.array([-math.sin(a) * math.cos(b), -math.sin(a) * math.sin(b), math.cos(a)])
    return np.arctan2(d @ n0, d @ e0), gamma


@pytest.mark.parametrize("rotation", [0.0, 90.0, 180.0, 23.0])
def test_headings_include_convergence(sample_site, rotation):
    s = dataclasses.replace(sample_site, grid_rotation_deg=rotation)
    g = Georeferencer(s)
    o = crs_to_plan(np.array([g.origin_en]), s)[0]
    xy = np.array([o, o + (2000.0, 0.0), o + (0.0, -3000.0), o + (150.0, 150.0)])
    heading = np.array([0.0, 90.0, 180.0, 270.0])
    yaw = g.headings(xy, heading)
    ref, gamma = _reference_yaw(s, xy, heading)
    diff = np.angle(np.exp(1j * (yaw - ref)))
    # get_factors takes numerical derivatives: its convergence is good to ~2e-8 rad.
    assert np.abs(diff).max() < 1e-7
    # At the origin it is heading + rotation - convergence (about -0.154 deg).
    assert abs(gamma[0] + 0.154) < 0.002
    assert math.isclose(math.remainder(yaw[0] - math.radians(rotation - gamma[0]), math.tau), 0.0, abs_tol=1e-7)
    # Ignoring convergence would be wrong by far more than the tolerance.
    assert abs(math.remainder(yaw[0] - math.radians(rotation), math.tau)) > 2e-3


def test_site_straddling_a_utm_zone_boundary(sample_site):
    """Zone 24S ends at 36 W. The same ground described in zone 24S and in 25S gives
    the same ENU, exact on both sides of the boundary."""
    lat0, lon0 = -12.70, -36.0
    s24 = site_at(sample_site, "EPSG:31984", lat0, lon0, rotation=15.0)
    s25 = site_at(sample_site, "EPSG:31985", lat0, lon0, rotation=-7.0)
    lon = np.array([-36.004, -36.001, -35.999, -35.996, -35.990])
    lat = np.array([-12.703, -12.698, -12.701, -12.695, -12.705])
    h = np.array([50.0, 51.0, 52.0, 49.0, 55.0])
    expected = reference_enu(lat, lon, h, s24.origin)
    for s in (s24, s25):
        e, n = Transformer.from_crs("EPSG:4326", s.crs, always_xy=True).transform(lon, lat)
        xy = crs_to_plan(np.stack([e, n], axis=1), s)
        assert np.abs(Georeferencer(s).to_enu(xy, h) - expected).max() < 1e-6


def test_northings_near_ten_million_are_mm_exact(sample_site):
    # Just south of the equator on zone 24S's central meridian: N ~ 9 998 900 m.
    s = site_at(sample_site, "EPSG:31984", -0.01, -39.0, h=10.0)
    assert s.grid_origin[1] > 9.99e6
    g = Georeferencer(s)
    xy = np.array([[120.0, -80.0], [120.001, -80.0], [120.0, -79.999]])
    enu = g.to_enu(xy, np.full(3, 10.0))
    k = Proj("EPSG:31984").get_factors(-39.0, -0.01).meridional_scale
    # A 1 mm step in the grid is 1 mm / k on the ground, to a micrometre.
    assert np.linalg.norm(enu[1] - enu[0]) == pytest.approx(1e-3 / k, abs=1e-6)
    assert np.linalg.norm(enu[2] - enu[0]) == pytest.approx(1e-3 / k, abs=1e-6)
    en = plan_to_crs(xy, s)
    lon, lat = Transformer.from_crs("EPSG:31984", "EPSG:4326", always_xy=True).transform(en[:, 0], en[:, 1])
    assert np.abs(enu - reference_enu(lat, lon, np.full(3, 10.0), s.origin)).max() < 1e-6


def test_millimetre_plan_georeferences_like_a_metre_plan(sample_site, tmp_path):
    g = Georeferencer(sample_site)
    out = []
    for units, f in ((6, 1.0), (4, 1000.0)):
        doc = ezdxf.new("R2010", setup=False)
        doc.header["$INSUNITS"] = units
        doc.blocks.new("current_transformer")
        ref = doc.modelspace().add_blockref("current_transformer", (187.345 * f, 93.125 * f, 0.5 * f), dxfattribs={"rotation": 33.0})
        ref.add_attrib("TAG", "TC-1A")
        ref.add_attrib("LEVEL", "L2")
        doc.saveas(tmp_path / f"{units}.dxf")
        fp = read_floorplan(tmp_path / f"{units}.dxf", levels=set(sample_site.level_names))
        out.append(g.placements_enu(fp.placements))
    (pm, ym), (pmm, ymm) = out
    assert np.abs(pm - pmm).max() < 1e-9 and np.abs(ym - ymm).max() < 1e-12
    # height = level elevation + INSERT z
    en = plan_to_crs([[187.345, 93.125]], sample_site)
    lon, lat = Transformer.from_crs("EPSG:31984", "EPSG:4326", always_xy=True).transform(en[0, 0], en[0, 1])
    assert np.abs(pm - reference_enu(np.array([lat]), np.array([lon]), np.array([53.0]), sample_site.origin)).max() < 1e-6


def test_default_origin_is_the_platform_centre(sample_site):
    s = dataclasses.replace(sample_site, origin=None)
    with pytest.raises(UserError) as e:
        Georeferencer(s)
    assert e.value.obj == "origin" and e.value.file == str(sample_site.path)
    plats = [ir.Platform("L2", [(100, 0), (200, 0), (200, 50), (100, 50)]), ir.Platform("L1", [(0, -20), (90, -20), (90, 80), (0, 80)])]
    origin = default_origin(s, plats)
    assert origin[2] == min(lv.elevation for lv in s.levels)
    g = Georeferencer(s, origin)
    assert np.abs(g.to_enu([[100.0, 30.0]], origin[2])).max() < 1e-6
    with pytest.raises(UserError):
        default_origin(s, [])


def test_sample_origin_is_the_centre_of_the_sample_platforms(sample_site):
    fp = read_floorplan(SITE_TOML.parent / sample_site.floorplan)
    lat, lon, h = default_origin(sample_site, fp.platforms)
    assert (lat, lon, h) == pytest.approx(sample_site.origin, abs=1e-7)


def test_bench_reports_speed_and_naive_error(sample_site):
    plats = [ir.Platform("L1", [(0, 0), (200, 0), (200, 200), (0, 200)])]
    r = bench_georef(sample_site, plats, n=20_000)
    assert r["exact_points_per_s"] > 0 and r["naive_points_per_s"] > 0
    assert r["naive_error_far_corner_m"] > r["naive_error_grid_median_m"] > 0
    assert r["naive_error_grid_max_m"] >= r["naive_error_far_corner_m"] - 1e-9
    assert 0.002 < r["naive_error_far_corner_m"] / r["far_corner_distance_m"] < 0.004  # ~2.7 mm per m


def test_headings_do_not_depend_on_what_the_process_ran_before():
    """Two clean builds must give the same yaw bits whichever worker runs the scene:
    the first headings() call in a fresh process equals later ones bit for bit."""
    import subprocess
    import sys

    code = (
        "import numpy as np, hashlib\n"
        "from pathlib import Path\n"
        "from pipeline.scene.assemble import _load\n"
        "site, fp, g = _load(Path('sources'))\n"
        "xy = np.array([[p.x, p.y] for p in fp.placements]); hd = np.array([p.heading_deg for p in fp.placements])\n"
        "a = g.headings(xy, hd); b = g.headings(xy, hd)\n"
        "print(int((a != b).sum()), hashlib.sha256(a.tobytes()).hexdigest())\n"
    )
    root = ROOT
    outs = [subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True).stdout
            for _ in range(2)]
    assert outs[0] == outs[1] and outs[0].split()[0] == "0", outs
