"""Author sources/assets/power_transformer: a 500/230 kV single-phase autotransformer.

Tank with stiffeners on skids, banks of fin radiators with fans on both ends, a tall
conservator, HV, MV and neutral bushings on turrets, a tap-changer compartment, a
control cabinet, and a main-tank dial gauge like the shunt reactor's, bound to
`oil_level_tank`, on the front face. One link.

    .venv/bin/python sources/authoring/power_transformer.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "power_transformer"
TANK_HALF = (3.5, 2.95)  # half length (x) and half depth (y) of the tank
SKID_TOP = 0.3
TANK_TOP = 4.8
GAUGE_CENTER = (2.0, -3.05, 3.0)


def tank() -> None:
    hx, hy = TANK_HALF
    for i, y in enumerate((-2.0, 2.0), start=1):
        P.box(f"skid_{i}", (7.6, 0.4, SKID_TOP), (0.0, y, SKID_TOP / 2), "painted_grey")
    height = TANK_TOP - SKID_TOP
    P.box("tank", (2 * hx, 2 * hy, height), (0.0, 0.0, SKID_TOP + height / 2), "painted_tank", bevel=0.05)
    P.box("tank_cover", (2 * hx + 0.2, 2 * hy + 0.2, 0.15), (0.0, 0.0, TANK_TOP + 0.075), "painted_tank",
          bevel=0.02)
    P.box("tank_base_flange", (2 * hx + 0.2, 2 * hy + 0.2, 0.12), (0.0, 0.0, SKID_TOP + 0.06), "painted_tank")
    size = (0.14, 0.12, height - 0.4)
    z = SKID_TOP + 0.2 + size[2] / 2
    # Ribs at x = -3, -2, -1, 0, 1 and 3 on the front (x = 2 holds the gauge); 7 on the back.
    for name, x0, y, count in (("tank_ribs_front_left", -3.0, -hy - 0.06, 5),
                               ("tank_ribs_front_right", 3.0, -hy - 0.06, 1),
                               ("tank_ribs_back", -3.0, hy + 0.06, 7)):
        rib = P.box(name, size, (x0, y, z), "painted_tank", bevel=0.01)
        if count > 1:
            P.add_array(rib, count, (1.0, 0.0, 0.0))


def radiators_and_fans() -> None:
    hx, _ = TANK_HALF
    for side, sign in (("east", 1.0), ("west", -1.0)):
        P.radiator_bank(f"radiator_{side}", sign, hx + 0.15, depth=1.8, pitch=0.065, count=70,
                        z0=0.9, height=3.4, feeds_y=(-1.8, 0.0, 1.8))
        x = sign * (hx + 0.15 + 0.9)
        for k, y in enumerate((-1.5, 0.0, 1.5), start=1):
            shroud = [(0.42, 0.0), (0.45, 0.0), (0.45, 0.25), (0.42, 0.25)]
            P.revolve(f"fan_{side}_{k}_shroud", shroud, "painted_grey", 64, (x, y, 0.3))
            fan_blades(f"fan_{side}_{k}_blades", (x, y, 0.45))
            P.cylinder(f"fan_{side}_{k}_hub", 0.07, 0.1, (x, y, 0.42), "painted_grey", "Z", 24)


def fan_blades(name: str, center, count: int = 5):
    """`count` pitched blades around a vertical hub, as one mesh."""
    verts, faces = [], []
    for k in range(count):
        a = kit.TAU * k / count
        c, s = math.cos(a), math.sin(a)
        for x, y, z in P.box_verts((0.14, 0.34, 0.01), (0.0, 0.24, 0.0)):
            # Pitch each blade 20 degrees about its own radial axis, then turn it into place.
            x, z = x * math.cos(0.35) - z * math.sin(0.35), x * math.sin(0.35) + z * math.cos(0.35)
            verts.append((x * c - y * s, x * s + y * c, z))
        faces += [tuple(8 * k + i for i in f) for f in P.BOX_FACES]
    return P.mesh(name, verts, faces, "painted_grey", center)


# the bushing tops (dome caps), left to right: what bushings() builds
BUSHINGS = (("hv", -2.0, 4.1, 0.16, 0.3, 0.7), ("mv", 0.5, 2.5, 0.13, 0.24, 0.5), ("neutral", 2.6, 0.9, 0.08, 0.15, 0.3))
TERMINALS = [(name, (x, 0.0, TANK_TOP + 0.15 + turret + 0.06 + height + 0.12))
             for name, x, height, _, _, turret in BUSHINGS]


def bushings() -> None:
    """HV (500 kV), MV (230 kV) and neutral bushings on turrets, left to right."""
    for name, x, height, r_core, r_big, turret_h in BUSHINGS:
        z0 = TANK_TOP + 0.15
        P.cylinder(f"turret_{name}", 0.42 if name != "neutral" else 0.22, turret_h, (x, 0.0, z0 + turret_h / 2),
                   "painted_tank", "Z", 48)
        top = z0 + turret_h
        P.flange(f"bushing_{name}_flange", (x, 0.0, top + 0.03), r_big + 0.12, 0.06)
        P.insulator(f"bushing_{name}_sheds", (x, 0.0, top + 0.06), height, r_core, r_big, "porcelain_brown",
                    pitch=0.085, segments=64)
        P.cylinder(f"bushing_{name}_dome", r_core + 0.04, 0.12, (x, 0.0, top + 0.06 + height + 0.06),
                   "aluminium", "Z", 48)


def conservator() -> None:
    y, z, r, half = 2.9, 8.2, 0.5, 2.6
    profile = [(0.0, -half - 0.18), (0.32, -half - 0.12), (0.46, -half - 0.05), (r, -half),
               (r, half), (0.46, half + 0.05), (0.32, half + 0.12), (0.0, half + 0.18)]
    P.revolve("conservator", profile, "painted_tank", 64, (0.0, y, z), (0.0, math.pi / 2, 0.0))
    for i, x in enumerate((-1.8, 1.8), start=1):
        P.rod(f"conservator_leg_{i}", (x, 2.6, TANK_TOP + 0.15), (x, y, z - r + 0.02), 0.08, "galvanised_steel")
        P.box(f"conservator_saddle_{i}", (0.15, 0.8, 0.18), (x, y, z - r + 0.06), "galvanised_steel")
    P.rod("pipe_main_riser", (0.0, y, z - r), (0.0, y, 6.0), 0.06, "painted_tank")
    P.rod("pipe_main_run", (0.0, y, 6.0), (0.0, 2.0, 6.0), 0.06, "painted_tank")
    P.rod("pipe_main_drop", (0.0, 2.0, 6.0), (0.0, 2.0, TANK_TOP + 0.15), 0.06, "painted_tank")
    P.box("buchholz_relay", (0.25, 0.35, 0.25), (0.0, 2.45, 6.0), "painted_grey", bevel=0.01)
    P.rod("breather_pipe", (half, y, z), (3.2, y, 5.6), 0.025, "painted_tank")
    P.cylinder("breather", 0.1, 0.5, (3.2, y, 5.35), "gauge_glass", "Z", 24)


def front_equipment() -> None:
    hx, hy = TANK_HALF
    P.dial_gauge("gauge_tank", GAUGE_CENTER, 0.15, "oil_level_tank")
    P.box("tap_changer", (1.0, 0.5, 2.2), (-1.5, -hy - 0.25, 2.6), "painted_tank", bevel=0.03)
    P.box("control_cabinet", (1.0, 0.45, 1.6), (0.5, -hy - 0.225, 1.6), "painted_grey", bevel=0.02)
    P.rod("control_conduit", (0.5, -hy - 0.2, 0.8), (0.5, -hy - 0.2, 0.3), 0.04, "galvanised_steel")


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    tank()
    radiators_and_fans()
    bushings()
    conservator()
    front_equipment()
    P.finish(ASSET_ID, out, terminals=TERMINALS)
    P.write_asset_toml(out, ASSET_ID, "transformer",
                       "500/230 kV single-phase autotransformer with a main-tank dial gauge",
                       budgets=(0.004, 0.02, 0.08), triangle_budget=300000, mass_kg=260000.0)


if __name__ == "__main__":
    main()
