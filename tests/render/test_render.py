"""Renderer: camera geometry and the phone camera model without Blender. Frames,
labels, determinism and the study table need the built sample: tests/test_sample.py."""

import math
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOT, SOURCES
from pipeline.perception import gauge
from pipeline.geometry import pinhole
from pipeline.render import sensor, study
from pipeline.bench import render as bench_render


def test_projection_matches_intrinsics():
    k = pinhole.intrinsics(1.047 / 45, 320, 240)
    pose = pinhole.look_at((0.0, -25.0, 1.6), (0.0, 0.0, 1.6))
    # The target projects on the principal point; a point at the FOV's edge on the border.
    uv = pinhole.project(np.array([[0.0, 0.0, 1.6], [25.0 * math.tan(k["hfov"] / 2), 0.0, 1.6]]), pose, k)
    assert np.allclose(uv[0], (160.0, 120.0))
    assert np.allclose(uv[1], (320.0, 120.0))
    assert np.isnan(pinhole.project(np.array([[0.0, -30.0, 1.6]]), pose, k)).all()  # behind


def test_gauge_box_surrounds_dial_centre():
    # the reactor's pointer binding, as its manifest records it (float32 rest pose)
    rest = [1.0, 0.0, 0.0, 0.0, 0.0, -4.4e-08, -1.0, -1.8, 0.0, 1.0, -4.4e-08, 2.8, 0.0, 0.0, 0.0, 1.0]
    manifest = {"bindings": [{"target": gauge.POINTER, "effect": "rotate", "link": "base", "axis": [0.0, 0.0, 1.0],
                              "domain": [0.0, 100.0], "range": [-2.356, 2.356], "rest_pose": rest}],
                "links": [{"name": "base", "pose": np.eye(4).reshape(16).tolist()}]}
    dial = gauge.dial_of(np.eye(4), manifest)
    np.testing.assert_allclose(dial.centre, (0.0, -1.8, 2.8))
    np.testing.assert_allclose(dial.axis, (0.0, -1.0, 0.0), atol=1e-7)  # the face looks out along -Y
    pose = pinhole.look_at(dial.centre + (0.0, -25.0, 0.0), dial.centre)
    k = pinhole.intrinsics(1.047 / 45, 320, 240)
    g = dial.box(pose, k)
    x0, y0, x1, y1 = g["box"]
    assert g["inside_frame"] and x0 < 160 < x1 and y0 < 120 < y1
    assert x1 - x0 == pytest.approx(2 * gauge.DIAL_RADIUS * k["fx"] / 25.0, rel=0.01)
    assert gauge.dial_of(np.eye(4), {"bindings": []}) is None


def test_a_frames_gauge_label_is_its_targets_own_dial():
    """The frame labels box the dial the target's binding places (a transformer's dial
    is not where a reactor's is) and give the pointer angle through the binding's own
    mapping (ir.StateBinding.output)."""
    import datetime as dt

    from pipeline.render.frames import frame_labels
    from pipeline.runtime.camera import lens
    from pipeline.runtime.nodes import state_binding
    from pipeline.runtime.site import BuiltSite, Shot

    # the power transformer's pointer binding, as its manifest records it
    rest = [1.0, 0.0, 0.0, 2.0, 0.0, -4.4e-08, -1.0, -3.05, 0.0, 1.0, -4.4e-08, 3.0, 0.0, 0.0, 0.0, 1.0]
    binding = {"target": gauge.POINTER, "effect": "rotate", "link": "base", "axis": [0.0, 0.0, 1.0],
               "variable": "oil_level_tank", "domain": [0.0, 100.0], "range": [-2.356, 2.356], "rest_pose": rest}
    manifest = {"bindings": [binding], "links": [{"name": "base", "pose": np.eye(4).reshape(16).tolist()}]}
    site = BuiltSite(Path("."), [{"tag": "T1", "asset": "power_transformer", "enu": [40.0, 10.0, 0.5], "yaw_rad": 0.7}],
                     {"power_transformer": manifest}, (0.0, 0.0, 0.0), "2025-03-20")
    dial = gauge.placed_dial(site, "T1")
    np.testing.assert_allclose(dial.centre, (site.pose(site.placement("T1")) @ np.array([2.0, -3.05, 3.0, 1.0]))[:3])
    pose = pinhole.look_at(dial.centre + 6.0 * dial.axis, dial.centre)
    shot = Shot(dt.datetime(2025, 3, 20, 12, tzinfo=dt.timezone.utc), pose, lens(20.0), 0.8, 1.0, 500.0,
                {"T1": {"oil_level_tank": 37.0}}, [], "T1")
    k = pinhole.intrinsics(shot.lens.hfov, 320, 240)
    labels = frame_labels(shot, k, site, 1.0, 0.0, dial)
    box = labels["gauges"]["gauge_tank"]
    x0, y0, x1, y1 = box["box"]
    assert box["visible"] and x0 < 160 < x1 and y0 < 120 < y1  # the camera looks at the dial's centre
    assert labels["pointer_angle_rad"] == state_binding(binding).output(37.0)
    assert frame_labels(shot, k, site, 1.0, 0.0, None)["gauges"]["gauge_tank"] == {"box": None, "visible": False}


def test_exposure_clamps_at_night_and_sensor_saturates():
    dark = np.full((8, 8, 3), 1e-4, np.float32)
    assert sensor.metered_gain(dark, sensor.PhoneCamera()) == sensor.PhoneCamera().gain_max
    assert (sensor.develop(dark, sensor.PhoneCamera().gain_max, 0.0) < 30).all()  # night stays dark
    assert (sensor.develop(np.ones((8, 8, 3)), 2.0, 0.0) == 255).all()


def test_white_balance_neutralises_a_tint_and_keeps_luminance():
    tinted = np.ones((16, 16, 3), np.float32) * np.array([0.5, 0.7, 1.0], np.float32)
    wb = sensor.metered_white_balance(tinted, sensor.PhoneCamera())
    out = tinted[0, 0] * wb
    assert out[0] == pytest.approx(out[1], rel=1e-6) == pytest.approx(out[2], rel=1e-6)
    assert sensor.luminance(wb[None, :])[0] == pytest.approx(1.0)


def test_isp_noise_reduction_removes_salt_and_pepper():
    rng = np.random.default_rng(1)
    flat = np.full((48, 64, 3), 0.2, np.float32)
    flat[rng.random((48, 64)) < 0.05] = 0.0  # dead samples of a 16-spp path tracer
    raw = sensor.develop(flat, 1.0, 0.0, cam=sensor.PhoneCamera(denoise=0.0))
    clean = sensor.develop(flat, 1.0, 0.0, cam=sensor.PhoneCamera())
    # lone specks and pairs go; the few clusters of three or more at this density stay,
    # as a wire's corner would
    assert (raw < 80).mean() > 0.03 and (clean < 80).mean() < 0.1 * (raw < 80).mean()


def test_isp_noise_reduction_keeps_a_wire_one_pixel_wide():
    """A dark conductor one pixel wide across a noisy sky keeps most of its contrast
    through the ISP (a plain 3x3 median erased it), and a lone speck beside it goes."""
    sky = np.full((48, 64, 3), 0.25, np.float32)
    rows = np.clip(np.round(10 + 0.4 * np.arange(64)), 0, 47).astype(int)  # a sloping line, 8-connected
    sky[rows, np.arange(64)] = 0.04
    sky[40, 10] = 0.9  # a firefly
    cam = sensor.PhoneCamera()
    raw = sensor.develop(sky, 1.0, 0.0, cam=sensor.PhoneCamera(denoise=0.0), seed=3).astype(float).mean(axis=2)
    out = sensor.develop(sky, 1.0, 0.0, cam=cam, seed=3).astype(float).mean(axis=2)
    background = np.median(out)
    contrast = (background - out[rows, np.arange(64)]) / (np.median(raw) - raw[rows, np.arange(64)])
    assert np.median(contrast) > 0.6 and contrast.min() > 0.3
    assert abs(out[40, 10] - background) < 10 < raw[40, 10] - np.median(raw)


def test_ray_box_and_blocking():
    pose = np.eye(4)
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 2.0])
    assert study._ray_hits_box(np.array([-5.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), 10.0, pose, lo, hi)
    assert not study._ray_hits_box(np.array([-5.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), 3.0, pose, lo, hi)
    assert not study._ray_hits_box(np.array([-5.0, 0.0, 3.0]), np.array([1.0, 0.0, 0.0]), 10.0, pose, lo, hi)


WIDE = pinhole.intrinsics(1.047, 320, 240)  # 1x: the sun's disc is ~1.4 px across
TELE = pinhole.intrinsics(1.047 / 45, 320, 240)  # the study's 45x close-up
FORWARD = pinhole.look_at((0.0, 0.0, 1.6), (0.0, 50.0, 1.6))  # looks north, level


def sun_through(k, u, v, pose=FORWARD):
    """The ENU direction whose ray passes through pixel position (u, v)."""
    ray = np.array([(u - k["cx"]) / k["fx"], -(v - k["cy"]) / k["fy"], -1.0])
    return pose[:3, :3] @ (ray / np.linalg.norm(ray))


def test_halo_holds_the_glare_fraction_and_falls_as_a_power_law():
    cam = sensor.PhoneCamera()
    theta = np.geomspace(1e-8, math.pi / 2, 400001)
    f = 2 * math.pi * np.sin(theta) * sensor.halo_psf(theta, cam)
    assert float(np.sum((f[1:] + f[:-1]) * np.diff(theta)) / 2) == pytest.approx(cam.glare_fraction, rel=1e-3)
    p = sensor.halo_psf(np.array([0.1, 0.2]), cam)
    assert p[0] / p[1] == pytest.approx(2 ** cam.glare_slope, rel=0.01)  # theta^-g beyond the shoulder


def test_a_sun_in_the_frame_saturates_a_disc_around_it_not_the_frame():
    cam = sensor.PhoneCamera(denoise=0.0)
    scene = np.full((240, 320, 3), 8.0)  # W/m2/sr: a sunlit yard
    gain = 0.4 / 8.0  # metered on the scene without the sun: the sun does not move it
    veil = sensor.lens_glare(scene, gain, np.ones(3), FORWARD, WIDE, sun_through(WIDE, 80.5, 60.5), 800.0, cam)
    rgb = sensor.develop(scene, gain, veil, None, cam)
    yy, xx = np.mgrid[0:240, 0:320]
    near = np.hypot(xx + 0.5 - 80.5, yy + 0.5 - 60.5) < 10.0
    assert (rgb[near] == 255).all()  # the disc and its halo's core saturate
    far = rgb[200:, 280:]  # the far corner: lifted a little, far from the clip
    assert far.max() < 200 and far.min() >= sensor.develop(scene[:1, :1], gain, 0.0, None, cam).min()
    assert (rgb == 255).all(axis=-1).mean() < 0.1
    # The halo falls off across the frame: brighter at 40 px than at 120 px from the sun.
    assert veil[60, 120, 0] > 3 * veil[60, 200, 0] > 0
    # At 45x the disc is resolved: its radiance is the core's share of DNI / 6.8e-5 sr.
    disc = sensor.sun_glare(sun_through(TELE, 160.0, 120.0), 800.0, FORWARD, TELE, cam)
    expected = (1 - cam.glare_fraction) * 800.0 / sensor.SUN_SOLID_ANGLE
    assert disc[120, 160] == pytest.approx(expected, rel=0.05) and disc[0, 0] < expected / 100


@pytest.mark.parametrize("a_shape, b_shape, mode", [((72, 96, 3), (143, 191, 1), "same"),
                                                     ((480, 640, 3), (959, 1279, 1), "same"),
                                                     ((83, 109), (11, 11), "valid"), ((97, 131), (29, 29), "valid")])
def test_the_glares_convolution_is_scipys_fftconvolve_bit_for_bit(a_shape, b_shape, mode):
    """The frame's and the sun's halo (fft_convolve) are what scipy.signal.fftconvolve
    gives for them, to the last bit: a frame's pixels do not change with the import."""
    from scipy.signal import fftconvolve

    rng = np.random.default_rng(len(a_shape) + a_shape[0])
    a, b = rng.random(a_shape) * 3.0, rng.random(b_shape) ** 4
    axes = {"axes": (0, 1)} if len(a_shape) == 3 else {}
    assert np.array_equal(sensor.fft_convolve(a, b, mode), fftconvolve(a, b, mode=mode, **axes))


def test_a_sun_behind_the_camera_set_or_occluded_adds_nothing():
    cam = sensor.PhoneCamera()
    behind = -sun_through(WIDE, 160.0, 120.0)
    assert not sensor.sun_glare(behind, 800.0, FORWARD, WIDE, cam).any()
    beside = np.array([1.0, -0.01, 0.0]) / math.hypot(1.0, 0.01)  # just behind the lens plane
    assert not sensor.sun_glare(beside, 800.0, FORWARD, WIDE, cam).any()
    in_view = sun_through(WIDE, 160.0, 120.0)
    assert sensor.sun_glare(in_view, 800.0, FORWARD, WIDE, cam).max() > 1e3
    assert not sensor.sun_glare(in_view, 0.0, FORWARD, WIDE, cam).any()  # occluded or set: the caller's dni 0


@pytest.mark.parametrize("k, beyond_px", [(WIDE, 30.0), (TELE, 300.0), (TELE, 2300.0)])
def test_a_sun_just_outside_the_frame_lights_the_near_edge_more(k, beyond_px):
    cam = sensor.PhoneCamera()
    g = sensor.sun_glare(sun_through(k, 320.0 + beyond_px, 120.0), 350.0, FORWARD, k, cam)
    near, far = g[:, -1].mean(), g[:, 0].mean()
    assert near > 1.05 * far > 0.0
    assert np.all(np.diff(g[120]) > 0)  # rising towards the sun along the row through it


def test_sensor_noise_is_seeded_and_grows_with_the_signal():
    cam = sensor.PhoneCamera(denoise=0.0)
    flat = np.full((200, 200, 3), 1.0)
    a, b = (sensor.sensor_noise(flat * 0.4, 1.0, cam, seed) for seed in (7, 7))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, sensor.sensor_noise(flat * 0.4, 1.0, cam, 8))
    full_scale = cam.full_well_e * cam.burst_frames  # base ISO: a daylight gain
    for level in (0.05, 0.4):
        var = float(np.var(sensor.sensor_noise(flat * level, 0.01, cam, 3) - level))
        expected = (level * full_scale + cam.read_noise_e**2 * cam.burst_frames) / full_scale**2
        assert var == pytest.approx(expected, rel=0.03)  # Poisson: variance proportional to the electrons
    night = float(np.var(sensor.sensor_noise(flat * 0.05, cam.gain_max, cam, 3) - 0.05))
    assert night > 30 * float(np.var(sensor.sensor_noise(flat * 0.05, 0.01, cam, 3) - 0.05))  # analog gain
    # Through develop: the seed decides the picture; no seed, no noise.
    scene = np.full((48, 64, 3), 0.2)
    assert np.array_equal(sensor.develop(scene, 1.0, 0.0, None, cam, seed=1),
                          sensor.develop(scene, 1.0, 0.0, None, cam, seed=1))
    assert not np.array_equal(sensor.develop(scene, 1.0, 0.0, None, cam, seed=1),
                              sensor.develop(scene, 1.0, 0.0, None, cam, seed=2))
    assert len(np.unique(sensor.develop(scene, 1.0, 0.0, None, cam))) == 1


DEVELOP_SCRIPT = """
import hashlib, sys
import numpy as np
from pipeline.geometry import pinhole
from pipeline.render import sensor
k = pinhole.intrinsics(1.047 / 45, 320, 240)
pose = pinhole.look_at((0.0, 0.0, 1.6), (0.0, 50.0, 1.6))
scene = np.random.default_rng(5).random((240, 320, 3)) * 16.0
scene[100:104, 50:54] = 5e4  # a glint above the clip: the scene's own halo
sun = pose[:3, :3] @ np.array([0.05, 0.03, -1.0]) / np.linalg.norm([0.05, 0.03, -1.0])
veil = sensor.lens_glare(scene, 0.05, np.array([1.1, 1.0, 0.9]), pose, k, sun, 350.0, sensor.PhoneCamera())
rgb = sensor.develop(scene, 0.05, veil, np.array([1.1, 1.0, 0.9]), sensor.PhoneCamera(), seed=11)
print(hashlib.sha256(veil.tobytes() + rgb.tobytes()).hexdigest())
"""


def test_develop_is_the_same_bytes_in_another_process():
    """Glare (FFT convolutions), noise and the ISP: a function of the inputs and seed."""
    import subprocess
    import sys

    here = {}
    exec(compile(DEVELOP_SCRIPT.replace("print(", "here['sha'] = ("), "develop", "exec"), {"here": here})
    there = subprocess.run([sys.executable, "-c", DEVELOP_SCRIPT], capture_output=True, text=True, timeout=120,
                           cwd=ROOT)
    assert there.returncode == 0, there.stderr[-2000:]
    assert there.stdout.strip() == here["sha"]


STUDY_TOML = (SOURCES / "study.toml").read_text()


@pytest.mark.parametrize("old, new, key", [
    ('zoom = 45.0', 'zoom = "far"', "zoom"),
    ('zoom = 45.0', 'zoom = 450.0', "zoom"),
    ('target = "RE-B3"', '', "target"),
    ('time = "17:05"', 'time = "5 pm"', "conditions[2].time"),
    ('name = "midnight"', 'name = "solar_noon"', "conditions[4].name"),
    ('faces_sun_of = "late_afternoon"', 'faces_sun_of = "dusk"', "faces_sun_of"),
    ('seed = 20250920', 'seed = 20250920\nsede = 1', "sede"),
    ('seed = 20250920', 'seed = -1', "seed"),
    ('zoom = 45.0', 'zoom = 45.0 45', None),  # TOML syntax
])
def test_a_bad_study_toml_is_one_error_naming_the_file_and_key(tmp_path, old, new, key):
    from pipeline.errors import UserError

    assert old in STUDY_TOML
    path = tmp_path / "study.toml"
    path.write_text(STUDY_TOML.replace(old, new, 1))
    with pytest.raises(UserError) as e:
        study.load_study(path)
    text = str(e.value)
    assert "\n" not in text and text.startswith(str(path))
    assert key is None or f"{path}: {key}:" in text
    assert study.load_study(SOURCES / "study.toml").target == "RE-B3"


def test_pointer_angle_follows_binding():
    b = {"domain": [0.0, 100.0], "range": [-2.356, 2.356]}
    assert gauge.pointer_angle(50.0, b) == pytest.approx(0.0)
    assert gauge.pointer_angle(0.0, b) == pytest.approx(-2.356)
    assert gauge.pointer_angle(120.0, b) == pytest.approx(2.356)


def test_cull_keeps_what_is_seen_and_shadowing():
    pose = pinhole.look_at((0.0, -25.0, 1.6), (0.0, 0.0, 1.6))
    k = pinhole.intrinsics(0.2, 64, 48)
    items = [{"tag": "seen", "centre": (0.0, 0.0, 1.6), "radius": 1.0},
             {"tag": "aside", "centre": (40.0, 0.0, 1.6), "radius": 1.0},
             {"tag": "shadower", "centre": (0.0, 0.0, 11.6), "radius": 1.0}]
    assert [i["tag"] for i in pinhole.cull(items, pose, k, 0.1, 100.0, None)] == ["seen"]
    sun = np.array([0.0, 0.0, 1.0])
    assert {i["tag"] for i in pinhole.cull(items, pose, k, 0.1, 100.0, sun)} == {"seen", "shadower"}


def test_frame_error_is_the_rms_level_difference_after_the_references_exposure():
    ref = np.full((24, 32, 3), 0.05, np.float32)
    cam = sensor.PhoneCamera()
    assert bench_render.frame_error(ref, ref, cam) == 0.0
    gain = sensor.metered_gain(ref, cam)  # 0.40 / 0.05: the reference develops to 0.40 linear
    levels = lambda x: np.round(sensor.srgb_encode(np.float64(gain * x)) * 255.0)  # noqa: E731
    expected = abs(levels(0.05) - levels(0.025))
    assert bench_render.frame_error(ref * 0.5, ref, cam) == pytest.approx(expected) and expected > 30


def test_the_clipped_mask_is_the_exposed_radiance_at_full_scale_before_noise():
    from pipeline.render.sensor import PhoneCamera, clipped, develop

    linear = np.full((4, 6, 3), 0.2)
    linear[1, 2] = [0.2, 0.2, 1.5]  # one channel over full scale at gain 1
    linear[3, 5] = 0.99
    veil = np.zeros((4, 6))
    veil[3, 5] = 0.02  # the lens's veil pushes this one over
    mask = clipped(linear, 1.0, veil)
    assert mask.dtype == bool and mask.shape == (4, 6)
    assert sorted(zip(*np.nonzero(mask))) == [(1, 2), (3, 5)]
    assert not clipped(linear, 0.5, veil).any()  # a shorter exposure clips nothing
    assert clipped(linear, 1.0, veil, wb=np.array([1.0, 1.0, 0.5]))[1, 2] == False  # noqa: E712 - the blue gain
    # the 8-bit picture of the same frame saturates there too (noise aside)
    rgb = develop(linear, 1.0, veil, None, PhoneCamera(denoise=0))
    assert (rgb[mask] == 255).any(axis=-1).all()


def test_vignetting_darkens_the_corners_and_leaves_the_centre():
    from pipeline.render.appearance import vignette

    flat = np.ones((48, 64, 3), np.float32)
    out = vignette(flat, 0.3)
    assert out.dtype == np.float32 and out[24, 32, 0] > 0.999 and abs(out[0, 0, 0] - 0.7) < 0.02
    assert vignette(flat, 0.0) is flat
