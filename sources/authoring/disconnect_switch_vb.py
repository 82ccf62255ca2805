"""Author sources/assets/disconnect_switch_vb: a vertical-break disconnector, one pole.

A steel support carries a fixed post insulator (with the jaw contact) at -X and an
operating column at +X. The operating column turns a little about Z (its crank drives
the blade); the blade is hinged on top of the operating column and swings up about the
hinge's local Y axis. So the blade's joint is a child of the operating column's link:
a chain of two joints, unlike the centre-break switch's two parallel ones.

    .venv/bin/python sources/authoring/disconnect_switch_vb.py [--out DIR]
"""

from __future__ import annotations

import kit
import _parts as P

ASSET_ID = "disconnect_switch_vb"
COLUMN_X = 2.0
BEAM_TOP = 2.6
COLUMN_BASE = BEAM_TOP + 0.2
COLUMN_HEIGHT = 2.4
HINGE_Z = COLUMN_BASE + COLUMN_HEIGHT + 0.3


def support():
    """The root link: legs, beam and the fixed column with its jaw contact."""
    beam = P.box("base_beam", (5.0, 0.3, 0.3), (0.0, 0.0, BEAM_TOP - 0.15), "galvanised_steel", bevel=0.01)
    for i, x in enumerate((-COLUMN_X, COLUMN_X), start=1):
        P.box(f"leg_{i}", (0.25, 0.25, BEAM_TOP - 0.3), (x, 0.0, (BEAM_TOP - 0.3) / 2), "galvanised_steel")
        P.box(f"leg_{i}_footplate", (0.5, 0.5, 0.03), (x, 0.0, 0.015), "galvanised_steel")
    P.box("mechanism_box", (0.4, 0.3, 0.5), (COLUMN_X, -0.35, 1.2), "painted_grey", bevel=0.015)
    x = -COLUMN_X
    P.flange("fixed_column_base_flange", (x, 0.0, COLUMN_BASE - 0.1), 0.15, 0.2)
    P.insulator("fixed_column_insulator", (x, 0.0, COLUMN_BASE), COLUMN_HEIGHT, 0.08, 0.18, "porcelain_grey",
                pitch=0.07, segments=96)
    P.flange("fixed_column_cap", (x, 0.0, COLUMN_BASE + COLUMN_HEIGHT + 0.02), 0.15, 0.04)
    P.box("fixed_contact_jaw", (0.25, 0.2, 0.28), (x, 0.0, HINGE_Z - 0.1), "copper", bevel=0.015)
    P.cylinder("fixed_contact_shield", 0.12, 0.03, (x, 0.0, HINGE_Z + 0.1), "aluminium", "Z", 32)
    return beam


def operating_column(beam):
    """The operating column on a small-range revolute joint about Z, with its crank."""
    x = COLUMN_X
    joint = kit.joint_empty("joint_operating_column", "revolute", (x, 0.0, BEAM_TOP), axis=(0.0, 0.0, 1.0),
                            lower=-0.35, upper=0.0, effort=600.0, velocity=0.4)
    kit.set_parent_keep(joint, beam)
    head = P.box("operating_column_head", (0.3, 0.24, 0.2), (x, 0.0, HINGE_Z - 0.18), "galvanised_steel",
                 bevel=0.015)
    parts = [
        P.cylinder("operating_column_bearing", 0.17, 0.2, (x, 0.0, BEAM_TOP + 0.1), "galvanised_steel", "Z", 48),
        P.box("operating_column_crank", (0.06, 0.45, 0.05), (x, -0.25, BEAM_TOP + 0.08), "galvanised_steel"),
        P.insulator("operating_column_insulator", (x, 0.0, COLUMN_BASE), COLUMN_HEIGHT, 0.08, 0.18,
                    "porcelain_grey", pitch=0.07, segments=96),
        P.flange("operating_column_cap", (x, 0.0, COLUMN_BASE + COLUMN_HEIGHT + 0.02), 0.15, 0.04),
        head,
    ]
    P.parent_keep(parts, joint)
    return head


def blade(head):
    """The blade on a hinge at the top of the operating column (revolute about local Y):
    it lies along -X towards the fixed jaw and opens upwards for positive angles."""
    x = COLUMN_X
    hinge = kit.joint_empty("joint_blade", "revolute", (x, 0.0, HINGE_Z), axis=(0.0, 1.0, 0.0),
                            lower=0.0, upper=1.6, effort=400.0, velocity=0.8)
    kit.set_parent_keep(hinge, head)
    length = 2 * COLUMN_X + 0.05
    parts = [
        P.prism_x("blade_tube", 0.055, -length, 0.0, "aluminium", (x, 0.0, HINGE_Z), segments=32),
        P.cylinder("blade_hinge_pin", 0.04, 0.3, (x, 0.0, HINGE_Z), "galvanised_steel", "Y", 24),
        P.box("blade_counterweight", (0.35, 0.16, 0.16), (x + 0.3, 0.0, HINGE_Z), "galvanised_steel", bevel=0.02),
        P.box("blade_contact", (0.22, 0.1, 0.08), (x - length + 0.1, 0.0, HINGE_Z), "copper", bevel=0.01),
    ]
    P.parent_keep(parts, hinge)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    beam = support()
    head = operating_column(beam)
    blade(head)
    P.finish(ASSET_ID, out, terminals=[("a", (-COLUMN_X, 0.0, COLUMN_BASE + COLUMN_HEIGHT + 0.1)),
                                       ("b", (COLUMN_X, 0.0, HINGE_Z + 0.05))])
    P.write_asset_toml(out, ASSET_ID, "switchgear",
                       "vertical-break disconnector, one pole, blade hinged on the operating column",
                       budgets=(0.003, 0.015, 0.06), triangle_budget=100000, mass_kg=600.0)


if __name__ == "__main__":
    main()
