"""`twin bench`: a quick smoke run on the mini sources, plus the bench's small pure parts.

Benchmarks are not timed tests: nothing here asserts a speed, only that the harness
runs every section, writes both files, and that bench.json matches its schema.
"""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest

import mini_sources
from helpers import ROOT
from pipeline.bench import plans, report, sections, stats, summary
from pipeline.bench.builds import edit_description, nudge_lod_budget

SCHEMA = ROOT / "schemas" / "bench.schema.json"


def validator():
    schema = json.loads(SCHEMA.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def test_pareto_front():
    pts = [(1.0, 5.0), (2.0, 1.0), (3.0, 3.0), (0.5, 9.0), (2.0, 1.0)]
    assert sections.pareto(pts) == [0, 1, 3, 4]  # (3, 3) is beaten by (2, 1); equal points both stay


def test_repeat_respects_bounds_and_budget():
    calls = []
    out = stats.repeat(lambda i: calls.append(i) or 5.0, 1, 4, budget_s=0.0)
    assert out == [5.0] and calls == [0]
    out = stats.repeat(lambda i: 1.0, 3, 3, budget_s=1e9)
    assert out == [1.0, 1.0, 1.0]
    s = stats.summarize([3.0, 1.0, 2.0])
    assert s == {"median_s": 2.0, "min_s": 1.0, "max_s": 3.0, "repeats": 3}


def test_edit_description_changes_only_description(tmp_path):
    toml = tmp_path / "asset.toml"
    toml.write_text('category = "kiosk"\ndescription = "old"\nsource = "k.stl"\n[lod]\nbudgets_m = [0.01]\n')
    edit_description(toml, 'new "quoted"')
    text = toml.read_text()
    assert 'description = "new \\"quoted\\""' in text and "old" not in text and "budgets_m" in text
    bare = tmp_path / "bare.toml"
    bare.write_text('category = "kiosk"\n[lod]\nbudgets_m = [0.01]\n')
    edit_description(bare, "added")
    import tomllib

    assert tomllib.loads(bare.read_text())["description"] == "added"


def test_nudge_lod_budget_scales_only_the_coarsest_budget(tmp_path):
    import tomllib

    toml = tmp_path / "asset.toml"
    toml.write_text('category = "kiosk"\nsource = "k.stl"\n[lod]\nbudgets_m = [0.004, 0.02]\n[collision]\nmode = "hull"\n')
    nudge_lod_budget(toml, 1.5)
    data = tomllib.loads(toml.read_text())
    assert data["lod"]["budgets_m"] == [0.004, 0.02 * 1.5] and data["collision"] == {"mode": "hull"}


def test_repeated_and_unique_plans(tmp_path):
    from pipeline import config
    from pipeline.ingest.floorplan import read_floorplan

    src = mini_sources.make(tmp_path / "src")
    rep = plans.repeated(src, tmp_path / "rep", 3)
    site = config.load_site(rep / "site.toml")
    fp = read_floorplan(site.root / site.floorplan)
    assert len(fp.placements) == 3 * len(mini_sources.PLACEMENTS)
    assert len(fp.platforms) == 3 * 2
    assert (rep / "assets").resolve() == (src / "assets").resolve()
    uniq, chosen = plans.unique_assets(src, tmp_path / "uniq", 1)
    site = config.load_site(uniq / "site.toml")
    assert [p.asset_id for p in read_floorplan(site.root / site.floorplan).placements] == chosen == ["kiosk"]
    scale = plans.at_scale(src, tmp_path / "scale", 20, 7)
    site = config.load_site(scale / "site.toml")
    placed = read_floorplan(site.root / site.floorplan).placements
    assert len(placed) == 20 and len({(p.x, p.y) for p in placed if "-P" in p.tag}) == 1
    assert sum("-P" in p.tag for p in placed) == 7 and {p.level for p in placed if "-P" in p.tag} == {"L1"}
    before = (rep / "floorplan" / "plan.dxf").read_bytes()
    plans.salt_plan(rep / "floorplan" / "plan.dxf", "x")
    assert (rep / "floorplan" / "plan.dxf").read_bytes() != before


def test_summary_tolerates_failed_sections():
    assert summary.rows({"lod": {"ok": False, "error": "x", "seconds": 0.0}}) == []


def test_clean_makes_json_safe():
    import numpy as np

    got = report.clean({"a": float("nan"), "b": np.float64(2.0), "c": [np.int64(3), float("inf")]})
    assert got == {"a": None, "b": 2.0, "c": [3, None]}
    json.dumps(got, allow_nan=False)


@pytest.mark.slow
@pytest.mark.long
def test_quick_bench_on_mini_sources(tmp_path):
    from pipeline.bench import run_bench

    src = mini_sources.make(tmp_path / "src")
    page = run_bench(src, tmp_path / "build", quick=True)
    reports = tmp_path / "build" / "reports"
    assert page == reports / "bench.html"
    doc = json.loads((reports / "bench.json").read_text())
    errors = sorted(validator().iter_errors(doc), key=lambda e: list(e.path))
    assert not errors, [f"{list(e.path)}: {e.message}" for e in errors[:5]]
    failed = {k: v["error"] for k, v in doc["sections"].items() if not v["ok"]}
    assert not failed, failed
    assert {"build", "lod", "georef", "runtime", "sun", "render", "blender", "gltf_transform"} <= set(doc["sections"])
    assert doc["summary"] and doc["targets"]
    html = page.read_text()
    assert html.count("data:image/png;base64,") >= 6 and "Summary" in html


def test_resave_source_changes_bytes_not_content(tmp_path):
    """The bench's 'saved again' edit: new bytes the reader reads as the same mesh."""
    from pipeline.bench.builds import resave_source
    from pipeline.ingest.readers import read_source
    from pipeline import config

    src = mini_sources.make(tmp_path / "src")
    for asset in ("kiosk", "pole"):
        cfg = config.load_asset_config(src / "assets" / asset / "asset.toml")
        before_bytes, before = cfg.source.read_bytes(), read_source(cfg)
        resave_source(cfg.source)
        after = read_source(cfg)
        assert cfg.source.read_bytes() != before_bytes
        for a, b in zip(before.links, after.links):
            for va, vb in zip(a.visuals, b.visuals):
                assert np.array_equal(va.mesh.vertices, vb.mesh.vertices) and np.array_equal(va.mesh.faces, vb.mesh.faces)


def test_scale_rows_put_the_sample_the_large_plan_both_ways_and_the_stacked_one_side_by_side():
    from pipeline.bench.builds import _scale_side_rows

    def side(n, seconds, rss, parse_s, parse_mb, rtf):
        return {"placements": n, "load_avg": [3.5, 3.0, 2.0], "validate": {"seconds": seconds, "maxrss_bytes": rss},
                "world": {"parse_s": parse_s, "peak_rss_mb": parse_mb}, "physics": {"real_time_factor": rtf},
                "elements": {"visuals": 10, "collisions": 4}}

    def probed(moving_parts, parse_s, cpu_s, parse_mb, rtf, joints, load):
        return {"placements": 5000, "moving_parts": moving_parts, "load_avg": [load, 3.0, 2.0],
                "world": {"parse_s": parse_s, "parse_cpu_s": cpu_s, "peak_rss_mb": parse_mb},
                "physics": {"real_time_factor": rtf, "real_time_factor_cpu": 2 * rtf},
                "elements": {"models": 40, "links": 1500, "joints": joints, "visuals": 3000, "collisions": 20}}

    stacked = {"placements": 1787, "piled": 1000, "load_avg": [9.0, 3.0, 2.0],
               "world": {"parse_s": 3.6, "parse_cpu_s": 1.3, "peak_rss_mb": 542.0},
               "physics": {"real_time_factor": 6.25, "real_time_factor_cpu": 25.0},
               "elements": {"visuals": 1573, "collisions": 67}}
    rows = _scale_side_rows({"sides": {"sample": side(787, 20.0, 1.0e9, 3.0, 900.0, 2.0),
                                       "scale": side(5000, 70.0, 2.5e9, 12.0, 2091.0, 0.25),
                                       "moving_all": probed("all", 7.4, 6.0, 3600.0, 0.25, 1400, 4.5),
                                       "moving_none": probed("none", 3.0, 2.5, 1260.0, 8.0, 0, 5.5),
                                       "stacked": stacked}})
    got = {t: (v, lim) for t, v, lim, _ in rows}
    assert len(rows) == 19 and sum("(load 3.5)" in t for t in got) == 10
    assert got["787 placements (load 3.5): twin validate under 60 s"] == (20.0, 60.0)
    assert got["5,000 placements (load 3.5): Gazebo world parse under 1.5 GB"] == (2.091, 1.5)
    assert got["5,000 placements (load 3.5): dartsim (bullet) at real time or faster (wall s per simulated s)"] == (4.0, 1.0)
    assert got["787 placements (load 3.5): dartsim (bullet) at real time or faster (wall s per simulated s)"] == (0.5, 1.0)
    assert "10 visuals, 4 collisions" in next(t for t in got if t.startswith("5,000") and "parse under 10 s" in t)
    # the large plan's world both ways, each row saying which, with its joints and load
    every = '5,000 placements, moving_parts = "all" (load 4.5)'
    none = '5,000 placements, moving_parts = "none" (load 5.5)'
    assert got[f"{every}: Gazebo world parse under 1.5 GB"] == (3.6, 1.5)
    assert got[f"{none}: Gazebo world parse under 1.5 GB"] == (1.26, 1.5)
    parse = "Gazebo world parse under 10 s"
    assert got[f"{every}: {parse} (1,400 joints, 3,000 visuals, 20 collisions; 6.0 s CPU)"] == (7.4, 10.0)
    assert got[f"{none}: {parse} (0 joints, 3,000 visuals, 20 collisions; 2.5 s CPU)"] == (3.0, 10.0)
    step = "dartsim (bullet) at real time or faster (wall s per simulated s"
    assert got[f"{every}: {step}; 2.000 CPU s per simulated s)"] == (4.0, 1.0)
    assert got[f"{none}: {step}; 0.062 CPU s per simulated s)"] == (0.125, 1.0)
    assert not any(t.startswith("5,000 placements, moving_parts") and "validate" in t for t in got)
    # the stacked plan is probed, not validated; its CPU times beside the wall times
    at = "1,787 placements, 1,000 at one point (load 9.0)"
    assert not any(t.startswith(at) and "validate" in t for t in got)
    assert got[f"{at}: Gazebo world parse under 10 s (1,573 visuals, 67 collisions; 1.3 s CPU)"] == (3.6, 10.0)
    assert got[f"{at}: dartsim (bullet) at real time or faster (wall s per simulated s; 0.040 CPU s per simulated s)"] \
        == (0.16, 1.0)
    # the summary: "all" against "none", measured in the same run
    both = summary.rows({"scale": {"ok": True, "data": {"sides": {
        "moving_all": probed("all", 7.4, 6.0, 3600.0, 0.25, 1400, 4.5),
        "moving_none": probed("none", 3.0, 2.5, 1260.0, 8.0, 0, 5.5)}}}})
    by_metric = {r["metric"]: r for r in both}
    assert {r["peer_name"] for r in both} == {'[gazebo] moving_parts = "none"'}
    assert by_metric["Gazebo world parse peak memory"]["ratio"] == pytest.approx(3600.0 / 1260.0)
    assert by_metric["Gazebo world parse time"]["ours"] == 7.4 and by_metric["Gazebo world parse time"]["peer"] == 3.0
    assert by_metric["dartsim (bullet) wall s per simulated s"]["ratio"] == pytest.approx(32.0)
    assert "1,400 joints against 0" in by_metric["Gazebo world parse CPU time"]["note"]
    assert summary.rows({"scale": {"ok": True, "data": {"sides": {}}}}) == []


def test_the_scale_run_writes_its_world_without_moving_parts_by_site_toml(tmp_path):
    """The edit the scale run makes: [gazebo] moving_parts set, whatever the file holds
    of [gazebo] already; the rest of site.toml as it was."""
    import tomllib

    from pipeline.bench.worlds import set_moving_parts

    src = mini_sources.make(tmp_path / "src")
    site = src / "site.toml"
    before = tomllib.loads(site.read_text())
    assert "gazebo" not in before
    set_moving_parts(site, "none")
    after = tomllib.loads(site.read_text())
    assert after.pop("gazebo") == {"moving_parts": "none"} and after == before
    set_moving_parts(site, "all")
    assert tomllib.loads(site.read_text())["gazebo"] == {"moving_parts": "all"}
    site.write_text(site.read_text().replace('moving_parts = "all"', ""))
    set_moving_parts(site, "none")
    assert tomllib.loads(site.read_text())["gazebo"] == {"moving_parts": "none"}
    from pipeline import config

    assert config.load_site(site).moving_parts == "none"


def test_the_dataset_section_compares_the_label_pass_before_and_after(tmp_path, monkeypatch):
    """The section's arithmetic on runs that write what run_dataset writes (no render):
    the labels_before run against local_1, per frame and per label pass, and the rows;
    the sun-in-view check's row from its counts."""
    import json as _json

    from pipeline.bench import dataset as section
    from pipeline.bench.context import Context
    from pipeline.bench.summary import _dataset_rows
    from pipeline.datasets import run as dataset_run

    calls = []

    def fake_run(config, out, *, executor, workers, tasks_per_worker, sources, labels_as_lights=False):
        calls.append(labels_as_lights)
        folder = out / "datasets" / "x"
        folder.mkdir(parents=True)
        (folder / "a.png").write_bytes(b"same")
        labels = 8.0 if labels_as_lights else 4.0
        (folder / "timings.json").write_text(_json.dumps({
            "frame_s": [20.0, 10.0 + labels, 10.0 + labels], "render_s": [10.0, 10.0, 10.0],
            "labels_s": [labels] * 3, "plan_s": 0.1, "scene_placements": 3}))
        return folder

    sun = {"planned": 400, "sun_in_view": 18, "rendered": 2, "annotations": 40, "problems": ["f: one"], "frames": []}
    monkeypatch.setattr(dataset_run, "run_dataset", fake_run)
    monkeypatch.setattr(section, "sun_in_view", lambda *args: sun)  # it renders: tests/datasets covers it
    built = tmp_path / "built"
    (built / "scene").mkdir(parents=True)
    (built / "models").mkdir()
    (built / "scene" / "placements.json").write_text("[]")
    sources = tmp_path / "sources"
    (sources / "datasets").mkdir(parents=True)
    (sources / "datasets" / "inspection_route.toml").write_text("count = 100\nwidth = 640\nheight = 480\n")
    work = tmp_path / "work"
    work.mkdir()
    ctx = Context(sources=sources, out=built, work=work, quick=True, shared={"built": built})
    d = section.dataset_section(ctx)
    assert calls.count(True) == 1 and len(calls) == len(section.RUNS)
    labels = d["labels"]
    assert labels["identical"] and labels["labels_after_to_before"] == 0.5
    assert labels["frame_after_to_before"] == pytest.approx(14.0 / 18.0)
    assert labels["label_share_before"] == pytest.approx(8.0 / 18.0) and labels["label_share_after"] == 4.0 / 14.0
    rows = {r["metric"]: r for r in _dataset_rows(d)}
    assert rows["s per label pass"]["ratio"] == 0.5 and "identical files" in rows["s per label pass"]["note"]
    sun_row = rows["annotations not their masks, sun in view"]
    assert sun_row["ours"] == 1 and sun_row["peer"] == 40 and "2 of 18 frames" in sun_row["note"]
