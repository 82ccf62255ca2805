"""Author sources/assets/equipment_support: a 2.5 m lattice steel pedestal with a cap
plate, the support a 500 kV current transformer, surge arrester or post insulator
stands on so that its live parts clear IEC 61936-1's 5.4 m over the ground
(sources/clearances.toml). The equipment is a placement of its own, at the pedestal's
top (the floor plan's INSERT z), as the rigid busbars ride on busbar_support.

    .venv/bin/python sources/authoring/equipment_support.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P
from lightning_mast import BEVEL_WIDTH, MeshBuilder, tapered_stations

ASSET_ID = "equipment_support"

TOP = 2.5                           # the cap plate's top: where the equipment's base stands
CAP = 0.03
BASE_HALF, TOP_HALF = 0.45, 0.3


def pedestal() -> None:
    frame = MeshBuilder()
    frame.lattice(tapered_stations(0.05, TOP - CAP, BASE_HALF, TOP_HALF, 4), leg_width=0.07, brace_width=0.045)
    frame.object("pedestal_lattice", "galvanised_steel", BEVEL_WIDTH)
    feet = MeshBuilder()
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * BASE_HALF, sy * BASE_HALF
            feet.box((x - 0.09, y - 0.09, 0.0), (x + 0.09, y + 0.09, 0.05))
    feet.object("base_plates", "galvanised_steel")
    P.box("cap_plate", (2 * TOP_HALF + 0.2, 2 * TOP_HALF + 0.2, CAP), (0.0, 0.0, TOP - CAP / 2), "galvanised_steel")


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    pedestal()
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "support_structure",
                       "Lattice steel pedestal, 2.5 m, under a 500 kV instrument transformer, arrester or post insulator",
                       budgets=[0.005, 0.02, 0.08], collision="hull_per_part", triangle_budget=40000, mass_kg=420.0)


if __name__ == "__main__":
    main()
