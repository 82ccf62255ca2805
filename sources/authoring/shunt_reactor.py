"""Author sources/assets/shunt_reactor: a 500 kV single-phase shunt reactor.

One link, no joints. Tank with stiffeners, fin radiator banks on both ends, two HV
bushings on turrets, conservator with pipework, and the three oil-level indicators of
the case study (PAPER_NOTES.md): the main-tank dial gauge with its alarm lamp and the two
bushing sight glasses. The indicator positions are fixed: the floor plan's inspection
points are derived from them.

    .venv/bin/python sources/authoring/shunt_reactor.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "shunt_reactor"
TANK_HALF = (2.5, 1.7)  # half length (x) and half depth (y) of the tank
TANK_TOP = 4.2
SKID_TOP = 0.25
GAUGE_CENTER = (0.0, -1.80, 2.80)
LAMP_CENTER = (0.45, -1.80, 2.80)
BUSHING_X = 1.5


def skids_and_tank() -> None:
    hx, hy = TANK_HALF
    for i, y in enumerate((-1.2, 1.2), start=1):
        P.box(f"skid_{i}", (5.4, 0.3, SKID_TOP), (0.0, y, SKID_TOP / 2), "painted_grey")
    height = TANK_TOP - SKID_TOP
    P.box("tank", (2 * hx, 2 * hy, height), (0.0, 0.0, SKID_TOP + height / 2), "painted_tank", bevel=0.04)
    P.box("tank_base_flange", (2 * hx + 0.2, 2 * hy + 0.2, 0.1), (0.0, 0.0, SKID_TOP + 0.05), "painted_tank")
    P.box("tank_cover", (2 * hx + 0.2, 2 * hy + 0.2, 0.12), (0.0, 0.0, TANK_TOP + 0.06), "painted_tank", bevel=0.02)
    stiffeners()


def stiffeners() -> None:
    """Vertical ribs on the long faces; the front keeps its middle free for the gauge."""
    hx, hy = TANK_HALF
    size = (0.12, 0.1, TANK_TOP - SKID_TOP - 0.3)
    z = SKID_TOP + 0.15 + size[2] / 2
    for name, x0, y, count in (("tank_ribs_front_left", -2.0, -hy - 0.05, 2),
                               ("tank_ribs_front_right", 1.0, -hy - 0.05, 2),
                               ("tank_ribs_back", -2.0, hy + 0.05, 5)):
        rib = P.box(name, size, (x0, y, z), "painted_tank", bevel=0.01)
        P.add_array(rib, count, (1.0, 0.0, 0.0))


def radiator_banks() -> None:
    hx, _ = TANK_HALF
    for side, sign in (("east", 1.0), ("west", -1.0)):
        P.radiator_bank(f"radiator_{side}", sign, hx + 0.15, depth=1.2, pitch=0.06, count=50,
                        z0=0.8, height=3.0, feeds_y=(-0.9, 0.9))


def turrets_and_bushings() -> None:
    for i, sign in enumerate((-1.0, 1.0), start=1):
        x = sign * BUSHING_X
        P.cylinder(f"turret_{i}", 0.4, 6.0 - TANK_TOP, (x, 0.0, (TANK_TOP + 6.0) / 2), "painted_tank", "Z", 48)
        P.flange(f"turret_{i}_flange", (x, 0.0, 6.0), 0.5, 0.06)
        P.cylinder(f"bushing_{i}_mounting", 0.22, 0.2, (x, 0.0, 6.13), "aluminium", "Z", 48)
        P.insulator(f"bushing_{i}_sheds", (x, 0.0, 6.23), 1.12, 0.13, 0.25, "porcelain_brown",
                    pitch=0.075, segments=96)
        P.cylinder(f"bushing_{i}_dome", 0.17, 0.1, (x, 0.0, 7.4), "aluminium", "Z", 48)
        P.cylinder(f"bushing_{i}_terminal", 0.04, 0.06, (x, 0.0, 7.48), "aluminium", "Z", 16)
        # The bushing-extension oil indicator stands off the turret's front on a bracket.
        P.box(f"gauge_b{i}_bracket", (0.06, 0.2, 0.04), (x, -0.5, 5.62), "galvanised_steel")
        P.sight_glass(f"gauge_b{i}", (x, -0.6, 5.65), f"oil_level_b{i}")


def conservator() -> None:
    y, z, r, half = 1.9, 6.4, 0.45, 1.8
    profile = [(0.0, -half - 0.15), (0.3, -half - 0.1), (0.42, -half - 0.04), (r, -half),
               (r, half), (0.42, half + 0.04), (0.3, half + 0.1), (0.0, half + 0.15)]
    P.revolve("conservator", profile, "painted_tank", 64, (0.0, y, z), (0.0, math.pi / 2, 0.0))
    for i, x in enumerate((-1.2, 1.2), start=1):
        P.rod(f"conservator_leg_{i}", (x, 1.5, TANK_TOP + 0.12), (x, y, z - r + 0.02), 0.06, "galvanised_steel")
        P.box(f"conservator_saddle_{i}", (0.12, 0.7, 0.15), (x, y, z - r + 0.05), "galvanised_steel")
    # Main pipe with the Buchholz relay, and a feed to each turret.
    P.rod("pipe_main_riser", (0.0, y, z - r), (0.0, y, 5.2), 0.05, "painted_tank")
    P.rod("pipe_main_run", (0.0, y, 5.2), (0.0, 1.0, 5.2), 0.05, "painted_tank")
    P.rod("pipe_main_drop", (0.0, 1.0, 5.2), (0.0, 1.0, TANK_TOP + 0.12), 0.05, "painted_tank")
    P.box("buchholz_relay", (0.22, 0.3, 0.22), (0.0, 1.45, 5.2), "painted_grey", bevel=0.01)
    for i, sign in enumerate((-1.0, 1.0), start=1):
        x = sign * BUSHING_X
        P.rod(f"pipe_turret_{i}", (x, y - 0.2, z - r + 0.05), (x, 0.35, 5.6), 0.025, "painted_tank")
    P.rod("breather_pipe", (half, y, z), (2.3, y, 5.0), 0.02, "painted_tank")
    P.cylinder("breather", 0.09, 0.45, (2.3, y, 4.75), "gauge_glass", "Z", 24)


def indicators() -> None:
    """Main-tank dial gauge and its alarm lamp (the case study's front indicator)."""
    P.dial_gauge("gauge_tank", GAUGE_CENTER, 0.15, "oil_level_tank")
    lx, ly, lz = LAMP_CENTER
    P.box("alarm_lamp_base", (0.12, 0.08, 0.12), (lx, -TANK_HALF[1] - 0.04, lz), "painted_grey")
    dome = [(0.0, 0.0), (0.045, 0.0), (0.045, 0.02), (0.035, 0.045), (0.0, 0.055)]
    lamp = P.revolve("alarm_lamp", dome, "lamp_off", 32, (lx, ly + 0.02, lz), P.DIAL_ROTATION)
    kit.bind_state(lamp, "oil_level_tank", "material", (0.0, 100.0),
                   materials=("lamp_alarm", "lamp_off"), thresholds=(25.0,))
    P.keep_material("lamp_alarm")


def control_cabinet() -> None:
    P.box("control_cabinet", (0.8, 0.4, 1.1), (-1.5, -TANK_HALF[1] - 0.2, 1.4), "painted_grey", bevel=0.02)
    P.rod("control_conduit", (-1.5, -TANK_HALF[1] - 0.2, 0.85), (-1.5, -TANK_HALF[1] - 0.2, 0.3), 0.03,
          "galvanised_steel")


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    skids_and_tank()
    radiator_banks()
    turrets_and_bushings()
    conservator()
    indicators()
    control_cabinet()
    P.finish(ASSET_ID, out, terminals=[("hv", (-BUSHING_X, 0.0, 7.51)), ("neutral", (BUSHING_X, 0.0, 7.51))])
    P.write_asset_toml(out, ASSET_ID, "reactor",
                       "500 kV single-phase shunt reactor with main-tank dial gauge and two bushing sight glasses",
                       budgets=(0.003, 0.015, 0.06), triangle_budget=250000, mass_kg=180000.0)


if __name__ == "__main__":
    main()
