"""site.toml / asset.toml loading: every error names the file and the key."""

import textwrap
from pathlib import Path

import pytest

from helpers import twin
from pipeline import config
from pipeline.errors import UserError

ROOT = Path(__file__).resolve().parents[1]

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
    assert site.moving_parts == "auto"  # the Gazebo world's switches move within its parse budget


def test_a_site_chooses_whether_the_gazebo_worlds_switches_move(tmp_path):
    site = config.load_site(write(tmp_path, GOOD_SITE + '[gazebo]\nmoving_parts = "none"\n'))
    assert site.moving_parts == "none"
    assert config.load_site(write(tmp_path, GOOD_SITE + "[gazebo]\n")).moving_parts == "auto"
    some = config.load_site(write(tmp_path, GOOD_SITE + '[gazebo]\nmoving_parts = ["Q1-*", "89-[12]"]\n'))
    assert some.moving_parts == ("Q1-*", "89-[12]")
    assert [config.moves_in_gazebo(some.moving_parts, t) for t in ("Q1-89", "89-1", "89-3", "q1-89")] == \
        [True, True, False, False]
    assert config.moves_in_gazebo("all", "x") and not config.moves_in_gazebo("none", "x")
    with pytest.raises(ValueError):  # the scene decides "auto", and records what it chose
        config.moves_in_gazebo("auto", "x")


@pytest.mark.parametrize("mutate, key, words", [
    (lambda s: s.replace('crs = "EPSG:31984"\n', ""), "plan.crs", "missing required key"),
    (lambda s: s.replace("grid_rotation_deg = 23.0", 'grid_rotation_deg = "23"'), "plan.grid_rotation_deg", "not of type"),
    (lambda s: s.replace("EPSG:31984", "EPSG:999999"), "plan.crs", "unknown CRS"),
    (lambda s: s.replace("EPSG:31984", "EPSG:4326"), "plan.crs", "not a projected CRS"),
    (lambda s: s.replace('level = "L1"', 'level = "L9"'), "inspection_points[0].level", "not defined"),
    (lambda s: s.replace("[site]", "[site]\nbogus = 1"), "site.bogus", "unknown key"),
    (lambda s: s.replace("elevation = 48.0", "elevation = nan"), "levels[0].elevation", "finite"),
    (lambda s: s + '[gazebo]\nmoving_parts = "some"\n', "gazebo.moving_parts", "'some' is not one of ['auto', 'all', 'none']"),
    (lambda s: s + '[gazebo]\nmoving_parts = false\n', "gazebo.moving_parts", "False is not one of ['auto', 'all', 'none']"),
    (lambda s: s + '[gazebo]\nmoving = "none"\n', "gazebo.moving", "unknown key (known: moving_parts)"),
    (lambda s: s + '[gazebo]\nmoving_parts = []\n', "gazebo.moving_parts", "[] should be non-empty"),
    (lambda s: s + '[gazebo]\nmoving_parts = ["Q1-*", ""]\n', "gazebo.moving_parts[1]", "'' should be non-empty"),
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


def test_cli_info_counts_the_assets_it_reads_on_stderr(tmp_path):
    """`twin info` reads every asset's source (tens of seconds on the sample): a bar on
    stderr counts them, and stdout keeps the report alone."""
    import re

    import mini_sources

    src = mini_sources.make(tmp_path / "src")
    proc = twin("info", "--sources", src, timeout=300)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert re.search(r"reading\s.*\s2/2\s", proc.stderr), proc.stderr  # kiosk and pole
    assert "2/2" not in proc.stdout and "kiosk" in proc.stdout


# --- every config's problems at once, in site.toml's form --------------------------------

def _problems(error: UserError, path) -> list[tuple[str, str]]:
    """The (key, message) of each problem one UserError holds, checked against its text:
    one `file: key: message` line each."""
    problems = [(error.obj, error.message), *error.more]
    assert str(error).splitlines() == [f"{path}: {k}: {m}" for k, m in problems]
    assert error.file == str(path)
    return problems


def test_a_bad_site_toml_gives_every_problem_at_once(tmp_path):
    text = GOOD_SITE.replace("grid_rotation_deg = 23.0", 'grid_rotation_deg = "23"').replace("[site]", "[site]\nbogus = 1")
    path = write(tmp_path, text.replace('crs = "EPSG:31984"\n', ""))
    with pytest.raises(UserError) as e:
        config.load_site(path)
    keys = [k for k, _ in _problems(e.value, path)]
    assert keys == ["plan.crs", "plan.grid_rotation_deg", "site.bogus"]


def test_a_bad_dataset_config_gives_every_problem_at_once(tmp_path):
    from pipeline.datasets import config as dataset_config

    good = (ROOT / "sources" / "datasets" / "inspection_route.toml").read_text()
    bad = (good.replace("count = 240", "count = 0").replace("height = 480", "height = 480\nheigth = 4")
           .replace('level = "L1"\npath = [[4.0, 199.8]', 'path = [[4.0, 199.8]')  # cameras[0] loses its level
           .replace("zoom = [1.0, 8.0]", "zoom = [8.0, 1.0]")  # cameras[2]: out of order, for the code after
           .replace('dates = ["2025-03-20"', 'dates = ["2025-02-30"'))
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    with pytest.raises(UserError) as e:
        dataset_config.load(path)
    schema = dict(_problems(e.value, path))
    assert list(schema) == ["cameras[0].level", "dataset.count", "sensor.heigth"]
    assert "missing required key" in schema["cameras[0].level"] and "unknown key" in schema["sensor.heigth"]
    # the schema's problems come first; what only code can check is reported once they are fixed
    path.write_text(bad.replace("count = 0", "count = 240").replace("\nheigth = 4", "")
                    .replace('path = [[4.0, 199.8]', 'level = "L1"\npath = [[4.0, 199.8]'))
    with pytest.raises(UserError) as e:
        dataset_config.load(path)
    assert [k for k, _ in _problems(e.value, path)] == ["conditions.dates[0]", "cameras[2].zoom"]


def test_a_bad_study_toml_gives_every_problem_at_once(tmp_path):
    from pipeline.render import study

    good = (ROOT / "sources" / "study.toml").read_text()
    path = tmp_path / "study.toml"
    path.write_text(good.replace("zoom = 45.0", "zoom = 450.0").replace("seed = 20250920", "seed = -1")
                    .replace('target = "RE-B3"', ""))
    with pytest.raises(UserError) as e:
        study.load_study(path)
    assert [k for k, _ in _problems(e.value, path)] == ["target", "seed", "zoom"]
    path.write_text(good.replace('name = "midnight"', 'name = "solar_noon"').replace('time = "17:05"', 'time = "25:05"')
                    .replace('faces_sun_of = "late_afternoon"', 'faces_sun_of = "dusk"'))
    with pytest.raises(UserError) as e:
        study.load_study(path)
    assert [k for k, _ in _problems(e.value, path)] == ["conditions[2].time", "conditions[4].name", "faces_sun_of"]


def test_a_bad_scenario_gives_every_problem_at_once(tmp_path):
    from pipeline.runtime import graph

    path = tmp_path / "s.toml"
    path.write_text('[scenario]\nname = "../x"\nseed = -1\nduration_s = 10.0\nstart = "2025-03-20T09:00:00Z"\n'
                    '[[nodes]]\nid = "a"\ntype = "clock"\ncolour = 1\n')
    with pytest.raises(UserError) as e:
        graph.load_scenario(path)
    assert [k for k, _ in _problems(e.value, path)] == ["nodes[0].colour", "scenario.step_s", "scenario.name",
                                                        "scenario.seed"]


def test_the_config_schemas_hold_the_camera_models_zoom_range():
    from pipeline.runtime.camera import ZOOM_MAX, ZOOM_MIN

    cams = config.schema("dataset")["properties"]["cameras"]["items"]["properties"]
    zooms = [config.schema("study")["properties"]["zoom"], cams["presets"]["items"]["properties"]["zoom"],
             *cams["zoom"]["anyOf"][:1], cams["zoom"]["anyOf"][1]["items"]]
    assert {(z["minimum"], z["maximum"]) for z in zooms} == {(ZOOM_MIN, ZOOM_MAX)}
