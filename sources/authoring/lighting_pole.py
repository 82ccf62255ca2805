"""Author sources/assets/lighting_pole: a 12 m tapered tubular pole with two floodlight
heads on a cross-arm (ASSETS.md, 1.2 x 0.5 x 12 m). The heads aim forwards (-Y) and
down; their lenses use the emissive lamp_white material.

    .venv/bin/python sources/authoring/lighting_pole.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "lighting_pole"
POLE_TOP = 11.8
ARM_Z = 11.9
HEAD_X = 0.42
HEAD_SIZE = (0.34, 0.16, 0.26)      # width, depth, height of a floodlight housing
HEAD_TILT = math.radians(25.0)      # aimed down from horizontal


def pole() -> None:
    P.box("base_plate", (0.4, 0.4, 0.025), (0.0, 0.0, 0.0125), "galvanised_steel", bevel=0.004)
    bolts = P.cylinder("anchor_nuts", 0.02, 0.04, (-0.15, -0.15, 0.045), "galvanised_steel", "Z", 6)
    P.add_array(bolts, 2, (0.3, 0.0, 0.0), "array_x")
    P.add_array(bolts, 2, (0.0, 0.3, 0.0), "array_y")
    profile = [(0.0, 0.025), (0.11, 0.025), (0.11, 0.06), (0.085, 0.08), (0.08, 0.6),
               (0.075, 3.0), (0.065, 6.0), (0.055, 9.0), (0.045, POLE_TOP), (0.0, POLE_TOP)]
    P.revolve("pole", profile, "galvanised_steel", 64)
    # Cable access door near the foot, on the back (+Y) so the front stays clean.
    P.box("handhole_cover", (0.08, 0.012, 0.25), (0.0, 0.082, 0.5), "galvanised_steel", bevel=0.003)
    P.cylinder("pole_top_cap", 0.05, 0.03, (0.0, 0.0, POLE_TOP + 0.015), "galvanised_steel", "Z", 24)
    P.cylinder("cross_arm", 0.03, 2 * HEAD_X, (0.0, 0.0, ARM_Z), "galvanised_steel", "X", 24)
    P.rod("arm_upright", (0.0, 0.0, POLE_TOP), (0.0, 0.0, ARM_Z), 0.035, "galvanised_steel", 24)


def attach(child, parent, local_location) -> None:
    """Make `child` ride with `parent`, placed at `local_location` in the parent's frame."""
    child.parent = parent
    child.location = local_location


def floodlight(i: int, x: float) -> None:
    """Housing, lens and yoke; the housing is tilted about X so the lens faces -Y and down."""
    w, d, h = HEAD_SIZE
    centre = (x, -0.12, ARM_Z - 0.05)
    tilt = (HEAD_TILT, 0.0, 0.0)
    housing = P.box(f"floodlight_{i}_housing", (w, d, h), centre, "painted_grey", bevel=0.015)
    housing.rotation_euler = tilt
    lens = P.box(f"floodlight_{i}_lens", (w - 0.04, 0.01, h - 0.04), (0.0, 0.0, 0.0), "lamp_white")
    attach(lens, housing, (0.0, -d / 2 - 0.004, 0.0))
    fins = P.box(f"floodlight_{i}_fins", (w - 0.04, 0.03, 0.008), (0.0, 0.0, 0.0), "painted_grey")
    attach(fins, housing, (0.0, d / 2 + 0.015, -h / 2 + 0.03))
    P.add_array(fins, 7, (0.0, 0.0, (h - 0.06) / 6))
    P.rod(f"floodlight_{i}_yoke", (x, 0.0, ARM_Z), centre, 0.015, "galvanised_steel", 12)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    pole()
    for i, x in enumerate((-HEAD_X, HEAD_X), start=1):
        floodlight(i, x)
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "lighting",
                       "12 m tubular lighting pole with two floodlights (emissive lenses)",
                       budgets=[0.005, 0.02, 0.08], collision="hull_per_part",
                       triangle_budget=20000, mass_kg=350.0)


if __name__ == "__main__":
    main()
