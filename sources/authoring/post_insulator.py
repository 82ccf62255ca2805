"""Author sources/assets/post_insulator/post_insulator.step: a two-unit station post
insulator as vendor CAD (ASSETS.md): millimetres, Z up, separate solids.

Built with gmsh's OpenCASCADE kernel: a bottom flange with eight bolt holes (cut from
the solid, as a manufacturer's model has them), two porcelain units of 15 alternating
sheds each joined by an intermediate flange pair, and a top flange. Ground is Z = 0,
the axis through the foundation centre.

    .venv/bin/python sources/authoring/post_insulator.py [--out DIR]
"""

from __future__ import annotations

import math

from surge_arrester import parse_out, start_gmsh, write_asset_toml, write_step

ASSET_ID = "post_insulator"
TESSELLATION_M = 0.0004

# Dimensions in millimetres (heights along Z).
HEIGHT = 4000.0
BASE_FLANGE = 200.0, 30.0, 20.0     # radius (0.4 m across), thickness, hub height
BOLT_HOLES = 8, 165.0, 11.0         # count, pitch-circle radius, hole radius
MID_FLANGE = 125.0, 25.0            # radius, thickness (one per unit end)
TOP_FLANGE = 110.0, 30.0
CORE_R = 70.0
UNITS = 2
SHEDS_PER_UNIT = 15
SHED_RADII = 180.0, 150.0           # big, small (alternating)
SHED_HEIGHT = 28.0
SHED_RIM = 8.0


def z_cylinder(occ, z0: float, height: float, radius: float) -> int:
    return occ.addCylinder(0, 0, z0, 0, 0, height, radius)


def base_flange(occ) -> float:
    """Flange plate with bolt holes and a hub; returns the height of its top."""
    radius, thickness, hub_h = BASE_FLANGE
    plate = z_cylinder(occ, 0.0, thickness, radius)
    count, pitch_r, hole_r = BOLT_HOLES
    holes = []
    for k in range(count):
        a = 2.0 * math.pi * (k + 0.5) / count
        holes.append((3, occ.addCylinder(pitch_r * math.cos(a), pitch_r * math.sin(a), -1.0,
                                         0, 0, thickness + 2.0, hole_r)))
    occ.cut([(3, plate)], holes)
    z_cylinder(occ, thickness, hub_h, MID_FLANGE[0])
    return thickness + hub_h


def porcelain_unit(occ, z0: float, z1: float) -> None:
    """Core and sheds between two flanges."""
    z_cylinder(occ, z0, z1 - z0, CORE_R)
    pitch = (z1 - z0 - 40.0) / SHEDS_PER_UNIT
    for i in range(SHEDS_PER_UNIT):
        z_rim = z0 + 30.0 + pitch * i
        radius = SHED_RADII[i % 2]
        z_cylinder(occ, z_rim - SHED_RIM, SHED_RIM, radius)
        occ.addCone(0, 0, z_rim, 0, 0, SHED_HEIGHT, radius, CORE_R + 4.0)


def build(occ) -> None:
    z = base_flange(occ)
    top_r, top_t = TOP_FLANGE
    mid_r, mid_t = MID_FLANGE
    unit_h = (HEIGHT - top_t - z - mid_t * 2 * (UNITS - 1)) / UNITS
    for u in range(UNITS):
        porcelain_unit(occ, z, z + unit_h)
        z += unit_h
        if u < UNITS - 1:
            z_cylinder(occ, z, 2 * mid_t, mid_r)
            z += 2 * mid_t
    z_cylinder(occ, z, HEIGHT - z, top_r)


def main() -> None:
    import gmsh

    out = parse_out()
    occ = start_gmsh(ASSET_ID)
    folder = out / ASSET_ID
    try:
        build(occ)
        write_step(folder / f"{ASSET_ID}.step")
    finally:
        gmsh.finalize()
    write_asset_toml(folder, {
        "category": "post_insulator",
        "description": "Station post insulator, two porcelain units with 30 sheds, bolted flanges (vendor STEP, mm, Z up)",
        "source": f"{ASSET_ID}.step",
        "units": "mm",
        "up_axis": "Z",
        "tessellation_tolerance_m": TESSELLATION_M,
        "triangle_budget": 80000,
        "mass_kg": 240.0,
    }, [0.003, 0.015, 0.06], "hull_per_link", terminals=[("top", (0.0, 0.0, HEIGHT / 1000.0))])


if __name__ == "__main__":
    main()
