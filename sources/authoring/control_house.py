"""Author sources/assets/control_house: a single-storey control house (ASSETS.md,
20 x 10 x 4.6 m): concrete plinth, brick walls, windows with frames and glass, a steel
door on the front (-Y), a corrugated metal gable roof with overhang.

    .venv/bin/python sources/authoring/control_house.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P
from lightning_mast import MeshBuilder

ASSET_ID = "control_house"
HALF_X, HALF_Y = 9.7, 4.6           # outer faces of the walls
PLINTH_TOP = 0.3
EAVES = 3.9                         # wall top
RIDGE = 4.55                        # ridge cap on top reaches 4.6 m
OVERHANG = 0.3
WALL_T = 0.25
WINDOW = 1.4, 1.1, 1.2              # width, height, sill height
WINDOWS_FRONT = (-7.5, -5.0, -2.5, 2.5, 5.0, 7.5)
WINDOWS_BACK = (-7.5, -5.0, -2.5, 0.0, 2.5, 5.0, 7.5)
WINDOWS_SIDE = (-2.0, 2.0)
CORRUGATION = 0.2                   # pitch of the roof sheet ribs


def walls() -> None:
    P.box("plinth", (2 * HALF_X + 0.1, 2 * HALF_Y + 0.1, PLINTH_TOP), (0.0, 0.0, PLINTH_TOP / 2), "concrete")
    brick = MeshBuilder()
    for sy in (-1, 1):
        brick.box((-HALF_X, sy * HALF_Y - (WALL_T if sy > 0 else 0), PLINTH_TOP),
                  (HALF_X, sy * HALF_Y + (0 if sy > 0 else WALL_T), EAVES))
    for sx in (-1, 1):
        x_in = sx * (HALF_X - WALL_T)
        brick.box((min(x_in, sx * HALF_X), -HALF_Y + WALL_T, PLINTH_TOP),
                  (max(x_in, sx * HALF_X), HALF_Y - WALL_T, EAVES))
    # Gable triangles above the end walls.
    for sx in (-1, 1):
        x0, x1 = sorted((sx * HALF_X, sx * (HALF_X - WALL_T)))
        tri = [(x0, -HALF_Y, EAVES), (x0, HALF_Y, EAVES), (x0, 0.0, RIDGE - 0.1),
               (x1, -HALF_Y, EAVES), (x1, HALF_Y, EAVES), (x1, 0.0, RIDGE - 0.1)]
        brick.add(tri, [(0, 2, 1), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)])
    brick.object("walls", "brick")


def window_openings():
    """(x or y along the wall, which wall) of every window: 'front', 'back', 'left', 'right'."""
    return ([(x, "front") for x in WINDOWS_FRONT] + [(x, "back") for x in WINDOWS_BACK] +
            [(y, "left") for y in WINDOWS_SIDE] + [(y, "right") for y in WINDOWS_SIDE])


def window_boxes(along: float, wall: str, depth: float, inset: float, frame: float):
    """Frame bars (4 boxes) of one window, proud of the wall face by `depth`."""
    w, h, sill = WINDOW
    z0 = PLINTH_TOP + sill
    bars = [(-w / 2, z0, w / 2, z0 + frame), (-w / 2, z0 + h - frame, w / 2, z0 + h),
            (-w / 2, z0, -w / 2 + frame, z0 + h), (w / 2 - frame, z0, w / 2, z0 + h),
            (-frame / 4, z0, frame / 4, z0 + h)]  # mullion
    return [_on_wall(wall, along, a, b, za, zb, depth, inset) for a, za, b, zb in bars]


def _on_wall(wall: str, along: float, a: float, b: float, za: float, zb: float, depth: float, inset: float):
    """A box on a wall face: a..b along the wall, za..zb high, from `inset` outside the
    face to `depth` outside it."""
    if wall in ("front", "back"):
        sy = -1 if wall == "front" else 1
        y0, y1 = sorted((sy * (HALF_Y + inset), sy * (HALF_Y + depth)))
        return (along + a, y0, za), (along + b, y1, zb)
    sx = -1 if wall == "left" else 1
    x0, x1 = sorted((sx * (HALF_X + inset), sx * (HALF_X + depth)))
    return (x0, along + a, za), (x1, along + b, zb)


def windows() -> None:
    frames, glass, sills = MeshBuilder(), MeshBuilder(), MeshBuilder()
    w, h, sill = WINDOW
    for along, wall in window_openings():
        for lo, hi in window_boxes(along, wall, 0.04, -0.02, 0.06):
            frames.box(lo, hi)
        glass.box(*_on_wall(wall, along, -w / 2, w / 2, PLINTH_TOP + sill, PLINTH_TOP + sill + h, 0.02, 0.005))
        sills.box(*_on_wall(wall, along, -w / 2 - 0.05, w / 2 + 0.05, PLINTH_TOP + sill - 0.06,
                            PLINTH_TOP + sill, 0.08, -0.02))
    frames.object("window_frames", "painted_grey")
    glass.object("window_glass", "camera_glass")
    sills.object("window_sills", "concrete")


def door() -> None:
    y = -HALF_Y
    P.box("door_frame", (1.4, 0.06, 2.3), (0.0, y - 0.01, PLINTH_TOP + 1.15), "painted_grey")
    P.box("door_leaf", (1.2, 0.05, 2.15), (0.0, y - 0.03, PLINTH_TOP + 1.075), "painted_grey", bevel=0.005)
    P.box("door_handle", (0.14, 0.04, 0.03), (0.45, y - 0.075, PLINTH_TOP + 1.05), "galvanised_steel")
    P.box("door_canopy", (2.0, 0.4, 0.08), (0.0, y - 0.2, PLINTH_TOP + 2.6), "roof_metal")
    P.box("entrance_step", (2.0, 0.4, PLINTH_TOP), (0.0, y - 0.2, PLINTH_TOP / 2), "concrete")


def roof() -> None:
    """Two corrugated sheets from the eaves to the ridge: one rib profile, extruded up the
    slope, arrayed along X and given thickness by a Solidify modifier."""
    run = HALF_Y + OVERHANG
    slope = math.atan2(RIDGE - EAVES, HALF_Y)
    length = run / math.cos(slope)
    z_eave = RIDGE - run * math.tan(slope)
    rib = [(0.0, 0.0), (0.05, 0.0), (0.08, 0.035), (0.12, 0.035), (0.15, 0.0), (CORRUGATION, 0.0)]
    n = len(rib)
    x_end = HALF_X + OVERHANG
    # Sheet local frame: x across the roof, y up the slope from the eave, z out of it.
    # The back sheet is the front one turned half a turn about Z.
    for side, location, turn in (("front", (-x_end, -run, z_eave), 0.0),
                                 ("back", (x_end, run, z_eave), math.pi)):
        sheet = MeshBuilder()
        verts = [(x, y, z) for y in (0.0, length) for x, z in rib]
        sheet.add(verts, [(i, i + 1, n + i + 1, n + i) for i in range(n - 1)])
        ob = sheet.object(f"roof_{side}", "roof_metal")
        ob.location = location
        ob.rotation_euler = (slope, 0.0, turn)
        P.add_array(ob, int(round(2 * x_end / CORRUGATION)), (CORRUGATION, 0.0, 0.0))
        solid = ob.modifiers.new("thickness", "SOLIDIFY")
        solid.thickness = 0.01
    P.box("ridge_cap", (2 * x_end, 0.3, 0.05), (0.0, 0.0, RIDGE + 0.025), "roof_metal")


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    walls()
    windows()
    door()
    roof()
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "building",
                       "Single-storey control house: brick walls, windows, steel door, metal gable roof",
                       budgets=[0.01, 0.05, 0.2], collision="box",
                       triangle_budget=40000, mass_kg=150000.0)


if __name__ == "__main__":
    main()
