"""The catenary of a span: closed forms to 0.1 mm and the hard cases, each by name."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.geometry import catenary as cat

TOL = 1e-4  # 0.1 mm


def level_sag(L, a):
    return a * (math.cosh(L / (2 * a)) - 1)


def brute_gap(c, n=200_001):
    """Vertical chord-to-curve gap sampled densely (independent of the closed form)."""
    x = np.linspace(0.0, c.L, n)
    z = a_cosh(c, x)
    return float(np.max(c.h * x / c.L - z))


def a_cosh(c, x):
    # the textbook form, written independently of the module's sinh products
    return c.a * (np.cosh((x - c.xm) / c.a) - np.cosh(-c.xm / c.a))


def test_level_span_sag_matches_closed_form():
    H, w, L = 20_000.0, 15.97, 60.0
    c = cat.from_tension([0, 0, 10], [L, 0, 10], H, w)
    assert abs(cat.sag(c) - level_sag(L, H / w)) < TOL
    assert abs(c.xm - L / 2) < 1e-9
    low = cat.lowest_point(c)
    assert abs(low[2] - (10 - level_sag(L, H / w))) < TOL and abs(low[0] - L / 2) < TOL
    # arc length closed form 2a sinh(L/2a)
    assert abs(cat.arc_length(c) - 2 * (H / w) * math.sinh(L / (2 * H / w))) < 1e-9


def test_span_in_any_horizontal_direction_is_the_same_curve():
    H, w, L = 8000.0, 12.0, 40.0
    d = np.array([math.cos(1.1), math.sin(1.1), 0.0])
    c = cat.from_tension([5, -3, 2], np.array([5, -3, 2]) + L * d, H, w)
    assert abs(cat.sag(c) - level_sag(L, H / w)) < TOL
    pts = cat.points(c, 64)
    # every vertex lies in the vertical plane of the span
    off = (pts[:, :2] - [5, -3]) @ np.array([-d[1], d[0]])
    assert np.max(np.abs(off)) < 1e-9


def test_inclined_span_ends_and_sag_against_dense_sampling():
    c = cat.from_tension([0, 0, 0], [50, 0, 12], 6000.0, 15.0)
    pts = cat.points(c, 100)
    assert np.allclose(pts[0], [0, 0, 0]) and np.allclose(pts[-1], [50, 0, 12])
    # the untruncated textbook formula reaches the far end to 0.1 mm
    assert abs(a_cosh(c, np.array([50.0]))[0] - 12) < TOL
    assert abs(cat.sag(c) - brute_gap(c)) < TOL


def test_steeply_inclined_span():
    # 30 m rise over 10 m: a gantry top down to a low pad
    c = cat.from_tension([0, 0, 30], [10, 0, 0], 500.0, 10.0)
    assert abs(a_cosh(c, np.array([10.0]))[0] + 30) < TOL
    assert abs(cat.sag(c) - brute_gap(c)) < TOL
    # from_sag recovers the same catenary
    back = cat.from_sag([0, 0, 30], [10, 0, 0], cat.sag(c))
    assert abs(back.a - c.a) / c.a < 1e-9


def test_very_taut_span_sag_over_span_1e4():
    L = 40.0
    c = cat.from_sag([0, 0, 15], [L, 0, 15], 1e-4 * L)
    assert abs(cat.sag(c) - 1e-4 * L) < 1e-9
    # parabola and catenary agree to far below 0.1 mm here: sag = L^2 / 8a
    assert abs(L * L / (8 * c.a) - 1e-4 * L) < TOL
    assert abs(level_sag(L, c.a) - 1e-4 * L) < 1e-9
    assert cat.chord_error(c, 1) == pytest.approx(1e-4 * L, abs=1e-9)


def test_slack_span_sag_over_span_0_2():
    L = 30.0
    c = cat.from_sag([0, 0, 12], [L, 0, 12], 0.2 * L)
    assert abs(level_sag(L, c.a) - 0.2 * L) < 1e-9
    assert abs(brute_gap(c) - 0.2 * L) < TOL
    # a parabola would be off by centimetres: the solver does not use it
    assert abs(L * L / (8 * c.a) - 0.2 * L) > 0.05


def test_near_vertical_dropper():
    # 1 mm of horizontal offset over 8 m of drop
    c = cat.from_tension([0, 0, 14], [0.001, 0, 6], 50.0, 15.0)
    pts = cat.points(c, 8)
    assert np.allclose(pts[[0, -1]], [[0, 0, 14], [0.001, 0, 6]])
    assert np.all(np.isfinite(pts))
    # a plumb-ish wire hangs within a fraction of a millimetre of its chord
    assert abs(cat.sag(c) - brute_gap(c)) < 1e-9 and cat.sag(c) < 1e-3
    assert abs(cat.arc_length(c) - math.hypot(0.001, 8)) < TOL
    d = cat.from_sag([0, 0, 14], [0.5, 0, 6], 0.3)
    assert abs(cat.sag(d) - 0.3) < 1e-9 and abs(brute_gap(d) - 0.3) < TOL


def test_plumb_dropper_is_the_chord():
    c = cat.from_tension([2, 3, 14], [2, 3, 6], 50.0, 15.0)
    assert c.straight and cat.sag(c) == 0.0 and cat.segments_for(c, 0.001) == 1
    assert np.allclose(cat.points(c, 2), [[2, 3, 14], [2, 3, 10], [2, 3, 6]])
    with pytest.raises(cat.CatenaryError, match="plumb"):
        cat.from_sag([2, 3, 14], [2, 3, 6], 0.2)


def test_coincident_terminals_are_refused():
    with pytest.raises(cat.CatenaryError, match="coincide"):
        cat.from_tension([1, 2, 3], [1, 2, 3], 1000.0, 10.0)
    with pytest.raises(cat.CatenaryError, match="coincide"):
        cat.from_sag([1, 2, 3], [1, 2, 3 + 1e-8], 0.1)


def test_very_short_span():
    c = cat.from_tension([0, 0, 5], [0.002, 0, 5.001], 1000.0, 15.0)
    pts = cat.points(c, 4)
    assert np.allclose(pts[-1], [0.002, 0, 5.001]) and np.all(np.isfinite(pts))
    assert abs(cat.sag(c) - brute_gap(c)) < 1e-12 and cat.sag(c) < 1e-7


def test_too_slack_for_its_tension_is_an_error_not_an_overflow():
    with pytest.raises(cat.CatenaryError, match="slack"):
        cat.from_tension([0, 0, 0], [500, 0, 0], 1.0, 15.0)


def test_chord_error_is_measured_and_meets_the_tolerance():
    c = cat.from_tension([0, 0, 20], [60, 0, 14], 9000.0, 15.0)
    for tol in (0.001, 0.01, 0.05):
        n = cat.segments_for(c, tol)
        err = cat.chord_error(c, n)
        assert err <= tol and cat.chord_error(c, n - 1) > tol
        # the measurement against a dense independent sampling of the true curve
        pts = cat.points(c, n)
        x = np.linspace(0, c.L, 20_001)
        curve = np.c_[x, np.zeros_like(x), 20 + a_cosh(c, x)]
        assert abs(_distance_to_polyline(curve, pts).max() - err) < 2e-5


def _distance_to_polyline(q, pts):
    """(k,) exact distances of points q: (k, 3) to the polyline pts: (n, 3)."""
    a, b = pts[:-1], pts[1:]
    ab = b - a
    t = np.clip(np.einsum("kij,ij->ki", q[:, None, :] - a[None], ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    foot = a[None] + t[..., None] * ab[None]
    return np.min(np.linalg.norm(q[:, None, :] - foot, axis=2), axis=1)


def test_change_of_state_round_trip_and_direction():
    p0, p1 = [0, 0, 15], [45, 0, 15]
    w, ea, alpha = 15.97, 6.0e7, 19.3e-6
    h_hot = cat.change_of_state(p0, p1, w, ea, alpha, 12_000.0, 15.0, 75.0)
    assert h_hot < 12_000.0  # hot conductor: longer, slacker, more sag
    back = cat.change_of_state(p0, p1, w, ea, alpha, h_hot, 75.0, 15.0)
    assert abs(back - 12_000.0) < 1e-6
    assert cat.change_of_state(p0, p1, w, ea, alpha, 12_000.0, 15.0, 15.0) == 12_000.0  # exactly


def test_change_of_state_matches_the_parabolic_state_equation():
    """Level taut span: the classic cubic (L^3 w^2 / 24)(1/H2^2 - 1/H1^2) = L (alpha dt
    + (H2 - H1)/EA), whose sag agrees with the catenary's to 0.1 mm here."""
    L, w, ea, alpha, h1, dt = 40.0, 15.97, 6.0e7, 19.3e-6, 30_000.0, 20.0
    h2 = cat.change_of_state([0, 0, 0], [L, 0, 0], w, ea, alpha, h1, 15.0, 15.0 + dt)
    roots = np.roots([1.0 / ea, (L * L * w * w) / (24 * h1 * h1) + alpha * dt - h1 / ea, 0.0, -(L * L * w * w) / 24])
    h2p = max(r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0)
    assert abs(level_sag(L, h2 / w) - L * L * w / (8 * h2p)) < TOL


def test_inextensible_cold_span_that_cannot_shorten_is_an_error():
    with pytest.raises(cat.CatenaryError, match="cannot shorten"):
        cat.change_of_state([0, 0, 0], [40, 0, 0], 15.0, math.inf, 19e-6, 1e6, 15.0, -500.0)


def test_segments_for_many_agrees_with_one_at_a_time():
    curves = [cat.from_tension([0, 0, 20], [60, 0, 14], 9000.0, 15.0),
              cat.from_sag([0, 0, 10], [30, 0, 10], 6.0),  # slack
              cat.from_sag([0, 0, 15], [40, 0, 15], 4e-3),  # taut
              cat.from_tension([0, 0, 14], [0.5, 0, 6], 50.0, 15.0),  # near-vertical
              cat.from_tension([2, 3, 14], [2, 3, 6], 50.0, 15.0)]  # plumb
    for tol in (0.001, 0.01, 0.05):
        n, err = cat.segments_for_many(curves, tol)
        assert n.tolist() == [cat.segments_for(c, tol) for c in curves]
        assert np.allclose(err, [cat.chord_error(c, k) for c, k in zip(curves, n)], rtol=1e-9, atol=1e-15)
