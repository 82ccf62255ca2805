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
from lightning_mast import lattice_pedestal

ASSET_ID = "equipment_support"

TOP = 2.5                           # the cap plate's top: where the equipment's base stands
CAP = 0.03
BASE_HALF, TOP_HALF = 0.45, 0.3


def pedestal() -> None:
    lattice_pedestal(TOP - CAP, BASE_HALF, TOP_HALF, 4, leg_width=0.07, brace_width=0.045, foot_half=0.09,
                     cap_side=2 * TOP_HALF + 0.2, cap_thickness=CAP, cap_z=TOP - CAP / 2)


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
