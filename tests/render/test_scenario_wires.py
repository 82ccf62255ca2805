"""`twin render SCENARIO`: each shot carries the conductor temperature the scenario's
graph gives the render node (render.conductors.temperature), which the Cycles scene
strings its spans at (test_conductors_cycles)."""

from __future__ import annotations

from helpers import SOURCES
from wire_scenario import rising_load, thermal_wire

LOAD = rising_load(10.0, 300.0) + thermal_wire("load.y")


def test_a_scenarios_shots_carry_its_conductor_temperature(sample_build, tmp_path):
    from pipeline.render.scenario import scenario_shots
    from pipeline.runtime import run
    from pipeline.runtime.graph import load_scenario
    from pipeline.runtime.site import load_site

    scenario = tmp_path / "oil_leak_loaded.toml"
    scenario.write_text((SOURCES / "scenarios" / "oil_leak.toml").read_text() + LOAD)
    site = load_site(sample_build, SOURCES)
    _, shots = scenario_shots(scenario, site, every=20)
    data, _ = run.simulate(load_scenario(scenario, site.zone), run.load_observed(sample_build))
    expected = data.conductor_temperature[::20]
    assert [s.conductor_temperature_c for s in shots] == expected
    assert len(expected) == 4 and 30.0 < expected[0] < expected[-1]  # the load rises, so does the heat

    _, plain = scenario_shots(SOURCES / "scenarios" / "oil_leak.toml", site, every=20)
    assert [s.conductor_temperature_c for s in plain] == [None] * 4  # nothing wired: the built scene's
