"""Author sources/assets/ptz_camera_mast: a 6 m mast with a pan-tilt camera head.

The pan joint turns the head about Z; the tilt joint, a child of the pan head, turns the
camera about its local X axis. The tilt Empty is turned half a turn about Z so that its
local X is the model's -X: positive tilt then raises the camera's view (it looks along
-Y at rest) and negative tilt lowers it, down to -1.5 rad.

    .venv/bin/python sources/authoring/ptz_camera_mast.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "ptz_camera_mast"
MAST_TOP = 5.95
TILT_Z = MAST_TOP + 0.38


def mast():
    """The root link: base plate, anchor bolts, gussets, tapered tube and top flange."""
    P.box("base_plate", (0.6, 0.6, 0.03), (0.0, 0.0, 0.015), "galvanised_steel", bevel=0.005)
    bolt = P.cylinder("anchor_bolts", 0.015, 0.09, (-0.24, -0.24, 0.06), "galvanised_steel", "Z", 12)
    P.add_array(bolt, 2, (0.48, 0.0, 0.0), "array_x")
    P.add_array(bolt, 2, (0.0, 0.48, 0.0), "array_y")
    for i, angle in enumerate((0.0, math.pi / 2, math.pi, 3 * math.pi / 2)):
        P.mesh(f"gusset_{i + 1}", P.box_verts((0.17, 0.012, 0.25), (0.175, 0.0, 0.155)),
                        P.BOX_FACES, "galvanised_steel", (0.0, 0.0, 0.0), (0.0, 0.0, angle))
    pole = P.revolve("mast_tube", mast_profile(), "galvanised_steel", 64)
    step = P.box("climbing_steps", (0.18, 0.024, 0.024), (0.16, 0.0, 1.2), "galvanised_steel", bevel=0.006)
    P.add_array(step, 10, (0.0, 0.0, 0.4))
    P.flange("mast_top_flange", (0.0, 0.0, MAST_TOP - 0.025), 0.12, 0.05)
    P.box("junction_box", (0.2, 0.12, 0.3), (0.0, -0.16, 1.4), "painted_grey", bevel=0.01)
    return pole


def mast_profile():
    """A tapered tube (0.2 m at the foot, 0.14 m at the top) with a welded collar every
    metre, closed on the axis at both ends."""
    top = MAST_TOP - 0.05
    pts = [(0.0, 0.03), (0.1, 0.03), (0.1, 0.5)]
    for k in range(1, 6):
        z = 0.5 + k * (top - 0.5) / 6
        r = 0.1 - 0.03 * (z - 0.5) / (top - 0.5)
        pts += [(r, z - 0.04), (r + 0.012, z - 0.03), (r + 0.012, z + 0.03), (r, z + 0.04)]
    return pts + [(0.07, top), (0.0, top)]


def pan_head(pole):
    joint = kit.joint_empty("joint_pan", "revolute", (0.0, 0.0, MAST_TOP), axis=(0.0, 0.0, 1.0),
                            lower=-3.0, upper=3.0, effort=30.0, velocity=1.5)
    kit.set_parent_keep(joint, pole)
    yoke = P.cylinder("pan_housing", 0.11, 0.16, (0.0, 0.0, MAST_TOP + 0.08), "painted_grey", "Z", 64)
    parts = [yoke, P.revolve("pan_housing_skirt", [(0.0, 0.0), (0.125, 0.0), (0.13, 0.02), (0.12, 0.04),
                                                   (0.0, 0.04)], "painted_grey", 64, (0.0, 0.0, MAST_TOP))]
    for i, x in enumerate((-0.16, 0.16), start=1):
        parts.append(P.box(f"pan_yoke_arm_{i}", (0.03, 0.1, 0.36), (x, 0.0, MAST_TOP + 0.3), "painted_grey",
                           bevel=0.008))
    parts.append(P.box("pan_yoke_bridge", (0.35, 0.1, 0.03), (0.0, 0.0, MAST_TOP + 0.17), "painted_grey"))
    P.parent_keep(parts, joint)
    return yoke


def camera(yoke):
    joint = kit.joint_empty("joint_tilt", "revolute", (0.0, 0.0, TILT_Z), axis=(1.0, 0.0, 0.0),
                            lower=-1.5, upper=0.6, effort=15.0, velocity=1.0, rotation=(0.0, 0.0, math.pi))
    kit.set_parent_keep(joint, yoke)
    body = P.box("camera_body", (0.2, 0.32, 0.16), (0.0, 0.0, TILT_Z), "painted_grey")
    P.add_bevel(body, 0.025, 6)
    parts = [
        body,
        P.box("camera_sunshield", (0.24, 0.4, 0.012), (0.0, -0.03, TILT_Z + 0.095), "painted_grey"),
        P.cylinder("camera_lens_ring", 0.055, 0.03, (0.0, -0.175, TILT_Z), "black_rubber", "Y", 32),
        P.cylinder("camera_lens", 0.045, 0.01, (0.0, -0.192, TILT_Z), "camera_glass", "Y", 32),
        P.cylinder("tilt_axle", 0.02, 0.3, (0.0, 0.0, TILT_Z), "galvanised_steel", "X", 16),
    ]
    for i, x in enumerate((-0.075, 0.045), start=1):
        leds = P.cylinder(f"ir_illuminator_{i}", 0.01, 0.01, (x, -0.165, TILT_Z - 0.055), "camera_glass", "Y", 16)
        P.add_array(leds, 2, (0.03, 0.0, 0.0), "array_x")
        P.add_array(leds, 2, (0.0, 0.03, 0.0), "array_z")  # local Y is the model's Z here
        parts.append(leds)
    P.parent_keep(parts, joint)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    pole = mast()
    yoke = pan_head(pole)
    camera(yoke)
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "sensor", "6 m mast with a pan-tilt RGB inspection camera",
                       budgets=(0.002, 0.01, 0.04), triangle_budget=20000, mass_kg=180.0)


if __name__ == "__main__":
    main()
