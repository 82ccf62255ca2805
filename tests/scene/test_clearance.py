"""Conductor clearances at maximum temperature (scene.clearance): one case per rule,
and the sample's table loads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline import wiring
from pipeline.geometry import catenary as cat
from pipeline.scene import clearance, conductors

from helpers import ROOT
RAIL = wiring.ConductorType("RAIL", 0.0296, 1.6, 3.26e7, 20.9e-6, 1, 0.0, 90.0)
TABLE = {500.0: clearance.Level(500.0, 3.1, 4.9, 5.4, 0.1)}


def span(a, b, tension=8000.0, kv=500.0, t=25.0, start=("A", "t"), end=("B", "t")):
    spec = wiring.SpanSpec(f"{start[0]}.{start[1]}~{end[0]}.{end[1]}", start, end, "RAIL", t, tension_n=tension,
                           voltage_kv=kv)
    return conductors.solve_span(spec, RAIL, np.array(a, float), np.array(b, float), t, (0.01,))


def flat(en):
    return np.zeros(len(en))


def test_a_span_that_sags_under_the_ground_clearance_when_hot():
    s = span([0, 0, 6.2], [40, 0, 6.2], tension=8000.0)
    cold_low = 6.2 - cat.sag(s.curve)
    hot_low = 6.2 - cat.sag(clearance.hot(s))
    assert cold_low > 5.4 > hot_low  # only the maximum temperature breaks the clearance
    found, counts = clearance.check([s], TABLE, flat)
    assert [f.code for f in found] == ["WIRE001"] and counts == {"spans_checked": 1, "spans_without_level": 0}
    assert f"{hot_low:.3f} m above the ground at 90 C" in found[0].message


def test_the_ground_under_the_span_is_what_counts():
    s = span([0, 0, 6.2], [40, 0, 6.2], tension=8000.0)
    assert clearance.check([s], TABLE, lambda en: np.full(len(en), -2.0))[0] == []


def test_phase_to_phase_between_nodes_only():
    a = span([0, 0, 12], [40, 0, 12], tension=20000.0, start=("G1", "p1"), end=("G2", "p1"))
    b = span([0, 4, 12], [40, 4, 12], tension=20000.0, start=("G1", "p2"), end=("G2", "p2"))
    found, _ = clearance.check([a, b], TABLE, flat)
    # G1's two terminals are one placement: one node, so no phase-to-phase finding
    assert found == []
    c = span([0, 4, 12], [40, 4, 12], tension=20000.0, start=("G3", "p2"), end=("G4", "p2"))
    found, _ = clearance.check([a, c], TABLE, flat)
    assert [f.code for f in found] == ["WIRE002"] and "4.000 m from conductor G3.p2~G4.p2" in found[0].message
    far = span([0, 6, 12], [40, 6, 12], tension=20000.0, start=("G3", "p2"), end=("G4", "p2"))
    assert clearance.check([a, far], TABLE, flat)[0] == []


def test_sag_beyond_the_limit():
    s = span([0, 0, 20], [10, 0, 20], tension=130.0)
    assert cat.sag(clearance.hot(s)) / 10 > 0.1
    assert "WIRE003" in [f.code for f in clearance.check([s], TABLE, flat)[0]]


def test_a_span_without_a_level_is_counted_not_checked():
    s = span([0, 0, 1], [40, 0, 1], kv=None)
    assert clearance.check([s], TABLE, flat) == ([], {"spans_checked": 0, "spans_without_level": 1})


def test_the_sample_table_loads():
    table = clearance.load_table(ROOT / "sources" / "clearances.toml")
    assert set(table) == {500.0, 230.0} and table[500.0].ground_m == pytest.approx(5.4)
