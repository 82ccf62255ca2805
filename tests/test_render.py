"""Renderer: camera geometry and the phone camera model without Blender. Frames,
labels, determinism and the study table need the built sample: test_sample.py."""

import math

import numpy as np
import pytest

from pipeline.runtime.render import gauge, pinhole, sensor, study
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
    model = np.eye(4)
    centre = gauge.DIAL_CENTER
    pose = pinhole.look_at(centre + (0.0, -25.0, 0.0), centre)
    k = pinhole.intrinsics(1.047 / 45, 320, 240)
    g = gauge.gauge_box(model, pose, k)
    x0, y0, x1, y1 = g["box"]
    assert g["inside_frame"] and x0 < 160 < x1 and y0 < 120 < y1
    assert x1 - x0 == pytest.approx(2 * gauge.DIAL_RADIUS * k["fx"] / 25.0, rel=0.01)


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
    assert (raw < 80).mean() > 0.03 and (clean < 80).mean() < 0.002


def test_ray_box_and_blocking():
    pose = np.eye(4)
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 2.0])
    assert study._ray_hits_box(np.array([-5.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), 10.0, pose, lo, hi)
    assert not study._ray_hits_box(np.array([-5.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), 3.0, pose, lo, hi)
    assert not study._ray_hits_box(np.array([-5.0, 0.0, 3.0]), np.array([1.0, 0.0, 0.0]), 10.0, pose, lo, hi)


def test_veil_needs_the_sun_in_front_and_visible():
    axis = np.array([0.0, 1.0, 0.0])
    cam = sensor.PhoneCamera()
    assert sensor.veil_radiance(axis, axis, 800.0, True, cam) == pytest.approx(cam.veil_k * 800.0)
    assert sensor.veil_radiance(-axis, axis, 800.0, True, cam) == 0.0
    assert sensor.veil_radiance(axis, axis, 800.0, False, cam) == 0.0


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
