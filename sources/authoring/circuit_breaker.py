"""Author sources/assets/circuit_breaker: an SF6 live-tank circuit breaker, one pole.

A steel pedestal with the spring mechanism cabinet carries a support insulator; on top a
mechanism housing holds two horizontal interrupter chambers (a T head), each with a
grading capacitor beneath it and a terminal pad at its outer end. One link.

    .venv/bin/python sources/authoring/circuit_breaker.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "circuit_breaker"
PEDESTAL_TOP = 3.0
COLUMN_BASE = PEDESTAL_TOP + 0.1
COLUMN_HEIGHT = 3.9
HEAD_Z = COLUMN_BASE + COLUMN_HEIGHT + 0.35  # axis of the interrupter chambers


def pedestal() -> None:
    P.box("pedestal_plate", (0.9, 0.9, 0.03), (0.0, 0.0, 0.015), "galvanised_steel")
    for i, (x, y) in enumerate(((-0.3, -0.3), (0.3, -0.3), (-0.3, 0.3), (0.3, 0.3)), start=1):
        P.box(f"pedestal_leg_{i}", (0.12, 0.12, PEDESTAL_TOP - 0.05), (x, y, PEDESTAL_TOP / 2), "galvanised_steel")
    brace = P.box("pedestal_braces", (0.6, 0.06, 0.06), (0.0, -0.3, 0.6), "galvanised_steel")
    P.add_array(brace, 3, (0.0, 0.0, 0.6))
    P.box("pedestal_top", (0.8, 0.8, 0.06), (0.0, 0.0, PEDESTAL_TOP + 0.02), "galvanised_steel")
    P.box("mechanism_cabinet", (0.8, 0.4, 1.2), (0.0, -0.5, 1.4), "painted_grey", bevel=0.02)
    P.box("mechanism_cabinet_roof", (0.9, 0.45, 0.04), (0.0, -0.5, 2.02), "painted_grey")
    P.rod("operating_rod_guard", (0.0, -0.3, 2.02), (0.0, -0.05, PEDESTAL_TOP), 0.05, "galvanised_steel", 24)
    P.cylinder("sf6_density_monitor", 0.06, 0.05, (0.25, -0.43, PEDESTAL_TOP + 0.02), "dial_white", "Y", 24)


def support_column() -> None:
    P.flange("column_base_flange", (0.0, 0.0, COLUMN_BASE - 0.02), 0.25, 0.06)
    P.insulator("column_insulator", (0.0, 0.0, COLUMN_BASE), COLUMN_HEIGHT, 0.14, 0.27, "porcelain_grey",
                pitch=0.08, segments=96)
    P.flange("column_top_flange", (0.0, 0.0, COLUMN_BASE + COLUMN_HEIGHT + 0.02), 0.25, 0.06)


def interrupter_head() -> None:
    """Mechanism housing and two chambers along +-X; insulators are authored along Z and
    turned onto the X axis."""
    P.revolve("head_housing", [(0.0, -0.3), (0.24, -0.3), (0.3, -0.2), (0.3, 0.2), (0.24, 0.3), (0.0, 0.3)],
              "aluminium", 64, (0.0, 0.0, HEAD_Z), (math.pi / 2, 0.0, 0.0))
    for i, sign in enumerate((-1.0, 1.0), start=1):
        rotation = (0.0, sign * math.pi / 2, 0.0)  # local Z onto +-X
        chamber = P.insulator(f"chamber_{i}_insulator", (0.0, 0.0, 0.0), 1.15, 0.13, 0.24, "porcelain_grey",
                              pitch=0.07, segments=96)
        chamber.location = (sign * 0.32, 0.0, HEAD_Z)
        chamber.rotation_euler = rotation
        P.cylinder(f"chamber_{i}_end_cap", 0.2, 0.16, (sign * 1.55, 0.0, HEAD_Z), "aluminium", "X", 48)
        P.box(f"chamber_{i}_terminal_pad", (0.12, 0.03, 0.12), (sign * 1.69, 0.0, HEAD_Z + 0.16), "aluminium")
        capacitor = P.insulator(f"capacitor_{i}_insulator", (0.0, 0.0, 0.0), 1.0, 0.05, 0.09, "porcelain_grey",
                                pitch=0.06, segments=48)
        capacitor.location = (sign * 0.4, 0.0, HEAD_Z - 0.42)
        capacitor.rotation_euler = rotation
        P.rod(f"capacitor_{i}_bracket", (sign * 1.45, 0.0, HEAD_Z - 0.15), (sign * 1.45, 0.0, HEAD_Z - 0.42),
              0.025, "aluminium")


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    pedestal()
    support_column()
    interrupter_head()
    P.finish(ASSET_ID, out,
             terminals=[(name, (sign * 1.69, 0.0, HEAD_Z + 0.16)) for name, sign in (("a", -1), ("b", 1))])
    P.write_asset_toml(out, ASSET_ID, "switchgear", "SF6 live-tank circuit breaker, one pole, T-shaped head",
                       budgets=(0.003, 0.015, 0.06), triangle_budget=200000, mass_kg=2200.0)


if __name__ == "__main__":
    main()
