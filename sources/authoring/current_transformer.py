"""Author sources/assets/current_transformer: an oil-insulated current transformer.

Base tank on a frame, insulator column with sheds, head tank (the primary winding's
housing) with primary terminals on both sides, a metal bellows on top and a small oil
sight glass on the head tank's front. One link.

    .venv/bin/python sources/authoring/current_transformer.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "current_transformer"
BASE_TOP = 0.9
COLUMN_HEIGHT = 4.2
HEAD_BASE = BASE_TOP + COLUMN_HEIGHT + 0.05


def base() -> None:
    P.box("base_frame", (1.2, 1.2, 0.1), (0.0, 0.0, 0.05), "galvanised_steel", bevel=0.01)
    P.box("base_tank", (0.75, 0.75, BASE_TOP - 0.1), (0.0, 0.0, (BASE_TOP + 0.1) / 2), "painted_grey", bevel=0.03)
    P.box("secondary_terminal_box", (0.35, 0.15, 0.3), (0.0, -0.45, 0.5), "painted_grey", bevel=0.01)
    P.box("earthing_pad", (0.08, 0.02, 0.1), (0.3, -0.385, 0.25), "copper")


def column() -> None:
    P.flange("column_base_flange", (0.0, 0.0, BASE_TOP + 0.02), 0.3, 0.05)
    P.insulator("column_insulator", (0.0, 0.0, BASE_TOP + 0.05), COLUMN_HEIGHT - 0.05, 0.16, 0.3,
                "porcelain_brown", pitch=0.085, segments=96)


def head() -> None:
    profile = [(0.0, 0.0), (0.3, 0.0), (0.42, 0.15), (0.45, 0.45), (0.42, 0.75), (0.3, 0.88), (0.0, 0.9)]
    P.revolve("head_tank", profile, "aluminium", 64, (0.0, 0.0, HEAD_BASE))
    for i, sign in enumerate((-1.0, 1.0), start=1):
        P.cylinder(f"primary_terminal_{i}", 0.06, 0.2, (sign * 0.53, 0.0, HEAD_BASE + 0.45), "aluminium", "X", 32)
        P.box(f"primary_pad_{i}", (0.02, 0.12, 0.12), (sign * 0.64, 0.0, HEAD_BASE + 0.45), "aluminium")
    bellows = [(0.0, 0.0)]
    for k in range(8):
        z = 0.03 * k
        bellows += [(0.2, z + 0.005), (0.23, z + 0.015), (0.2, z + 0.025)]
    bellows += [(0.2, 0.25), (0.0, 0.27)]
    P.revolve("bellows_cover", bellows, "galvanised_steel", 64, (0.0, 0.0, HEAD_BASE + 0.88))
    # The sight glass window on the head's front (-Y), oil visible behind it.
    rotation = (math.pi / 2, 0.0, 0.0)
    window = (0.0, -0.455, HEAD_BASE + 0.5)
    P.revolve("sight_glass_rim", [(0.0, -0.02), (0.08, -0.02), (0.08, 0.02), (0.0, 0.02)], "galvanised_steel",
              32, window, rotation)
    P.revolve("sight_glass_oil", [(0.0, 0.02), (0.06, 0.02), (0.06, 0.024), (0.0, 0.024)], "oil_amber", 32,
              window, rotation)
    P.revolve("sight_glass_window", [(0.0, 0.026), (0.065, 0.026), (0.065, 0.03), (0.0, 0.03)], "gauge_glass",
              32, window, rotation)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    base()
    column()
    head()
    P.finish(ASSET_ID, out,
             terminals=[(name, (sign * 0.64, 0.0, HEAD_BASE + 0.45)) for name, sign in (("a", -1), ("b", 1))])
    P.write_asset_toml(out, ASSET_ID, "instrument_transformer", "oil-insulated current transformer, one phase",
                       budgets=(0.003, 0.015, 0.06), triangle_budget=100000, mass_kg=1400.0)


if __name__ == "__main__":
    main()
