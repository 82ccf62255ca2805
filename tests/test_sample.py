"""The full sample substation, end to end (slow; CI runs it): build, validate with the
formats' own validators, run the oil-leak scenario, render frames and the study, on
the run's one sample build (conftest's sample_build)."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

from helpers import ROOT, SOURCES, twin
from pipeline.render import frames, sensor, study
from pipeline.perception import gauge
from pipeline.geometry import pinhole
from pipeline.runtime import site as render_site

STUDY = study.load_study(SOURCES / "study.toml")

pytestmark = [pytest.mark.slow, pytest.mark.blender]


@pytest.fixture(scope="session")
def sample(sample_build):
    return sample_build


def test_every_used_asset_has_a_package_within_budget(sample):
    placements = json.loads((sample / "scene" / "placements.json").read_text())
    used = {p["asset"] for p in placements["placements"]}
    assert len(placements["placements"]) == 853
    assert "wave_trap" not in used and not (sample / "models" / "wave_trap").exists()
    for asset in sorted(used):
        m = json.loads((sample / "models" / asset / "manifest.json").read_text())
        assert m["lods"][0]["triangles"] > 0
        assert all(lod["within_budget"] for lod in m["lods"]), (asset, m["lods"])
        for rel in m["outputs"]:
            assert (sample / "models" / asset / rel).is_file()


@pytest.mark.parametrize("fmt", ["sdf", "usda", "glb"])
def test_every_sample_pose_matches_independent_pyproj(sample, fmt):
    """All 853 placements, in each format, against the DXF through pyproj alone."""
    from poses import angle_diff, gltf_poses, independent_poses, sdf_poses, usd_poses

    truth = independent_poses(SOURCES)
    reader = {"sdf": sdf_poses, "usda": usd_poses, "glb": gltf_poses}[fmt]
    got = reader(sample / "scene" / f"sample_substation.{fmt}")
    got.pop("terrain", None)
    assert set(got) == set(truth) and len(truth) == 853
    metres = max(np.linalg.norm(got[tag][0] - p) for tag, (p, _) in truth.items())
    degrees = max(angle_diff(got[tag][1], yaw) for tag, (_, yaw) in truth.items())
    assert metres < 1e-3 and degrees < 1e-3, (metres, degrees)


def test_validation_report_has_no_errors(sample):
    proc = twin("validate", "--sources", SOURCES, "--out", sample, timeout=3600)
    report = json.loads((sample / "reports" / "validation.json").read_text())
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    assert report["summary"]["errors"] == 0
    # 500 kV live parts stand on supports tall enough: no span under its 5.4 m at 90 C
    assert "WIRE001" not in report["summary"]["by_code"], report["summary"]["by_code"]
    assert (sample / "reports" / "validation.html").is_file()
    assert (sample / "reports" / "junit.xml").is_file()
    # Gazebo's own loaders read every mesh and the world (tools/gzprobe): no GZ finding
    # at all, the world within its parse budget, dartsim able to build every shape
    assert not [c for c in report["summary"]["by_code"] if c.startswith("GZ")], report["summary"]["by_code"]
    assert report["scene"]["gazebo"]["models"] < 100 and report["scene"]["gazebo"]["visuals"] > 0
    figures = json.loads((sample / "reports" / "timings.json").read_text())["gazebo"]
    assert figures["world"]["peak_rss_mb"] < 1536 and figures["physics"]["failed_shapes"] == 0


def test_oil_leak_scenario_runs_on_the_sample(sample):
    proc = twin("run", SOURCES / "scenarios" / "oil_leak.toml", "--out", sample, timeout=3600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert re.search(r"running\s.*\s4/4\s", proc.stderr), proc.stderr  # simulation and appliers, on stderr
    assert json.loads(proc.stdout)["steps"] >= 60  # stdout: the summary alone
    run = sample / "runs" / "oil_leak"
    lines = (run / "states.jsonl").read_text().splitlines()
    assert len(lines) >= 60
    assert (run / "states.usda").is_file()


# --- render-in-the-loop on the built sample ---------------------------------------

TINY = sensor.PhoneCamera(width=64, height=48, samples=4)
SMALL = sensor.PhoneCamera(width=128, height=96, samples=4)  # the history test's frame: it showed the bug


def test_frames_labels_and_determinism(sample, tmp_path):
    site = render_site.load_site(sample, SOURCES)
    shots = dict(study.study_shots(site, STUDY))
    night, noon = shots["midnight"], shots["early_morning"]  # the white dial in direct sun
    a = frames.render_shots(site, [noon], tmp_path / "a", cam=TINY, seed=7)[0]
    b = frames.render_shots(site, [noon], tmp_path / "b", cam=TINY, seed=7)[0]
    assert a["sha256"] == b["sha256"] and np.array_equal(a["rgb"], b["rgb"])
    labels = json.loads((tmp_path / "a" / "frame_0000.json").read_text())
    g = labels["gauges"]["gauge_tank"]
    x0, y0, x1, y1 = g["box"]
    assert g["inside_frame"] and x0 < g["centre"][0] < x1 and y0 < g["centre"][1] < y1
    assert labels["camera"]["fx"] == pytest.approx(32.0 / math.tan(1.047 / 45 / 2))
    # The box lands on the dial: it holds the image's brightest (white dial) pixels.
    gray = a["rgb"].mean(axis=2)
    ys, xs = np.nonzero(gray >= np.percentile(gray, 90))
    inside = (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
    assert inside.mean() > 0.6
    dark = frames.render_shots(site, [night], tmp_path / "n", cam=TINY, seed=7)[0]
    assert float((dark["rgb"].mean(axis=2) > 240).mean()) == 0.0


def test_denoised_frame_is_the_same_in_a_fresh_process(sample, tmp_path):
    """OIDN on the CPU: a frame rendered in another process has the same pixels."""
    site = render_site.load_site(sample, SOURCES)
    noon = dict(study.study_shots(site, STUDY))["solar_noon"]
    assert TINY.render_denoise
    here = frames.render_shots(site, [noon], tmp_path / "here", cam=TINY, seed=3)[0]["sha256"]
    script = ("import json, sys; from pathlib import Path; from pipeline.render import frames, sensor, study; "
              "from pipeline.runtime import site as s; sources = Path(sys.argv[4]); "
              "site = s.load_site(Path(sys.argv[1]), sources); "
              "shot = dict(study.study_shots(site, study.load_study(sources / 'study.toml')))['solar_noon']; "
              "cam = sensor.PhoneCamera(**json.loads(sys.argv[3])); "
              "print('SHA', frames.render_shots(site, [shot], Path(sys.argv[2]), cam=cam, seed=3)[0]['sha256'])")
    proc = subprocess.run([sys.executable, "-c", script, str(sample), str(tmp_path / "there"),
                           json.dumps(dataclasses.asdict(TINY)), str(SOURCES)],
                          capture_output=True, text=True, timeout=600)
    there = next(x.split()[1] for x in proc.stdout.splitlines() if x.startswith("SHA "))
    assert here == there


def test_a_frame_does_not_depend_on_the_frames_before_it(sample, tmp_path):
    """Night (lamps on, sun off), then noon: the noon frame equals noon rendered alone."""
    site = render_site.load_site(sample, SOURCES)
    shots = dict(study.study_shots(site, STUDY))
    alone = frames.render_shots(site, [shots["solar_noon"]], tmp_path / "a", cam=SMALL, seed=5, gain=1.0)
    after = frames.render_shots(site, [shots["midnight"], shots["solar_noon"], shots["midnight"]], tmp_path / "b",
                           cam=SMALL, seed=5, gain=1.0)
    assert after[1]["sha256"] == alone[0]["sha256"]
    first = frames.render_shots(site, [shots["midnight"]], tmp_path / "c", cam=SMALL, seed=5, gain=1.0)
    assert after[2]["sha256"] == after[0]["sha256"] == first[0]["sha256"]


def test_study_table(sample, tmp_path):
    import shutil

    shutil.copytree(sample / "scene", tmp_path / "scene")
    (tmp_path / "models").symlink_to((sample / "models").resolve())
    study.render_study(tmp_path, SOURCES, cam=sensor.PhoneCamera())  # the study's own frame: H needs its pixels
    report = json.loads((tmp_path / "reports" / "study.json").read_text())
    names = [c["condition"] for c in report["conditions"]]
    # A day's order from the first light in which the pointer is visible (H_ref).
    assert names == ["early_morning", "solar_noon", "late_afternoon", "early_night", "midnight", "late_night"]
    assert report["target"] == "RE-B3"
    for c in report["conditions"]:
        assert 0.0 <= c["S"] <= 1.0 and c["C"] >= 0.0
        assert (tmp_path / "reports" / c["image"]).is_file()
    by = {c["condition"]: c for c in report["conditions"]}
    assert by["early_morning"]["H"] == 1.0 and by["early_morning"]["H_true"] == 1.0
    assert by["midnight"]["S"] == 0.0 and by["late_night"]["S"] == 0.0
    assert by["solar_noon"]["S"] < 0.2
    for night in ("midnight", "late_night"):  # lamps light the dial: H follows the true level
        assert by[night]["H"] == pytest.approx(by[night]["H_true"], abs=0.2)
    # Late afternoon: the sun faces the lens ~10 deg off the axis of a 1.3 deg field. A
    # lens spreads it as a veil over the whole crop, a little stronger on the sun's side:
    # contrast falls, but the crop does not turn white (that needs the sun in or at the
    # edge of the field). A veil above ~0.08 of full scale lifts the dark pointer over the
    # study's threshold (V <= 80): then the pointer is lost in the glare, H = 0.
    late = by["late_afternoon"]
    assert late["sun_off_axis_deg"] > 5.0 and late["veil"] > 0.0
    assert late["S"] < 0.5 and late["C"] < by["early_morning"]["C"]
    assert late["H"] == 0.0 or late["veil"] * late["exposure_gain"] < 0.08
    # Each condition set against the shape of the study's Table 1.
    for c in report["conditions"]:
        assert [t["metric"] for t in c["table1"]] == ["C", "S", "H"]
        assert all(isinstance(t["match"], bool) and t["study"] for t in c["table1"])
    assert report["table1_matches"] == sum(t["match"] for c in report["conditions"] for t in c["table1"])
    html = (tmp_path / "reports" / "study.html").read_text()
    assert "late_afternoon" in html and "Table 1" in html


def test_the_late_sun_lights_the_study_crop_from_its_side(sample):
    """The lens's glare on the study's own geometry: the late sun (outside the frame)
    lights the frame's corner towards it more than the far one, and the glare alone
    reaches the clip nowhere at the exposure a metered frame of the gauge gets."""
    site = render_site.load_site(sample, SOURCES)
    late = dict(study.study_shots(site, STUDY))["late_afternoon"]
    cam = sensor.PhoneCamera()
    k = pinhole.intrinsics(late.lens.hfov, cam.width, cam.height)
    u, v = pinhole.project(late.cam_pose[:3, 3][None, :] + late.sun_dir[None, :], late.cam_pose, k)[0]
    assert not (0 <= u < cam.width and 0 <= v < cam.height)
    glare = sensor.sun_glare(late.sun_dir, late.dni, late.cam_pose, k, cam)
    corners = {(0, 0): glare[0, 0], (cam.width, 0): glare[0, -1], (0, cam.height): glare[-1, 0],
               (cam.width, cam.height): glare[-1, -1]}
    nearest = min(corners, key=lambda c: math.hypot(c[0] - u, c[1] - v))
    farthest = max(corners, key=lambda c: math.hypot(c[0] - u, c[1] - v))
    assert corners[nearest] > 1.1 * corners[farthest] > 0.0
    assert glare.max() * 0.05 < 1.0  # a gain of 0.05: the metered late-afternoon close-up's order


def test_study_viewpoint_faces_the_late_sun_with_a_clear_view(sample):
    """Bank B's gauges face ENE: the study camera looks WSW, the late sun within ~25 deg
    of its axis and not hidden by a built model."""
    site = render_site.load_site(sample, SOURCES)
    shots = dict(study.study_shots(site, STUDY))
    late = shots["late_afternoon"]
    axis = -late.cam_pose[:3, 2]
    assert math.degrees(math.acos(float(axis @ late.sun_dir))) < 25.0
    assert not study._blocked(site, late.cam_pose[:3, 3], late.sun_dir, 300.0)
    cfg = STUDY
    normal = gauge.placed_dial(site, cfg.target).axis
    assert float(-axis @ normal) > math.cos(cfg.max_obliquity) - 1e-9


def test_twin_render_counts_frames_and_keeps_blenders_log_in_a_file(sample, tmp_path):
    """`twin render` renders in its own process: Blender's log goes to OUT/logs/, the
    terminal gets a bar of the frames, and the temp folder keeps nothing."""
    import os
    import re

    out = tmp_path / "build"
    out.mkdir()
    for sub in ("models", "scene"):
        (out / sub).symlink_to(sample / sub)
    scenario = tmp_path / "short.toml"
    text = (ROOT / "sources" / "scenarios" / "oil_leak.toml").read_text()
    scenario.write_text(text.replace("duration_s = 60.0", "duration_s = 1.0"))
    temp = tmp_path / "tmp"
    temp.mkdir()
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "render", str(scenario), "--out", str(out)],
                          capture_output=True, text=True, cwd=ROOT, timeout=3600, env={**os.environ, "TMPDIR": str(temp)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = out / "logs" / "render_short.log"
    assert "Blender create Mesh node" in log.read_text()
    assert "Blender create" not in proc.stdout + proc.stderr and "INFO" not in proc.stdout + proc.stderr
    m = re.search(r"frames\s.*?(\d+)/(\d+)", proc.stderr)
    assert m and m.group(1) == m.group(2), proc.stderr
    rendered = sorted((out / "runs" / "oil_leak" / "render").glob("frame_*.png"))
    assert len(rendered) == int(m.group(2)) >= 1
    assert sorted(p.name for p in temp.rglob("*")) == []
