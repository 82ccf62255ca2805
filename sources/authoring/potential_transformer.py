"""Author sources/assets/potential_transformer: a capacitive voltage transformer.

Base box (the electromagnetic unit) with a terminal box, two stacked capacitor units
with sheds joined by flanges, and a top cap with the line terminal. One link.

    .venv/bin/python sources/authoring/potential_transformer.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P

ASSET_ID = "potential_transformer"
BASE_TOP = 1.05
UNIT_HEIGHT = 2.7


def base() -> None:
    P.box("base_frame", (1.2, 1.2, 0.1), (0.0, 0.0, 0.05), "galvanised_steel", bevel=0.01)
    P.box("electromagnetic_unit", (0.9, 0.7, BASE_TOP - 0.1), (0.0, 0.0, (BASE_TOP + 0.1) / 2), "painted_grey",
          bevel=0.03)
    P.box("terminal_box", (0.4, 0.16, 0.35), (0.0, -0.43, 0.6), "painted_grey", bevel=0.01)
    fins = P.box("cooling_ribs", (0.02, 0.05, 0.6), (-0.35, 0.37, 0.55), "painted_grey")
    P.add_array(fins, 8, (0.1, 0.0, 0.0))


def capacitor_units() -> float:
    """Two stacked units; returns the height of the top flange."""
    z = BASE_TOP
    for i in (1, 2):
        P.flange(f"unit_{i}_bottom_flange", (0.0, 0.0, z + 0.03), 0.24, 0.06)
        P.insulator(f"unit_{i}_insulator", (0.0, 0.0, z + 0.06), UNIT_HEIGHT - 0.12, 0.14, 0.26,
                    "porcelain_grey", pitch=0.08, segments=72)
        P.flange(f"unit_{i}_top_flange", (0.0, 0.0, z + UNIT_HEIGHT - 0.03), 0.24, 0.06)
        z += UNIT_HEIGHT
    return z


def top_cap(z: float) -> None:
    profile = [(0.0, 0.0), (0.25, 0.0), (0.27, 0.05), (0.22, 0.16), (0.12, 0.22), (0.0, 0.24)]
    P.revolve("top_cap", profile, "aluminium", 64, (0.0, 0.0, z))
    P.cylinder("line_terminal", 0.04, 0.15, (0.0, 0.0, z + 0.3), "aluminium", "Z", 24)
    P.box("line_terminal_pad", (0.12, 0.02, 0.1), (0.0, 0.0, z + 0.42), "aluminium")


# the line terminal pad on the top cap of the two capacitor units
TERMINALS = [("line", (0.0, 0.0, BASE_TOP + 2 * UNIT_HEIGHT + 0.47))]


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    base()
    top_cap(capacitor_units())
    P.finish(ASSET_ID, out, terminals=TERMINALS)
    P.write_asset_toml(out, ASSET_ID, "instrument_transformer", "capacitive voltage transformer, one phase",
                       budgets=(0.003, 0.015, 0.06), triangle_budget=100000, mass_kg=900.0)


if __name__ == "__main__":
    main()
