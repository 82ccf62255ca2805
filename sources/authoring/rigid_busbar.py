"""Author sources/assets/rigid_busbar: a 12 m aluminium tube busbar (ASSETS.md).

The tube (0.2 m diameter) lies along X, centred on the origin at z = 0: the floor plan's
INSERT z lifts it onto its supports. Two welded couplers and rounded end caps (corona
protection) make it 0.25 m across at the ends. One revolved profile, Screw modifier.

    .venv/bin/python sources/authoring/rigid_busbar.py [--out DIR]
"""

from __future__ import annotations

import math

import kit
import _parts as P

ASSET_ID = "rigid_busbar"
HALF_LENGTH = 6.0
TUBE_R = 0.1
CAP_R = 0.125
COUPLER_AT = (-2.0, 2.0)     # positions of the welded couplers along the tube
COUPLER = 0.108, 0.15        # radius, length
SEGMENTS = 64
# taps on the tube's top every metre (the ends rest on supports, whose clamps are the
# terminals there): at_m5 .. at_0 .. at_p5
TERMINALS = [(f"at_{'m' if k < 0 else 'p' if k > 0 else ''}{abs(k)}", (float(k), 0.0, TUBE_R)) for k in range(-5, 6)]


def end_cap(sign: float):
    """(r, x) points of a rounded corona cap at the end x = sign * HALF_LENGTH, from the
    tube outwards to the axis (ordered by increasing x)."""
    quarter = [(CAP_R * math.cos(a), HALF_LENGTH - 0.08 + 0.08 * math.sin(a))
               for a in (math.pi / 2 * k / 6 for k in range(7))]
    body = [(TUBE_R, HALF_LENGTH - 0.2), (CAP_R, HALF_LENGTH - 0.14), (CAP_R, HALF_LENGTH - 0.08)]
    pts = body + quarter[1:] + [(0.0, HALF_LENGTH)]
    if sign > 0:
        return pts
    return [(r, -x) for r, x in reversed(pts)]


def profile():
    """Bottom-to-top (along the revolve axis) profile, closed on the axis at both ends."""
    pts = end_cap(-1.0)
    for x in COUPLER_AT:
        r, half = COUPLER[0], COUPLER[1] / 2
        pts += [(TUBE_R, x - half - 0.01), (r, x - half), (r, x + half), (TUBE_R, x + half + 0.01)]
    return pts + end_cap(1.0)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    # Revolved about local Z, turned so local Z is the model X axis.
    P.revolve("busbar_tube", profile(), "aluminium", SEGMENTS, (0.0, 0.0, 0.0), (0.0, math.pi / 2, 0.0))
    P.finish(ASSET_ID, out, terminals=TERMINALS)
    P.write_asset_toml(out, ASSET_ID, "busbar",
                       "Rigid aluminium tube busbar, 12 m along X, 0.2 m diameter, centred at z = 0",
                       budgets=[0.002, 0.01, 0.04], collision="box",
                       triangle_budget=20000, mass_kg=75.0)


if __name__ == "__main__":
    main()
