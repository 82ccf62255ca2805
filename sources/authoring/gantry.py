"""Author sources/assets/gantry: a lattice steel line gantry (ASSETS.md, 21 x 1.6 x 16 m).

Two lattice columns with centres 20 m apart along X, a lattice beam across their tops
and three suspension insulator strings (one per phase) hanging from the beam, each
ending in a clamp. Lattice members come from lightning_mast.MeshBuilder.

    .venv/bin/python sources/authoring/gantry.py [--out DIR]
"""

from __future__ import annotations

import numpy as np

import kit
import _parts as P
from lightning_mast import BEVEL_WIDTH, MeshBuilder, rectangle

ASSET_ID = "gantry"

COLUMN_X = 10.0
# Half-widths of the leg lines in X and Y; members and base plates reach 0.08 m
# further out, so the column is 1 x 1.6 m overall.
COLUMN_HALF = (0.42, 0.72)
COLUMN_TOP = 15.95
LATTICE_BOTTOM = 0.05
COLUMN_PANELS = 16
BEAM_BOTTOM, BEAM_TOP = 14.6, 15.8
BEAM_HALF_Y = 0.5
BEAM_PANELS = 19
PHASE_X = (-5.0, 0.0, 5.0)
STRING_LENGTH = 2.6
# a phase's conductors hang from the clamp at the foot of its insulator string
CLAMP_Z = BEAM_BOTTOM - 0.05 - STRING_LENGTH - 0.04
TERMINALS = [(f"p{i}", (x, 0.0, CLAMP_Z)) for i, x in enumerate(PHASE_X, start=1)]


def column_sections(x: float):
    hx, hy = COLUMN_HALF
    step = (COLUMN_TOP - LATTICE_BOTTOM) / COLUMN_PANELS
    return [rectangle(x, 0.0, LATTICE_BOTTOM + step * i, hx, hy) for i in range(COLUMN_PANELS + 1)]


def beam_sections():
    """Vertical rectangles (in the YZ plane) from one column's inner face to the other's."""
    x_in = COLUMN_X - COLUMN_HALF[0]
    sections = []
    for x in np.linspace(-x_in, x_in, BEAM_PANELS + 1):
        sections.append([(x, -BEAM_HALF_Y, BEAM_BOTTOM), (x, BEAM_HALF_Y, BEAM_BOTTOM),
                         (x, BEAM_HALF_Y, BEAM_TOP), (x, -BEAM_HALF_Y, BEAM_TOP)])
    return sections


def steelwork() -> None:
    for name, x in (("column_left", -COLUMN_X), ("column_right", COLUMN_X)):
        frame = MeshBuilder()
        frame.lattice(column_sections(x))
        frame.object(f"{name}_lattice", "galvanised_steel", BEVEL_WIDTH)
        feet = MeshBuilder()
        for sx in (-1, 1):
            for sy in (-1, 1):
                cx, cy = x + sx * COLUMN_HALF[0], sy * COLUMN_HALF[1]
                feet.box((cx - 0.08, cy - 0.08, 0.0), (cx + 0.08, cy + 0.08, LATTICE_BOTTOM))
        feet.object(f"{name}_base_plates", "galvanised_steel")
    beam = MeshBuilder()
    beam.lattice(beam_sections(), leg_width=0.06, brace_width=0.04)
    beam.object("beam_lattice", "galvanised_steel", BEVEL_WIDTH)


def insulator_strings() -> None:
    """Per phase: a suspension link under the beam, a string of sheds, a line clamp."""
    for i, x in enumerate(PHASE_X, start=1):
        top = BEAM_BOTTOM - 0.05
        bottom = top - STRING_LENGTH
        P.box(f"phase_{i}_hanger", (0.12, 0.12, 0.05), (x, 0.0, top + 0.025), "galvanised_steel")
        P.cylinder(f"phase_{i}_link", 0.02, 0.25, (x, 0.0, top - 0.125), "galvanised_steel", "Z", 16)
        P.insulator(f"phase_{i}_string", (x, 0.0, bottom + 0.1), STRING_LENGTH - 0.35, 0.03, 0.13,
                    "silicone_grey", pitch=0.07, segments=48)
        P.cylinder(f"phase_{i}_yoke", 0.05, 0.1, (x, 0.0, bottom + 0.05), "galvanised_steel", "Z", 24)
        P.cylinder(f"phase_{i}_clamp", 0.06, 0.4, (x, 0.0, bottom - 0.04), "aluminium", "X", 24)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    steelwork()
    insulator_strings()
    P.finish(ASSET_ID, out, terminals=TERMINALS)
    P.write_asset_toml(out, ASSET_ID, "gantry",
                       "Lattice steel line gantry, columns 20 m apart, three suspension insulator strings",
                       budgets=[0.01, 0.05, 0.2], collision="hull_per_part",
                       triangle_budget=300000, mass_kg=9000.0)


if __name__ == "__main__":
    main()
