"""Inputs that would expand without end fail fast with one error that says by what:
a floor plan of nested INSERTs, a dataset of a billion frames."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import ezdxf
import pytest

import mini_sources
from pipeline.config import FloorplanOptions
from pipeline.errors import UserError
from pipeline.ingest.floorplan import scan_floorplan

from helpers import ROOT


def twin(*args, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout)


def nested_plan(path: Path, levels: int, fan: int, leaf: str = "kiosk") -> Path:
    """A drawing whose modelspace holds `fan` INSERTs of block N<levels>, each block
    N<k> `fan` INSERTs of N<k-1>, and N1 `fan` INSERTs of the asset `leaf`: fan**(levels
    + 1) placements from (levels + 1) * fan INSERTs."""
    doc = ezdxf.new("R2018", setup=False)
    doc.header["$INSUNITS"] = 6
    doc.blocks.new(leaf)
    inner = leaf
    for k in range(1, levels + 1):
        block = doc.blocks.new(f"N{k}")
        for i in range(fan):
            block.add_blockref(inner, (0.5 * i, 0.0))
        inner = f"N{k}"
    msp = doc.modelspace()
    for i in range(fan):
        msp.add_blockref(inner, (0.0, 0.5 * i))
    msp.add_lwpolyline([(-4, -10), (22, -10), (22, 12), (-4, 12)], close=True, dxfattribs={"layer": "PLATFORM_L1"})
    doc.saveas(path)
    return path


def test_nested_inserts_of_ten_to_the_ten_placements_fail_fast(tmp_path):
    sources = mini_sources.make(tmp_path / "sources")
    nested_plan(sources / "floorplan" / "plan.dxf", levels=9, fan=10)  # 10 x 10^9 placements
    site = sources / "site.toml"
    site.write_text(site.read_text() + '\n[floorplan]\ndefault_level = "L1"\n')
    for command in ("build", "info"):
        t0 = time.perf_counter()
        extra = ("--out", tmp_path / "build") if command == "build" else ()
        proc = twin(command, "--sources", sources, *extra)
        assert time.perf_counter() - t0 < 60
        assert proc.returncode == 1, proc.stderr[-2000:]
        assert "Traceback" not in proc.stderr
        assert "nested INSERTs of block 'N9' expand to 10,000,000,000 placements" in proc.stderr
        assert "[floorplan] max_placements" in proc.stderr and "100,000" in proc.stderr


def test_the_placement_bound_is_a_site_toml_key(tmp_path):
    plan = nested_plan(tmp_path / "plan.dxf", levels=2, fan=10)  # 1,000 placements
    options = FloorplanOptions(default_level="L1", max_placements=999)
    with pytest.raises(UserError) as e:
        scan_floorplan(plan, {"kiosk"}, {"L1"}, options)
    assert e.value.obj == "block 'N2'" and "1,000 placements" in e.value.message and "999" in e.value.message
    fp, problems = scan_floorplan(plan, {"kiosk"}, {"L1"}, FloorplanOptions(default_level="L1",
                                                                            max_placements=1000))
    assert not problems and len(fp.placements) == 1000
    assert len({p.tag for p in fp.placements}) == 1000


# --- datasets ------------------------------------------------------------------------------


def test_a_billion_frames_is_refused_before_anything_is_planned(tmp_path):
    from pipeline.datasets import config as dataset_config
    from test_dataset import TINY

    config = tmp_path / "huge.toml"
    config.write_text(TINY.replace("count = 4", "count = 1000000000"))
    with pytest.raises(UserError) as e:
        dataset_config.load(config)
    assert e.value.obj == "dataset.count"
    assert "1,000,000,000 frames" in e.value.message and "at most 100,000" in e.value.message
    t0 = time.perf_counter()
    proc = twin("dataset", config, "--out", tmp_path / "build", timeout=60)
    assert time.perf_counter() - t0 < 30
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "dataset.count" in proc.stderr and "100,000" in proc.stderr
    config.write_text(TINY.replace("count = 4", "count = 100000"))
    assert dataset_config.load(config).count == 100_000  # the bound itself is a dataset


@pytest.mark.slow
@pytest.mark.blender
def test_a_run_plans_only_the_frames_it_renders(sample_build, tmp_path):
    """--frames 1 of a long config plans one frame: the scene its worker loads is what
    frame 0 sees, not what the config's 2,000 frames see."""
    import json

    from pipeline.datasets.plan import Planner
    from pipeline.runtime.site import load_site
    from test_dataset import CLOSE_FIRST, _scene_copy

    config = tmp_path / "long.toml"
    config.write_text(CLOSE_FIRST.replace("count = 4", "count = 2000"))
    out = _scene_copy(sample_build, tmp_path / "build")
    proc = twin("dataset", config, "--out", out, "--frames", "1", timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    timings = json.loads((out / "datasets" / "tiny" / "timings.json").read_text())
    from pipeline.datasets import config as dataset_config

    planner = Planner(dataset_config.load(config), load_site(out, ROOT / "sources"), ROOT / "sources")
    first = set(planner.plan(0).visible_tags)
    assert timings["frames"] == 1 and timings["scene_placements"] == len(first)
    assert len(first | set(planner.plan(1).visible_tags) | set(planner.plan(2).visible_tags)) > len(first)
    assert timings["plan_s"] < 10.0
