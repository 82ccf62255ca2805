"""A site frame that does not hold together is one error naming the key: a CRS of the
other side of the world, a time zone of another continent, a stray INSERT far away
(real site.toml and DXF files, through `twin build` and `twin info`)."""

from __future__ import annotations

import shutil

import pytest
from pyproj import Transformer

import mini_sources
from pipeline.builder.tasks import load_sources
from pipeline.errors import UserError
from test_bounds import twin
from test_incremental import explain, tree_hashes


def origin_of_mini() -> tuple[float, float]:
    """lat, lon of the mini plan's grid origin (SIRGAS 2000 / UTM 24S, Bahia)."""
    lon, lat = Transformer.from_crs("EPSG:31984", "EPSG:4326", always_xy=True).transform(561234.5, 8595432.25)
    return lat, lon


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The mini sources with an [origin] at the site, built once."""
    root = tmp_path_factory.mktemp("frame")
    sources = mini_sources.make(root / "sources")
    lat, lon = origin_of_mini()
    site = sources / "site.toml"
    site.write_text(site.read_text() + f"\n[origin]\nlat = {lat:.7f}\nlon = {lon:.7f}\nheight = 48.0\n")
    explain(sources, root / "build")
    return sources, root / "build"


def _copy(sources, tmp_path, edit):
    src = tmp_path / "sources"
    shutil.copytree(sources, src)
    site = src / "site.toml"
    site.write_text(edit(site.read_text()))
    return src


def test_a_crs_of_the_other_side_of_the_world_is_an_error_naming_it(built, tmp_path):
    sources, out = built
    before = tree_hashes(out)
    src = _copy(sources, tmp_path, lambda t: t.replace('crs = "EPSG:31984"', 'crs = "EPSG:32650"'))
    proc = twin("build", "--sources", src, "--out", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "site.toml: plan.crs:" in proc.stderr
    assert "EPSG:32650 (WGS 84 / UTM zone 50N)" in proc.stderr and "UTM zone 24S" in proc.stderr
    assert tree_hashes(out) == before  # nothing was built on it
    info = twin("info", "--sources", src)
    assert info.returncode == 1 and "plan.crs" in info.stderr and "EPSG:32650" in info.stderr
    # an asset's package does not stand on the site's frame: --only builds it
    only = twin("build", "--sources", src, "--out", tmp_path / "only", "--only", "kiosk")
    assert only.returncode == 0, only.stderr[-2000:]


def test_without_origin_the_wrong_crs_contradicts_the_time_zone(tmp_path):
    sources = mini_sources.make(tmp_path / "sources")
    site = sources / "site.toml"
    site.write_text(site.read_text().replace('crs = "EPSG:31984"', 'crs = "EPSG:32650"'))
    with pytest.raises(UserError) as e:
        load_sources(sources)
    assert e.value.obj == "site.timezone"
    assert "America/Bahia keeps UTC-3" in e.value.message and "plan.crs" in e.value.message


def test_a_time_zone_that_contradicts_the_longitude_is_an_error(built, tmp_path):
    sources, out = built
    src = _copy(sources, tmp_path, lambda t: t.replace('"America/Bahia"', '"Asia/Shanghai"'))
    proc = twin("build", "--sources", src, "--out", tmp_path / "build")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "site.toml: site.timezone: Asia/Shanghai keeps UTC+8" in proc.stderr
    # a zone of the site's own region is fine, daylight saving or not, and UTC is a clock anyone may keep
    for zone in ("America/Sao_Paulo", "America/Recife", "UTC", "Etc/UTC"):
        load_sources(_copy(sources, tmp_path / zone.replace("/", "_"), lambda t: t.replace("America/Bahia", zone)))


def test_a_stray_insert_far_from_the_origin_is_named(built, tmp_path):
    sources, _ = built
    src = _copy(sources, tmp_path, lambda t: t)
    stray = [*mini_sources.PLACEMENTS, ("K-9", "kiosk", "L1", 48_000.0, 0.0, 0.0, 0.0)]
    mini_sources.write_plan(src / "floorplan" / "plan.dxf", stray)
    with pytest.raises(UserError) as e:
        load_sources(src)
    assert e.value.obj.startswith("INSERT K-9 (#") and "lands 48 km from [origin]" in e.value.message and "at plan (48000.0, 0.0) m" in e.value.message
