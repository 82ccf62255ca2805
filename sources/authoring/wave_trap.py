"""Author sources/assets/wave_trap: a line trap, an air-core coil on three insulators
(ASSETS.md, 2 x 2 x 4 m). The sample floor plan deliberately does not place it: the
build must skip assets that no placement uses.

The coil is one round conductor section swept along a helix by a Screw modifier; the
clamping spiders are an 8-arm star arrayed to top and bottom.

    .venv/bin/python sources/authoring/wave_trap.py [--out DIR]
"""

from __future__ import annotations

import math

import bpy

import kit
import _parts as P
from lightning_mast import MeshBuilder

ASSET_ID = "wave_trap"
COIL_R = 0.92                 # mean winding radius (2 m across with the rings)
COIL_BOTTOM, COIL_TOP = 2.25, 3.75
TURNS = 10
CONDUCTOR_R = 0.03
INSULATOR_RING_R = 0.6
INSULATOR_BASE, INSULATOR_HEIGHT = 0.1, 2.0
# Quads of a box whose 8 corners run x fastest, then y, then z.
BOX_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def coil() -> None:
    """A circle of the conductor's radius at the winding radius, screwed up the axis."""
    steps = 12
    verts = [(COIL_R + CONDUCTOR_R * math.cos(2 * math.pi * k / steps), 0.0,
              CONDUCTOR_R * math.sin(2 * math.pi * k / steps)) for k in range(steps)]
    edges = [(k, (k + 1) % steps) for k in range(steps)]
    me = bpy.data.meshes.new("coil")
    me.from_pydata(verts, edges, [])
    me.materials.append(kit.material("aluminium"))
    ob = bpy.data.objects.new("coil", me)
    ob.location = (0.0, 0.0, COIL_BOTTOM + 0.05)
    bpy.context.scene.collection.objects.link(ob)
    screw = ob.modifiers.new("helix", "SCREW")
    screw.axis = "Z"
    screw.angle = kit.TAU
    screw.iterations = TURNS
    screw.screw_offset = (COIL_TOP - COIL_BOTTOM - 0.1) / TURNS
    screw.steps = screw.render_steps = 48
    screw.use_normal_calculate = True


def spiders() -> None:
    """Eight radial aluminium arms at the bottom and top of the coil, plus corona rings."""
    star = MeshBuilder()
    length = COIL_R + 0.05
    for z in (COIL_BOTTOM, COIL_TOP):
        for k in range(8):
            c, sn = math.cos(kit.TAU * k / 8), math.sin(kit.TAU * k / 8)
            arm = [(x * c - y * sn, x * sn + y * c, z + dz)
                   for dz in (-0.04, 0.04) for y in (-0.03, 0.03) for x in (0.0, length)]
            star.add(arm, BOX_FACES)
    star.object("spiders", "aluminium")
    P.cylinder("hub", 0.12, COIL_TOP - COIL_BOTTOM, (0.0, 0.0, (COIL_BOTTOM + COIL_TOP) / 2), "aluminium", "Z", 32)
    for name, z in (("corona_ring_bottom", COIL_BOTTOM - 0.05), ("corona_ring_top", COIL_TOP + 0.05)):
        ring = [(0.97 + 0.03 * math.cos(a), 0.03 * math.sin(a))
                for a in (-math.pi / 2 + 2 * math.pi * k / 12 for k in range(13))]
        P.revolve(name, [(r, zz + z) for r, zz in ring], "aluminium", 64)


def supports() -> None:
    """Base frame and three post insulators on a circle, 120 degrees apart."""
    P.box("base_frame", (1.5, 1.5, INSULATOR_BASE), (0.0, 0.0, INSULATOR_BASE / 2), "galvanised_steel")
    for i in range(3):
        a = math.pi / 2 + kit.TAU * i / 3
        x, y = INSULATOR_RING_R * math.cos(a), INSULATOR_RING_R * math.sin(a)
        P.insulator(f"insulator_{i + 1}", (x, y, INSULATOR_BASE), INSULATOR_HEIGHT, 0.045, 0.1,
                    "porcelain_brown", pitch=0.09, segments=24)
        P.flange(f"insulator_{i + 1}_cap", (x, y, INSULATOR_BASE + INSULATOR_HEIGHT + 0.02), 0.07, 0.04)
        P.rod(f"insulator_{i + 1}_bracket", (x, y, INSULATOR_BASE + INSULATOR_HEIGHT + 0.04),
              (0.0, 0.0, COIL_BOTTOM - 0.04), 0.03, "aluminium", 12)
    P.cylinder("line_terminal", 0.04, 0.2, (0.0, 0.0, COIL_TOP + 0.12), "aluminium", "Z", 16)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    supports()
    coil()
    spiders()
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "wave_trap",
                       "Line trap: air-core coil with spiders and corona rings on three post insulators",
                       budgets=[0.005, 0.02, 0.08], collision="hull_per_part",
                       triangle_budget=60000, mass_kg=900.0)


if __name__ == "__main__":
    main()
