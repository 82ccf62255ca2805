"""The catenary of a conductor strung between two terminals, pure numpy (+ scipy roots).

A span hangs in the vertical plane through its two ends p0, p1 (ENU, metres). In that
plane x is the horizontal distance from p0 (0..L) and z the height above p0; the curve
is z(x) = a (cosh((x - xm) / a) - cosh(xm / a)) with a = H / w (the catenary constant:
horizontal tension H in N over weight per metre w in N/m) and xm the abscissa of the
lowest point of the whole curve (often outside the span on an inclined one).

Numbers. Differences of cosh are written as products of sinh (cosh A - cosh B =
2 sinh((A+B)/2) sinh((A-B)/2)), so a taut span (a of 10^5 m) loses nothing to
cancellation; every quantity is float64 relative to p0.

Sag is the largest vertical distance between the chord and the curve (the usual
definition on inclined spans; on a level span it is the mid-span sag
a (cosh(L / 2a) - 1)). The chord error of a polyline whose vertices lie on the
curve is the largest Euclidean distance from a polyline segment to the arc it spans:
on a convex arc it is reached where the tangent is parallel to the segment, so it is
measured in closed form, not sampled. Vertices evenly spaced in x give segments of
equal chord error (to leading order dx^2 / 8a: the slope and the curvature cancel),
which is why `points` spaces them that way.

A span whose horizontal length is below `VERTICAL_TOL` times its chord (a plumb
dropper), or whose catenary constant is infinite (w = 0), is the straight chord.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

G = 9.80665  # standard gravity, m/s^2: mass per metre -> weight per metre
VERTICAL_TOL = 1e-9  # horizontal / chord length below which a span is a plumb line
MIN_CHORD = 1e-6  # m: two terminals closer than this are one point
T_BASE = 20.0  # deg C at which conductor tables give lengths (linear expansion from it)
MAX_ARG = 600.0  # largest |(x - xm) / a| allowed: cosh(700) overflows float64


class CatenaryError(ValueError):
    """A span that has no catenary: coincident ends, or too slack to represent."""


@dataclass(frozen=True)
class Catenary:
    """A solved span. p0, p1: (3,) float64 ENU ends; direction: (2,) unit horizontal
    from p0 towards p1 (x axis of the span plane; (1, 0) for a plumb line); L the
    horizontal and h the vertical distance p0 -> p1; a = H / w (inf: straight);
    xm the lowest point's abscissa."""

    p0: np.ndarray
    p1: np.ndarray
    direction: np.ndarray
    L: float
    h: float
    a: float
    xm: float

    @property
    def straight(self) -> bool:
        return not math.isfinite(self.a)


def _frame(p0, p1) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    p0 = np.asarray(p0, dtype=np.float64).reshape(3)
    p1 = np.asarray(p1, dtype=np.float64).reshape(3)
    d = p1 - p0
    if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
        raise CatenaryError("a terminal position is not finite")
    chord = float(np.linalg.norm(d))
    if chord < MIN_CHORD:
        raise CatenaryError(f"the two ends coincide (chord {chord:.3g} m)")
    L = float(math.hypot(d[0], d[1]))
    direction = d[:2] / L if L > VERTICAL_TOL * chord else np.array([1.0, 0.0])
    return p0, p1, direction, L, float(d[2])


def _plumb(p0, p1, direction, L, h) -> Catenary:
    return Catenary(p0, p1, direction, L, h, math.inf, 0.0)


def _lowest(L: float, h: float, a: float) -> float:
    """xm for a span (L, h) of catenary constant a (closed form)."""
    half = L / (2.0 * a)
    if half > MAX_ARG / 2:
        raise CatenaryError(f"span too slack for its tension: L / a = {L / a:.3g}")
    xm = L / 2.0 - a * math.asinh(h / (2.0 * a * math.sinh(half)))
    if max(abs(xm), abs(L - xm)) / a > MAX_ARG:
        raise CatenaryError(f"span too slack for its tension: |x - xm| / a beyond {MAX_ARG:g}")
    return xm


def from_tension(p0, p1, H: float, w: float) -> Catenary:
    """The span between `p0`, `p1`: (3,) under horizontal tension `H` (N, > 0) with
    weight `w` (N/m, >= 0; 0 gives the straight chord)."""
    p0, p1, direction, L, h = _frame(p0, p1)
    if not (H > 0 and math.isfinite(H)) or not (w >= 0 and math.isfinite(w)):
        raise CatenaryError(f"tension {H!r} N and weight {w!r} N/m must be positive and finite")
    chord = math.hypot(L, h)
    if w == 0 or L <= VERTICAL_TOL * chord:
        return _plumb(p0, p1, direction, L, h)
    a = H / w
    return Catenary(p0, p1, direction, L, h, a, _lowest(L, h, a))


def _rise(a: float, xm: float, x0, x1):
    """z(x1) - z(x0) without cancellation: 2a sinh((x0 + x1 - 2xm) / 2a) sinh((x1 - x0) / 2a)."""
    return 2.0 * a * np.sinh((x0 + x1 - 2.0 * xm) / (2.0 * a)) * np.sinh((x1 - x0) / (2.0 * a))


def _vertical_gap(a: float, xm: float, x0, x1):
    """Largest vertical distance chord - curve over [x0, x1]: (k,) arrays or floats."""
    x0, x1 = np.asarray(x0, dtype=np.float64), np.asarray(x1, dtype=np.float64)
    dx = x1 - x0
    m = _rise(a, xm, x0, x1) / np.where(dx > 0, dx, 1.0)
    xs = xm + a * np.arcsinh(m)  # where the tangent is parallel to the chord
    return np.where(dx > 0, m * (xs - x0) - _rise(a, xm, x0, xs), 0.0)


def _chord_distance(a: float, xm: float, x0, x1):
    """Largest Euclidean distance segment - arc over [x0, x1] (closed form: the
    vertical gap at the parallel tangent times the cosine of the chord's slope)."""
    x0, x1 = np.asarray(x0, dtype=np.float64), np.asarray(x1, dtype=np.float64)
    dx = x1 - x0
    dz = _rise(a, xm, x0, x1)
    cos = np.divide(dx, np.hypot(dx, dz), out=np.ones_like(dx), where=dx > 0)
    return _vertical_gap(a, xm, x0, x1) * cos


def _span_gap(a: float, xm: float, L: float, h: float) -> float:
    """_vertical_gap over the whole span [0, L], in scalar math (root searches call it
    often: numpy's overhead on one value would dominate)."""
    m = h / L
    xs = xm + a * math.asinh(m)
    return m * xs - 2.0 * a * math.sinh((xs - 2.0 * xm) / (2.0 * a)) * math.sinh(xs / (2.0 * a))


def sag(c: Catenary) -> float:
    """Largest vertical chord-to-curve distance of the span, m (0 for a straight one)."""
    return 0.0 if c.straight else float(_vertical_gap(c.a, c.xm, 0.0, c.L))


def height(c: Catenary, x) -> np.ndarray:
    """z above p0 at horizontal distances `x`: (k,) -> (k,) float64."""
    x = np.asarray(x, dtype=np.float64)
    if c.straight:
        return c.h * (x / c.L) if c.L > 0 else np.zeros_like(x)
    return _rise(c.a, c.xm, 0.0, x)


def lowest_point(c: Catenary) -> np.ndarray:
    """(3,) ENU of the span's lowest point (an end when the vertex is outside it)."""
    x = 0.0 if c.straight else min(max(c.xm, 0.0), c.L)
    if c.straight:
        return (c.p0 if c.h >= 0 else c.p1).copy()
    return _at(c, np.array([x]))[0]


def _length_and_integral(a: float, xm: float, L: float) -> tuple[float, float]:
    """Arc length and the integral of cosh(u) ds / 1 (times H: of the tension) of a
    catenary of constant a between x = 0 and L, scalars."""
    u0, u1 = -xm / a, (L - xm) / a
    # sinh u1 - sinh u0 = 2 cosh((u0+u1)/2) sinh((u1-u0)/2): no cancellation
    length = 2.0 * a * math.cosh((u0 + u1) / 2.0) * math.sinh((u1 - u0) / 2.0)
    # a [u/2 + sinh(2u)/4] between u0 and u1, the sinh difference as a product
    integral = a * ((u1 - u0) / 2.0 + 0.5 * math.cosh(u0 + u1) * math.sinh(u1 - u0))
    return length, integral


def arc_length(c: Catenary) -> float:
    """Length of conductor between the ends, m."""
    if c.straight:
        return math.hypot(c.L, c.h)
    return _length_and_integral(c.a, c.xm, c.L)[0]


def tension_integral(c: Catenary, H: float) -> float:
    """Integral of the tension T = H cosh(u) along the conductor, N m: the elastic
    elongation is this over EA."""
    if c.straight:
        return H * math.hypot(c.L, c.h)
    return H * _length_and_integral(c.a, c.xm, c.L)[1]


def from_sag(p0, p1, target: float) -> Catenary:
    """The span between `p0`, `p1`: (3,) whose sag (vertical, see `sag`) is `target`
    m (> 0). The catenary constant a is found by a bracketed root search on log a
    (sag falls monotonically as a grows); H = a w for any weight."""
    p0, p1, direction, L, h = _frame(p0, p1)
    chord = math.hypot(L, h)
    if not (target > 0 and math.isfinite(target)):
        raise CatenaryError(f"sag {target!r} m must be positive and finite")
    if L <= VERTICAL_TOL * chord:
        raise CatenaryError("a plumb span has no sag: give its tension instead")

    def excess(log_a: float) -> float:
        a = math.exp(log_a)
        return _span_gap(a, _lowest(L, h, a), L, h) - target

    guess = math.log(L * chord / (8.0 * target))  # parabola: sag = L chord / 8a
    lo, hi = _bracket(excess, guess - 0.5, guess + 0.5, 1.0, f"sag {target:g} m is beyond any catenary of this span")
    # imported here: scipy.optimize is slow to import, and not every process that
    # imports this module solves a span
    from scipy.optimize import brentq

    log_a = brentq(excess, lo, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=200)
    a = math.exp(log_a)
    return Catenary(p0, p1, direction, L, h, a, _lowest(L, h, a))


def _at(c: Catenary, x: np.ndarray) -> np.ndarray:
    """(k, 3) ENU points at horizontal distances x: (k,)."""
    if c.straight:
        t = np.linspace(0.0, 1.0, len(x)) if c.L == 0 else x / c.L
        return c.p0 + t[:, None] * (c.p1 - c.p0)
    out = np.empty((len(x), 3))
    out[:, 0] = c.p0[0] + x * c.direction[0]
    out[:, 1] = c.p0[1] + x * c.direction[1]
    out[:, 2] = c.p0[2] + height(c, x)
    return out


def points(c: Catenary, segments: int) -> np.ndarray:
    """(segments + 1, 3) float64 ENU polyline vertices on the curve, evenly spaced
    in x (equal chord error per segment), ends exactly p0 and p1."""
    n = max(int(segments), 1)
    if c.straight:
        return c.p0 + np.linspace(0.0, 1.0, n + 1)[:, None] * (c.p1 - c.p0)
    out = _at(c, np.linspace(0.0, c.L, n + 1))
    out[0], out[-1] = c.p0, c.p1  # the ends are exact: no rounding gap at a terminal
    return out


def chord_error(c: Catenary, segments: int) -> float:
    """Measured largest distance (m) between the `points(c, segments)` polyline and
    the true curve (exact per segment, see the module note)."""
    if c.straight:
        return 0.0
    x = np.linspace(0.0, c.L, max(int(segments), 1) + 1)
    return float(np.max(_chord_distance(c.a, c.xm, x[:-1], x[1:])))


def segments_for(c: Catenary, tolerance: float, cap: int = 4096) -> int:
    """Fewest segments whose measured chord error is within `tolerance` m (at most
    `cap`): the leading-order estimate L / sqrt(8 a tol), then corrected by
    measurement (it is exact to a few per cent; steep ends can need one more)."""
    if c.straight:
        return 1
    n = min(max(1, math.ceil(c.L / math.sqrt(8.0 * c.a * tolerance))), cap)
    while n > 1 and chord_error(c, n - 1) <= tolerance:
        n -= 1
    while n < cap and chord_error(c, n) > tolerance:
        n += 1
    return n


def segments_for_many(curves: list[Catenary], tolerance: float, cap: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """`segments_for` and the measured chord error of many curves at once: (k,) int
    segment counts and (k,) float64 errors. Every candidate count of every curve is
    measured in one vectorised pass over all their segments (a few passes in all)."""
    k = len(curves)
    n = np.ones(k, dtype=np.int64)
    err = np.zeros(k)
    live = np.array([not c.straight for c in curves], dtype=bool)
    if not live.any():
        return n, err
    idx = np.nonzero(live)[0]
    a = np.array([curves[i].a for i in idx])
    xm = np.array([curves[i].xm for i in idx])
    L = np.array([curves[i].L for i in idx])
    guess = np.clip(np.ceil(L / np.sqrt(8.0 * a * tolerance)), 1, cap).astype(np.int64)

    def measure(counts):
        owner = np.repeat(np.arange(len(counts)), counts)
        start = np.cumsum(counts) - counts
        j = np.arange(int(counts.sum())) - np.repeat(start, counts)
        dx = np.repeat(L / counts, counts)
        x0, x1 = j * dx, (j + 1) * dx
        d = _chord_distance_v(np.repeat(a, counts), np.repeat(xm, counts), x0, x1)
        return np.maximum.reduceat(d, start) if len(d) else np.zeros(0), owner

    e, _ = measure(guess)
    # fewer while the one below still meets the tolerance, more while this one fails
    for _ in range(64):
        below = np.maximum(guess - 1, 1)
        eb, _ = measure(below)
        step_down = (guess > 1) & (eb <= tolerance)
        step_up = (e > tolerance) & (guess < cap)
        if not (step_down.any() or step_up.any()):
            break
        guess = np.where(step_down, below, np.where(step_up, guess + 1, guess))
        e = np.where(step_down, eb, e)
        if step_up.any():
            e, _ = measure(guess)
    n[idx], err[idx] = guess, e
    return n, err


def _chord_distance_v(a, xm, x0, x1):
    """_chord_distance with a per-segment catenary constant and vertex, (m,) arrays."""
    dx = x1 - x0
    rise = 2.0 * a * np.sinh((x0 + x1 - 2.0 * xm) / (2.0 * a)) * np.sinh(dx / (2.0 * a))
    m = rise / dx
    xs = xm + a * np.arcsinh(m)
    gap = m * (xs - x0) - 2.0 * a * np.sinh((x0 + xs - 2.0 * xm) / (2.0 * a)) * np.sinh((xs - x0) / (2.0 * a))
    return gap * dx / np.hypot(dx, rise)


def change_of_state(p0, p1, w: float, ea: float, alpha: float, h_ref: float, t_ref: float, t: float) -> float:
    """Horizontal tension (N) at conductor temperature `t` (deg C) of the span whose
    tension is `h_ref` N at `t_ref`: the conductor's unstressed length at a fixed
    temperature is invariant. The length stretched by tension is S = S0 (1 + alpha
    (t - t_ref)) + (integral of T ds) / EA (small strain), with S and the integral
    exact on the catenary; solved for H by a bracketed root search (S - integral/EA
    falls monotonically with H). `ea` in N (inf: inextensible), `alpha` in 1/K. At
    the reference temperature the reference tension is the answer, exactly (a root
    search would return it to within its tolerance, at the cost of the search)."""
    if t == t_ref:
        return float(h_ref)
    ref = from_tension(p0, p1, h_ref, w)
    if ref.straight:
        return h_ref  # a plumb or weightless span carries no sag to trade for tension
    elastic = 0.0 if math.isinf(ea) else 1.0 / ea
    unstressed = arc_length(ref) - tension_integral(ref, h_ref) * elastic
    # lengths grow linearly from the tables' 20 deg C: the ratio makes t -> t' -> t exact
    target = unstressed * (1.0 + alpha * (t - T_BASE)) / (1.0 + alpha * (t_ref - T_BASE))

    L, h = ref.L, ref.h

    def excess(log_h: float) -> float:
        H = math.exp(log_h)
        a = H / w
        length, integral = _length_and_integral(a, _lowest(L, h, a), L)
        return length - H * integral * elastic - target

    lo, hi = _bracket(excess, math.log(h_ref) - 0.25, math.log(h_ref) + 0.25, 0.5,
                      f"the span goes slack beyond representation at {t:g} deg C",
                      ceiling=(math.log(h_ref) + 60,
                               f"the conductor cannot shorten enough at {t:g} deg C (inextensible and taut)"))
    from scipy.optimize import brentq

    return math.exp(brentq(excess, lo, hi, xtol=1e-14, rtol=4 * np.finfo(float).eps, maxiter=200))


def _bracket(excess, lo: float, hi: float, step: float, too_low: str,
             ceiling: tuple[float, str] | None = None) -> tuple[float, float]:
    """Widen [lo, hi] by `step` until excess(lo) > 0 > excess(hi), for brentq. A
    CatenaryError on the low side is re-raised as `too_low`; past `ceiling`'s bound the
    high side raises its message."""
    for _ in range(200):
        try:
            if excess(lo) > 0:
                break
        except CatenaryError:
            raise CatenaryError(too_low) from None
        lo -= step
    for _ in range(200):
        if excess(hi) < 0:
            break
        if ceiling is not None and hi > ceiling[0]:
            raise CatenaryError(ceiling[1])
        hi += step
    return lo, hi
