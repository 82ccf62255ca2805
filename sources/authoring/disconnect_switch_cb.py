"""Author sources/assets/disconnect_switch_cb: a centre-break disconnector, one pole.

A steel support (legs and beam, with authored collision boxes) carries two rotating
post-insulator columns 4.6 m apart. The beam tops out at 4 m: the sample strings this
pole at 500 kV, whose live parts stand 5.4 m clear of the ground (IEC 61936-1's H,
sources/clearances.toml), the blades' terminals at 6.8 m with the hot conductors' sag
below them. Each column turns on a revolute joint about Z and
carries half of the blade; the halves meet in the middle when closed. Blade half 2 is
blade half 1 mirrored with a negative X scale, as a modeller would build it.

    .venv/bin/python sources/authoring/disconnect_switch_cb.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P

ASSET_ID = "disconnect_switch_cb"
COLUMN_X = 2.3
BEAM_TOP = 4.0
COLUMN_BASE = BEAM_TOP + 0.2
COLUMN_HEIGHT = 2.3
BLADE_Z = COLUMN_BASE + COLUMN_HEIGHT + 0.22
LIMITS = {1: (0.0, 1.571), 2: (-1.571, 0.0)}


def support():
    """The root link: legs, beam, operating mechanism and two collision boxes."""
    beam = P.box("base_beam", (5.6, 0.3, 0.3), (0.0, 0.0, BEAM_TOP - 0.15), "galvanised_steel", bevel=0.01)
    for i, x in enumerate((-COLUMN_X, COLUMN_X), start=1):
        P.box(f"leg_{i}", (0.25, 0.25, BEAM_TOP - 0.3), (x, 0.0, (BEAM_TOP - 0.3) / 2), "galvanised_steel")
        P.box(f"leg_{i}_footplate", (0.5, 0.5, 0.03), (x, 0.0, 0.015), "galvanised_steel")
    P.box("mechanism_box", (0.4, 0.3, 0.5), (-COLUMN_X, -0.3, 1.2), "painted_grey", bevel=0.015)
    P.rod("operating_shaft", (-COLUMN_X, -0.3, 1.45), (-COLUMN_X, -0.3, BEAM_TOP - 0.3), 0.025, "galvanised_steel")
    P.rod("coupling_rod", (-COLUMN_X + 0.25, -0.25, BEAM_TOP + 0.08), (COLUMN_X - 0.25, -0.25, BEAM_TOP + 0.08),
          0.02, "galvanised_steel")
    P.collision_box("collision_beam", (5.6, 0.3, 0.3), (0.0, 0.0, BEAM_TOP - 0.15))
    P.collision_box("collision_legs", (0.25, 0.25, BEAM_TOP - 0.3), (-COLUMN_X, 0.0, (BEAM_TOP - 0.3) / 2),
                    count=2, offset=(2 * COLUMN_X, 0.0, 0.0))
    return beam


def column(i: int, x: float, beam):
    """Rotating column i on its joint: bearing, insulator, cap and crank lever."""
    lower, upper = LIMITS[i]
    joint = kit.joint_empty(f"joint_column_{i}", "revolute", (x, 0.0, BEAM_TOP), axis=(0.0, 0.0, 1.0),
                            lower=lower, upper=upper, effort=800.0, velocity=0.6)
    kit.set_parent_keep(joint, beam)
    parts = [
        P.cylinder(f"column_{i}_bearing", 0.16, 0.2, (x, 0.0, BEAM_TOP + 0.1), "galvanised_steel", "Z", 48),
        P.box(f"column_{i}_crank", (0.3, 0.06, 0.04), (x - 0.1 if i == 1 else x + 0.1, -0.2, BEAM_TOP + 0.08),
              "galvanised_steel"),
        P.flange(f"column_{i}_base_flange", (x, 0.0, COLUMN_BASE - 0.02), 0.14, 0.04),
        P.insulator(f"column_{i}_insulator", (x, 0.0, COLUMN_BASE), COLUMN_HEIGHT, 0.075, 0.17,
                    "porcelain_grey", pitch=0.075, segments=96),
        P.flange(f"column_{i}_cap", (x, 0.0, COLUMN_BASE + COLUMN_HEIGHT + 0.02), 0.14, 0.04),
        P.box(f"column_{i}_blade_clamp", (0.2, 0.14, 0.16), (x, 0.0, BLADE_Z - 0.05), "aluminium", bevel=0.01),
    ]
    P.parent_keep(parts, joint)
    return joint


def blade_half(name: str, location, scale_x: float):
    """Half a blade (tube and contact) built along local +X from the column axis;
    scale_x = -1 mirrors it to point -X (a negative scale, on purpose)."""
    length = COLUMN_X - 0.04
    scale = (scale_x, 1.0, 1.0)
    tube = P.prism_x(f"{name}_tube", 0.05, 0.0, length, "aluminium", location, scale, 32)
    contact_verts = P.box_verts((0.18, 0.09, 0.07), (length - 0.06, 0.0, 0.0))
    contact = P.mesh(f"{name}_contact", contact_verts, P.BOX_FACES, "copper", location, (0, 0, 0), scale)
    horn_verts = P.box_verts((0.02, 0.02, 0.35), (length - 0.25, 0.07, 0.17))
    horn = P.mesh(f"{name}_arcing_horn", horn_verts, P.BOX_FACES, "copper", location, (0, 0, 0), scale)
    return [tube, contact, horn]


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    beam = support()
    for i, (x, sign) in enumerate(((-COLUMN_X, 1.0), (COLUMN_X, -1.0)), start=1):
        joint = column(i, x, beam)
        P.parent_keep(blade_half(f"blade_{i}", (x, 0.0, BLADE_Z), sign), joint)
    P.finish(ASSET_ID, out,
             terminals=[(name, (sign * COLUMN_X, 0.0, BLADE_Z + 0.08)) for name, sign in (("a", -1), ("b", 1))])
    P.write_asset_toml(out, ASSET_ID, "switchgear",
                       "centre-break disconnector, one pole, two rotating post-insulator columns",
                       budgets=(0.003, 0.015, 0.06), collision="hull_per_link",
                       triangle_budget=100000, mass_kg=650.0)


if __name__ == "__main__":
    main()
