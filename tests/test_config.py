"""site.toml / asset.toml loading: every error names the file and the key."""

import textwrap

import pytest

from helpers import twin
from pipeline import config
from pipeline.errors import UserError

GOOD_SITE = """
[site]
name = "t"
timezone = "America/Bahia"
[plan]
crs = "EPSG:31984"
grid_origin = [560000.0, 8595000.0]
grid_rotation_deg = 23.0
[[levels]]
name = "L1"
elevation = 48.0
[[inspection_points]]
name = "p"
position = [1.0, 2.0, 1.6]
level = "L1"
"""


def write(tmp_path, text, name="site.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_good_site_loads_with_defaults(tmp_path):
    site = config.load_site(write(tmp_path, GOOD_SITE))
    assert site.crs == "EPSG:31984"
    assert site.grid_scale == 1.0 and site.slope_ratio == 1.5
    assert site.levels[0].elevation == 48.0
    assert site.natural_ground == 46.0
    assert site.inspection_points[0].position == (1.0, 2.0, 1.6)


@pytest.mark.parametrize("mutate, key, words", [
    (lambda s: s.replace('crs = "EPSG:31984"\n', ""), "plan.crs", "missing required key"),
    (lambda s: s.replace("grid_rotation_deg = 23.0", 'grid_rotation_deg = "23"'), "plan.grid_rotation_deg", "not of type"),
    (lambda s: s.replace("EPSG:31984", "EPSG:999999"), "plan.crs", "unknown CRS"),
    (lambda s: s.replace("EPSG:31984", "EPSG:4326"), "plan.crs", "not a projected CRS"),
    (lambda s: s.replace('level = "L1"', 'level = "L9"'), "inspection_points[0].level", "not defined"),
    (lambda s: s.replace("[site]", "[site]\nbogus = 1"), "site", "unknown key"),
    (lambda s: s.replace("elevation = 48.0", "elevation = nan"), "levels[0].elevation", "finite"),
])
def test_site_errors_name_file_and_key(tmp_path, mutate, key, words):
    path = write(tmp_path, mutate(GOOD_SITE))
    with pytest.raises(UserError) as e:
        config.load_site(path)
    assert e.value.file == str(path)
    assert e.value.obj == key
    assert words in e.value.message


def test_toml_syntax_error_names_file_and_line(tmp_path):
    path = write(tmp_path, GOOD_SITE + "\n[broken\n")
    with pytest.raises(UserError) as e:
        config.load_site(path)
    assert "TOML syntax error" in str(e.value) and "line" in str(e.value)
    assert str(path) in str(e.value)


def asset_dir(tmp_path, name="post", toml='category = "insulator"\nsource = "post.stl"\n'):
    d = tmp_path / "assets" / name
    d.mkdir(parents=True)
    (d / "post.stl").write_bytes(b"solid x\nendsolid x\n")
    (d / "asset.toml").write_text(toml)
    return d / "asset.toml"


def test_asset_config_defaults(tmp_path):
    cfg = config.load_asset_config(asset_dir(tmp_path))
    # units and up axis left to the file; scale 1 and the tessellation guard by default
    assert cfg.id == "post" and cfg.units is None and cfg.up_axis is None and cfg.scale == 1.0
    assert cfg.tessellation_max_triangles == 1_000_000
    assert cfg.lod_budgets_m == (0.005, 0.02, 0.08)
    assert cfg.collision_mode == "hull_per_link"


@pytest.mark.parametrize("toml, key", [
    ('source = "post.stl"\n', "category"),
    ('category = "insulator"\nsource = "post.stl"\nunits = "inch"\n', "units"),
    ('category = "insulator"\nsource = "post.stl"\nscale = 0\n', "scale"),
    ('category = "insulator"\nsource = "post.stl"\nup_axis = "-Y"\n', "up_axis"),
    ('category = "insulator"\nsource = "post.stl"\ntessellation_max_triangles = 0\n', "tessellation_max_triangles"),
    ('category = "insulator"\nsource = "../../etc/passwd.stl"\n', "source"),
    ('category = "insulator"\nsource = "missing.stl"\n', "source"),
    ('category = "insulator"\nsource = "post.stl"\n[lod]\nbudgets_m = [0.1, 0.01]\n', "lod.budgets_m"),
])
def test_asset_config_errors(tmp_path, toml, key):
    path = asset_dir(tmp_path, toml=toml)
    with pytest.raises(UserError) as e:
        config.load_asset_config(path)
    assert e.value.obj == key and e.value.file == str(path)


def test_asset_id_that_escapes_is_rejected(tmp_path):
    path = asset_dir(tmp_path, name="..evil")
    with pytest.raises(UserError, match="asset id"):
        config.load_asset_config(path)


def test_cli_reports_one_line_and_exit_1(tmp_path):
    (tmp_path / "site.toml").write_text(GOOD_SITE.replace("EPSG:31984", "EPSG:999999"))
    proc = twin("info", "--sources", tmp_path)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    lines = [l for l in proc.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and "plan.crs" in lines[0] and "site.toml" in lines[0]
