"""Author sources/assets/fence_segment: a 3 m chain-link fence panel along X with two
posts (ASSETS.md, 3 x 0.1 x 2.5 m).

The mesh is one zig-zag wire (a thin square-section strip) that an Array modifier
repeats across the panel; neighbouring wires touch at their bends, giving the diamonds.

    .venv/bin/python sources/authoring/fence_segment.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P
from lightning_mast import MeshBuilder

ASSET_ID = "fence_segment"
POST_X = 1.45
POST_R = 0.05
HEIGHT = 2.5
MESH_BOTTOM, MESH_TOP = 0.08, 2.3
DIAMOND = 0.1        # wire pitch along X and the bend spacing along Z
WIRE = 0.004         # wire thickness


def zigzag_wire(x0: float) -> MeshBuilder:
    """A vertical zig-zag wire between x0 and x0 + DIAMOND, as square-section segments."""
    bends = int(round((MESH_TOP - MESH_BOTTOM) / DIAMOND))
    pts = [(x0 + DIAMOND * (i % 2), 0.0, MESH_BOTTOM + DIAMOND * i) for i in range(bends + 1)]
    wire = MeshBuilder()
    for a, b in zip(pts, pts[1:]):
        wire.angle(a, b, (0.0, -1.0, 0.0), WIRE, WIRE / 2)
    return wire


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    inner = POST_X - POST_R
    wires = int(round(2 * inner / DIAMOND))
    mesh = zigzag_wire(-inner).object("chain_link", "galvanised_steel")
    P.add_array(mesh, wires - 1, (DIAMOND, 0.0, 0.0))
    for i, x in enumerate((-POST_X, POST_X), start=1):
        P.cylinder(f"post_{i}", POST_R, HEIGHT - 0.02, (x, 0.0, (HEIGHT - 0.02) / 2), "galvanised_steel", "Z", 24)
        P.revolve(f"post_{i}_cap", [(0.0, 0.0), (POST_R, 0.0), (POST_R - 0.004, 0.015), (0.0, 0.02)],
                  "galvanised_steel", 24, (x, 0.0, HEIGHT - 0.02))
    for name, z in (("rail_bottom", MESH_BOTTOM - 0.02), ("rail_top", MESH_TOP + 0.02)):
        P.cylinder(name, 0.021, 2 * inner, (0.0, 0.0, z), "galvanised_steel", "X", 16)
    P.cylinder("tension_wire", 0.003, 2 * inner, (0.0, 0.0, 2.45), "galvanised_steel", "X", 8)
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "fence",
                       "3 m chain-link fence panel with two posts, along X",
                       budgets=[0.005, 0.02, 0.08], collision="box",
                       triangle_budget=40000, mass_kg=60.0)


if __name__ == "__main__":
    main()
