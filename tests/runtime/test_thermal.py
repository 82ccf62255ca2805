"""The steady-state conductor temperature (runtime.thermal, IEEE 738 style)."""

from __future__ import annotations

import pytest

from pipeline.runtime import thermal

DRAKE = dict(diameter_m=0.02814, r25_ohm_per_km=0.07284, r75_ohm_per_km=0.08689, emissivity=0.5, absorptivity=0.5)


def test_the_heat_balance_holds_at_the_solution():
    tc = thermal.temperature(900.0, 35.0, wind_m_s=0.61, irradiance_w_m2=1000.0, **DRAKE)
    r = (0.07284 + (0.08689 - 0.07284) / 50 * (tc - 25)) / 1000
    gain = 900.0 ** 2 * r + 0.5 * 1000.0 * 0.02814
    assert thermal.heat_loss(tc, 35.0, 0.02814, 0.61, 0.5) == pytest.approx(gain, rel=1e-9)


def test_no_current_no_sun_is_the_air_temperature():
    assert thermal.temperature(0.0, 25.0, **DRAKE) == pytest.approx(25.0, abs=1e-6)


def test_more_current_is_hotter_and_more_wind_cooler():
    temps = [thermal.temperature(i, 40.0, wind_m_s=0.61, irradiance_w_m2=1000.0, **DRAKE) for i in (0, 400, 800, 1200)]
    assert temps == sorted(temps) and temps[0] > 40.0  # the sun alone warms it
    assert thermal.temperature(1000, 40.0, wind_m_s=3.0, **DRAKE) < thermal.temperature(1000, 40.0, wind_m_s=0.3, **DRAKE)


def test_near_the_standards_worked_example():
    """IEEE 738's worked example rates Drake (40 C air, 0.61 m/s across, emissivity and
    absorptivity 0.5, full sun) about 1,000 A for 100 C: this model is within a few
    degrees of it."""
    assert 95.0 < thermal.temperature(1025.0, 40.0, wind_m_s=0.61, irradiance_w_m2=1000.0, **DRAKE) < 110.0


def test_runaway_is_an_error():
    with pytest.raises(ValueError, match="runaway"):
        thermal.temperature(1e6, 40.0, **DRAKE)
