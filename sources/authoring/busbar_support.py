"""Author sources/assets/busbar_support: a 5 m lattice steel pedestal carrying a station
post insulator and a bus clamp (ASSETS.md, 1 x 1 x 8 m). The rigid busbar (a separate
asset) rests in the clamp at about 8 m.

    .venv/bin/python sources/authoring/busbar_support.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P
from lightning_mast import lattice_pedestal

ASSET_ID = "busbar_support"

PEDESTAL_TOP = 5.0
BASE_HALF, TOP_HALF = 0.42, 0.22
INSULATOR_BASE = PEDESTAL_TOP + 0.05
INSULATOR_HEIGHT = 2.5
CLAMP_Z = 7.85                      # busbar axis height


def pedestal() -> None:
    lattice_pedestal(PEDESTAL_TOP, BASE_HALF, TOP_HALF, 7, leg_width=0.06, brace_width=0.04, foot_half=0.08,
                     cap_side=0.56, cap_thickness=0.03, cap_z=PEDESTAL_TOP + 0.015)


def insulator() -> None:
    P.flange("insulator_base_flange", (0.0, 0.0, INSULATOR_BASE - 0.005), 0.14, 0.03)
    P.insulator("post_insulator_sheds", (0.0, 0.0, INSULATOR_BASE + 0.01), INSULATOR_HEIGHT - 0.04,
                0.06, 0.16, "porcelain_brown", pitch=0.075, segments=64)
    P.flange("insulator_top_flange", (0.0, 0.0, INSULATOR_BASE + INSULATOR_HEIGHT - 0.015), 0.1, 0.03)


def bus_clamp() -> None:
    """A saddle the 0.2 m tube lies in: base block and two cheeks either side in Y."""
    z0 = INSULATOR_BASE + INSULATOR_HEIGHT
    P.box("clamp_base", (0.3, 0.3, 0.06), (0.0, 0.0, z0 + 0.03), "aluminium", bevel=0.005)
    for i, y in enumerate((-0.125, 0.125), start=1):
        P.box(f"clamp_cheek_{i}", (0.25, 0.03, CLAMP_Z - z0 + 0.05), (0.0, y, (z0 + CLAMP_Z + 0.05) / 2),
              "aluminium", bevel=0.005)
    P.cylinder("clamp_bolt", 0.012, 0.3, (0.0, 0.0, CLAMP_Z + 0.09), "galvanised_steel", "Y", 16)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    pedestal()
    insulator()
    bus_clamp()
    P.finish(ASSET_ID, out, terminals=[("clamp", (0.0, 0.0, CLAMP_Z + 0.1))])
    P.write_asset_toml(out, ASSET_ID, "busbar_support",
                       "Lattice steel pedestal with a station post insulator and a bus clamp",
                       budgets=[0.005, 0.02, 0.08], collision="hull_per_part",
                       triangle_budget=120000, mass_kg=650.0)


if __name__ == "__main__":
    main()
