"""`twin baseline`: the study's gauge reader on drawn dials (known angles, glare, night,
too small), the report's bins and plots, and one run on a dataset rendered from the
sample build."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from helpers import SOURCES, twin
from pipeline.perception import gauge_reader as bl
from pipeline.perception.baseline import BINS, bin_of, write_report
from pipeline.perception.gauge import DIAL_RADIUS, FACE_RADIUS, POINTER, dial_of, pointer_angle
from pipeline.geometry.pinhole import intrinsics, look_at, project


# the reactor's main-tank pointer binding as its manifest records it
REST = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, -1.78], [0.0, 1.0, 0.0, 2.8], [0.0, 0.0, 0.0, 1.0]])
BINDING = {"target": POINTER, "effect": "rotate", "link": "base", "axis": [0.0, 0.0, 1.0], "domain": [0.0, 100.0],
           "range": [-2.356, 2.356], "rest_pose": REST.reshape(16).tolist()}
MANIFEST = {"bindings": [BINDING], "links": [{"name": "base", "pose": np.eye(4).reshape(16).tolist()}]}
WIDTH, HEIGHT = 200, 150


def _view(px_across: float, oblique_deg: float = 0.0, dist: float = 5.0):
    """A dial at a yawed placement and a camera `dist` from it, turned `oblique_deg`
    from its normal, zoomed so the face spans about `px_across` pixels."""
    place = np.eye(4)
    place[:2, :2] = [[math.cos(0.4), -math.sin(0.4)], [math.sin(0.4), math.cos(0.4)]]
    place[:3, 3] = (30.0, 180.0, 12.0)
    dial = dial_of(place, MANIFEST)
    a = math.radians(oblique_deg)
    side = np.cross(dial.axis, (0.0, 0.0, 1.0))
    pose = look_at(dial.centre + dist * (math.cos(a) * dial.axis + math.sin(a) * side), dial.centre)
    hfov = 2.0 * math.atan(FACE_RADIUS * WIDTH / px_across / dist)
    return dial, pose, hfov


def _draw(level: float, px_across: float, oblique_deg: float = 0.0, supersample: int = 4, pointer: float = 25.0):
    """(image, dial, pose, k): the dial drawn by casting each subpixel's ray onto its
    plane: grey housing, bezel, white face with a red low sector, a tapered
    pointer of grey `pointer` at the binding's angle of `level`, averaged down like a
    sensor's pixels."""
    dial, pose, hfov = _view(px_across, oblique_deg)
    s = supersample
    fine = intrinsics(hfov, WIDTH * s, HEIGHT * s)
    plane = bl.dial_plane_coordinates(dial, pose, fine, (0, 0, WIDTH * s, HEIGHT * s))
    left, up = plane[..., 0], plane[..., 1]
    r = np.hypot(left, up)
    t = pointer_angle(level, BINDING)
    along = left * math.sin(t) + up * math.cos(t)
    across = np.abs(left * math.cos(t) - up * math.sin(t))
    tip = 0.85 * FACE_RADIUS
    half = 0.012 + (0.002 - 0.012) * (along + 0.03) / (tip + 0.03)
    img = np.full(r.shape + (3,), 110.0)
    img[r <= DIAL_RADIUS] = 150.0
    img[r <= FACE_RADIUS] = 235.0
    angle = np.arctan2(left, up)
    img[(r > 0.55 * FACE_RADIUS) & (r < 0.95 * FACE_RADIUS) & (angle > -2.356) & (angle < -2.356 + 4.712 / 4)] = (40, 40, 200)
    img[(along >= -0.03) & (along <= tip) & (across <= half)] = pointer
    img = img.reshape(HEIGHT, s, WIDTH, s, 3).mean(axis=(1, 3))
    return np.round(img).astype(np.uint8), dial, pose, intrinsics(hfov, WIDTH, HEIGHT)


@pytest.mark.parametrize("px_across, oblique_deg", [(40, 0.0), (60, 35.0), (120, 50.0)])
def test_a_drawn_dial_reads_back_its_level(px_across, oblique_deg):
    for level in (3.0, 24.0, 47.5, 66.0, 81.0, 99.0):
        img, dial, pose, k = _draw(level, px_across, oblique_deg)
        row = bl.score_gauge(img, dial, pose, k, level)
        assert row["status"] == bl.SCORED
        # a black pointer on a white face is dark by either threshold, but at 40 px its
        # thin outer half mixes with the face into greys above the study's V <= 80
        for reader in bl.READERS if px_across >= 60 else ("relative",):
            assert row[reader]["status"] == "read", (level, reader, row)
            assert abs(row[reader]["error"]) < 1.5, (level, reader, row)
        assert 0.6 < row["H"] <= 1.05, row  # the pointer's thin tip fades into the face at low resolution
        assert row["S"] == 0.0 and row["C"] > 0.1


def test_a_grey_pointer_is_lost_by_the_fixed_threshold_only():
    """An auto-exposed frame develops the black pointer to a mid grey: the study's
    V <= 80 finds nothing, the face-relative threshold still reads it."""
    img, dial, pose, k = _draw(62.0, 80, pointer=110.0)
    row = bl.score_gauge(img, dial, pose, k, 62.0)
    assert row["study"]["status"] == "no_pointer" and row["study"]["read"] is None
    assert abs(row["relative"]["error"]) < 1.5 and row["H"] == 0.0


def test_level_of_angle_inverts_the_binding():
    for level in np.linspace(0.0, 100.0, 21):
        assert bl.level_of_angle(pointer_angle(level, BINDING), BINDING) == pytest.approx(level, abs=1e-9)
    # a pointer past the stops reads as the nearest end of the scale, not a wrapped value
    assert bl.level_of_angle(math.pi - 0.1, BINDING) == 100.0
    assert bl.level_of_angle(-math.pi + 0.1, BINDING) == 0.0


def test_plane_coordinates_are_the_inverse_of_the_projection():
    dial, pose, hfov = _view(80, 40.0)
    k = intrinsics(hfov, WIDTH, HEIGHT)
    box = (80, 50, 120, 100)
    plane = bl.dial_plane_coordinates(dial, pose, k, box)
    world = dial.centre + plane[..., :1] * dial.left + plane[..., 1:] * dial.up
    uv = project(world.reshape(-1, 3), pose, k).reshape(plane.shape)
    cols, rows = np.meshgrid(np.arange(box[0], box[2]) + 0.5, np.arange(box[1], box[3]) + 0.5)
    assert np.allclose(uv[..., 0], cols) and np.allclose(uv[..., 1], rows)


def test_glare_and_night_are_unreadable_not_a_wrong_number():
    _, dial, pose, k = _draw(50.0, 60)
    white = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    row = bl.score_gauge(white, dial, pose, k, 50.0)
    for reader in bl.READERS:
        assert row[reader] == {"status": "no_pointer", "angle_rad": None, "read": None, "error": None}
    assert row["S"] == 1.0 and row["H"] == 0.0
    dark = np.full((HEIGHT, WIDTH, 3), 12, np.uint8)
    row = bl.score_gauge(dark, dial, pose, k, 50.0)
    assert all(row[reader]["status"] == "dark_face" for reader in bl.READERS)
    # dark blotches that run along no ray from the pivot: a shadow, not a pointer
    img, dial, pose, k = _draw(50.0, 60, supersample=1)
    img[:] = np.where(img == 25, 235, img).astype(np.uint8)  # the pointer erased
    u, v = project(dial.centre[None, :] + 0.09 * dial.left + 0.02 * dial.up, pose, k)[0]
    img[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2] = 10
    row = bl.score_gauge(img, dial, pose, k, 50.0)
    assert all(row[reader]["status"] == "no_line" and row[reader]["read"] is None for reader in bl.READERS)


def test_a_dial_too_small_or_cut_is_counted_not_scored():
    img, dial, pose, k = _draw(50.0, 12)
    assert bl.score_gauge(img, dial, pose, k, 50.0)["status"] == "too_small"
    img, dial, pose, k = _draw(50.0, 60)
    k_off = {**k, "cx": k["cx"] + 95.0}  # the dial's centre near the left edge
    assert bl.score_gauge(img, dial, pose, k_off, 50.0)["status"] == "cut"


def _row(frame: int, elevation: float, hours: float, status: str, error: float | None, h: float | None) -> dict:
    """A scored row whose readers both give `status` and `error`, or a not-scored one."""
    row = {"frame_id": f"{frame:06d}", "image": f"images/{frame:06d}.png", "tag": "RE-A1", "camera": "cam",
           "zoom": 4.0, "local_time": "2025-03-20T12:00:00-03:00", "local_hours": hours,
           "sun_elevation_deg": elevation, "sun_azimuth_deg": 0.0, "irradiance": 0.0, "true": 50.0, "dial_px": 50.0}
    if status in bl.NOT_SCORED:
        return {**row, "status": status}
    reading = {"status": status, "angle_rad": None, "read": None if error is None else 50.0 + error, "error": error}
    return {**row, "status": bl.SCORED, "roi": [4, 2, 20, 18], "H": h, "C": 0.2, "S": 0.0,
            **{n: dict(reading) for n in bl.READERS}}


def test_report_bins_counts_and_same_bytes(tmp_path):
    assert [bin_of(e) for e in (-12.0, 0.0, 0.5, 10.0, 29.0, 30.5, 80.0)] == [
        BINS[0][0], BINS[0][0], BINS[1][0], BINS[1][0], BINS[2][0], BINS[3][0], BINS[3][0]]
    rows = [_row(0, -5.0, 21.0, "dark_face", None, 3.0), _row(1, -5.0, 21.5, "read", -4.0, 1.2),
            _row(2, 5.0, 7.0, "read", 2.0, 0.9), _row(3, 20.0, 9.0, "too_small", None, None),
            _row(4, 45.0, 12.0, "read", 1.0, 1.0), _row(5, 45.0, 12.5, "no_pointer", None, 0.0)]
    folder = tmp_path / "build" / "datasets" / "toy"
    (folder / "images").mkdir(parents=True)
    for r in rows:
        ok, buf = cv2.imencode(".png", np.full((24, 32, 3), 40 * int(r["frame_id"]), np.uint8))
        (folder / r["image"]).write_bytes(buf.tobytes())
    first = write_report(tmp_path / "a", "toy", folder, rows)
    report = json.loads(first.with_suffix(".json").read_text())
    by_bin = {b["bin"]: b for b in report["bins"]}
    night, high, every = by_bin[BINS[0][0]], by_bin[BINS[3][0]], by_bin["all"]
    for reader in bl.READERS:
        n, h, a = night["readers"][reader], high["readers"][reader], every["readers"][reader]
        assert (night["scored"], n["read"], n["share_read"], n["mae"]) == (2, 1, 0.5, 4.0)
        assert n["unreadable"]["dark_face"] == 1
        assert (h["read"], h["mae"], h["unreadable"]["no_pointer"]) == (1, 1.0, 1)
        assert (every["seen"], every["scored"], a["read"]) == (6, 5, 3)
        assert a["mae"] == pytest.approx(7.0 / 3.0)
    assert night["mae_H"] == pytest.approx(1.1)
    assert by_bin[BINS[2][0]]["too_small"] == 1 and by_bin[BINS[2][0]]["scored"] == 0
    html = first.read_text()
    assert "baseline_toy_sun.png" in html and "baseline_toy_time.png" in html
    shown = [x["file"] for xs in report["examples"].values() for x in xs]
    assert len(shown) == 5 and all(f"src=\"{f}\"" in html for f in shown)  # every scored row, in its bin
    second = write_report(tmp_path / "b", "toy", folder, rows)
    for name in ("baseline_toy.json", "baseline_toy_sun.png", "baseline_toy_time.png", shown[0]):
        a, b = (first.parent / name).read_bytes(), (second.parent / name).read_bytes()
        assert a == b, name
    assert (first.parent / "baseline_toy_sun.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_command_names_a_folder_that_is_no_dataset(tmp_path):
    from click.testing import CliRunner

    from pipeline.cli import main

    result = CliRunner().invoke(main, ["baseline", str(tmp_path / "nowhere")])
    assert result.exit_code == 1 and result.output.startswith("error:")


# --- on a rendered dataset -----------------------------------------------------------------

CLOSE = """
[dataset]
name = "close"
seed = 5
count = 3
[sensor]
width = 240
height = 180
samples = 2
[conditions]
dates = ["2025-03-20"]
local_time = ["10:00", "14:00"]
[states]
oil_level = [20.0, 100.0]
[[cameras]]
kind = "inspection_point"
points = ["RE-A1_gauges", "RE-B1_gauges"]
zoom = [5.0, 7.0]
"""


@pytest.fixture(scope="module")
def close_dataset(sample_build, tmp_path_factory) -> Path:
    """Three close-ups of reactor dials at midday, rendered beside the session's sample
    build (its models and scene linked, not copied)."""
    from pipeline.datasets.run import run_dataset

    out = tmp_path_factory.mktemp("baseline") / "build"
    out.mkdir()
    for sub in ("models", "scene"):
        (out / sub).symlink_to(sample_build / sub)
    config = out.parent / "close.toml"
    config.write_text(CLOSE)
    return run_dataset(config, out, sources=SOURCES)


def test_the_baseline_reads_a_rendered_dataset(close_dataset, tmp_path):
    proc = twin("baseline", close_dataset, "--out", tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert re.search(r"frames\s.*\s3/3\s", proc.stderr), proc.stderr  # its progress, on stderr
    report = json.loads((tmp_path / "reports" / "baseline_close.json").read_text())
    gauges = report["gauges"]
    frames = [json.loads(line) for line in (close_dataset / "frames.jsonl").read_text().splitlines()]
    assert len(gauges) == sum(g["visible"] for f in frames for g in f["gauges"]) >= 3
    read = [g["relative"] for g in gauges if g["status"] == "scored" and g["relative"]["status"] == "read"]
    assert len(read) >= 2, gauges
    assert all(abs(g["error"]) < 3.0 for g in read), read
    assert report["bins"][-1]["readers"]["relative"]["read"] == len(read)
    for png in report["plots"].values():
        assert (tmp_path / "reports" / png).is_file()


def test_the_readers_angle_is_scored_against_the_keypoints_in_the_picture():
    """A dataset's keypoints (datasets.labels.gauge_keypoints) against a reader's angle:
    0 when they agree, the turn between them otherwise, signed; None without keypoints."""
    from pipeline.datasets import labels
    from pipeline.perception import baseline as pb
    from pipeline.geometry.pinhole import intrinsics

    axis, up = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    dial = bl.Dial(np.zeros(3), axis, up, np.cross(axis, up), {"variable": "level", "range": [-2.0, 2.0]})
    pose = np.eye(4)
    pose[2, 3] = 0.6
    k = intrinsics(np.radians(40.0), 64, 48)
    ids, depth = np.full((48, 64), 3, np.uint16), np.full((48, 64), 0.6, np.float32)
    kp = labels.gauge_keypoints(dial, 0.3, pose, k, ids, depth, 3)
    assert pb.keypoint_angle_error(dial, 0.3, kp, pose, k) == pytest.approx(0.0, abs=1e-9)
    # facing the camera, the picture shows the dial's turn as it is (the sign: the image's v runs down)
    assert abs(pb.keypoint_angle_error(dial, 0.3 + math.radians(10.0), kp, pose, k)) == pytest.approx(10.0, abs=1e-6)
    assert pb.keypoint_angle_error(dial, None, kp, pose, k) is None
    assert pb.keypoint_angle_error(dial, 0.3, None, pose, k) is None
    scored = [{"status": bl.SCORED, **{n: {"status": "read", "error": 1.0, "angle_error_deg": e} for n in bl.READERS}}
              for e in (2.0, -4.0, None)]
    assert pb.reader_summary(scored, "study")["angle_mae_deg"] == pytest.approx(3.0)
