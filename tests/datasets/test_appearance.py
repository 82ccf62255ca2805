"""A dataset config's [appearance] (issue 38 item 5): read against the schema, drawn per
frame from a stream of its own, leaving the frame's other draws alone."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import ROOT
from pipeline.errors import UserError
from pipeline.datasets import config as dataset_config
from test_dataset import LOOK, TINY, _config


def test_the_appearance_table_loads_and_is_optional(tmp_path):
    plain = dataset_config.load(_config(tmp_path))
    assert plain.appearance is None
    cfg = dataset_config.load(_config(tmp_path, TINY + LOOK))
    look = cfg.appearance
    assert look.dirt == (0.0, 0.8) and look.roughness_jitter == (0.1, 0.1) and look.exposure_ev == (-1.0, 1.0)
    assert dict(look.sky) == {"clear": 2.0, "overcast": 1.0, "hazy": 1.0}


@pytest.mark.parametrize("edit, key", [
    (lambda t: t.replace("dirt = [0.0, 0.8]", "dirt = [0.0, 1.8]"), "appearance.dirt[1]"),
    (lambda t: t.replace("hazy = 1 }", "foggy = 1 }"), "appearance.sky.foggy"),
    (lambda t: t.replace("clear = 2, overcast = 1, hazy = 1", "clear = 0"), "appearance.sky"),
    (lambda t: t.replace("{ clear = 2, overcast = 1, hazy = 1 }", "{}"), "appearance.sky"),
    (lambda t: t.replace("vignetting = [0.0, 0.3]", "vignette = 0.3"), "appearance.vignette"),
    (lambda t: t.replace("exposure_ev = [-1.0, 1.0]", "exposure_ev = [1.0, -1.0]"), "appearance.exposure_ev"),
])
def test_a_bad_appearance_is_one_error_naming_the_key(tmp_path, edit, key):
    path = _config(tmp_path, edit(TINY + LOOK))
    with pytest.raises(UserError) as e:
        dataset_config.load(path)
    assert e.value.obj == key


def test_a_frames_look_is_its_own_draw_and_leaves_the_rest_of_the_plan_alone(tmp_path):
    from pipeline.datasets.plan import appearance

    cfg = dataset_config.load(_config(tmp_path, TINY + LOOK))
    tags = ["RE-A2", "RE-A1", "T1"]
    a = appearance(cfg.appearance, cfg.seed, 3, tags)
    assert a == appearance(cfg.appearance, cfg.seed, 3, list(reversed(tags)))  # drawn in tag order
    assert a != appearance(cfg.appearance, cfg.seed, 4, tags)
    assert a["sky"] in ("clear", "overcast", "hazy") and -1.0 <= a["exposure_ev"] <= 1.0
    assert 0.0 <= a["vignetting"] <= 0.3 and sorted(a["instances"]) == sorted(tags)
    for v in a["instances"].values():
        assert all(0.8 <= c <= 1.2 for c in v["tint"]) and -0.1 <= v["roughness"] <= 0.1
        assert 0.0 <= v["dirt"] <= 0.8 and 0.2 <= v["weathering"] <= 0.6
    skies = {appearance(cfg.appearance, cfg.seed, i, tags)["sky"] for i in range(40)}
    assert skies == {"clear", "overcast", "hazy"}


@pytest.mark.slow
def test_an_appearance_table_changes_no_other_draw_of_a_frame(sample_build, tmp_path):
    from pipeline.datasets.plan import Planner
    from pipeline.runtime.site import load_site

    site = load_site(sample_build, ROOT / "sources")
    plain = Planner(dataset_config.load(_config(tmp_path)), site, ROOT / "sources")
    (tmp_path / "look").mkdir()
    looks = Planner(dataset_config.load(_config(tmp_path / "look", TINY + LOOK)), site, ROOT / "sources")
    for i in range(4):
        p, q = plain.plan(i), looks.plan(i)
        assert p.look is None and q.look is not None and sorted(q.look["instances"]) == sorted(q.visible_tags)
        assert p.seed == q.seed and np.array_equal(p.shot.cam_pose, q.shot.cam_pose)
        assert p.oil_levels == q.oil_levels and p.visible_tags == q.visible_tags
