"""Author sources/assets/lightning_mast: a 25 m lattice steel mast with a spike.

The lattice is one mesh of angle-section members (legs, horizontals, X bracing on every
face) whose edges a Bevel modifier rounds at evaluation, so the file stays small. The
lattice helpers here are shared by gantry.py and busbar_support.py.

    .venv/bin/python sources/authoring/lightning_mast.py [--out DIR]
"""

from __future__ import annotations

import numpy as np

import kit
import _parts as P

ASSET_ID = "lightning_mast"

ANGLE_WIDTH = 0.07       # leg of an angle section (m)
ANGLE_THICKNESS = 0.008
BRACE_WIDTH = 0.045
BEVEL_WIDTH = 0.002


class MeshBuilder:
    """Vertices and faces of one mesh object, accumulated part by part."""

    def __init__(self):
        self.verts: list[tuple[float, float, float]] = []
        self.faces: list[tuple[int, ...]] = []

    def add(self, verts, faces) -> None:
        base = len(self.verts)
        self.verts += [tuple(float(c) for c in v) for v in verts]
        self.faces += [tuple(base + i for i in f) for f in faces]

    def box(self, lo, hi) -> None:
        """An axis-aligned box between corners `lo` and `hi`."""
        corners = [(x, y, z) for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
        self.add(corners, [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)])

    def angle(self, a, b, outward, width: float, thickness: float = ANGLE_THICKNESS) -> None:
        """An L-section steel angle from point a to b, its heel towards `outward`."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        d = (b - a) / np.linalg.norm(b - a)
        out = np.asarray(outward, float)
        out = out - d * (out @ d)
        if np.linalg.norm(out) < 1e-9:  # outward along the member: any perpendicular
            out = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        u = -out / np.linalg.norm(out)       # flanges point inwards from the heel
        v = np.cross(d, u)
        w, t = width, thickness
        outline = [(0, 0), (w, 0), (w, t), (t, t), (t, w), (0, w)]
        # Centre the section on the member line.
        shift = -0.5 * w * (u + v)
        ring = [shift + p * u + q * v for p, q in outline]
        verts = [a + r for r in ring] + [b + r for r in ring]
        n = len(outline)
        sides = [(i, (i + 1) % n, n + (i + 1) % n, n + i) for i in range(n)]
        caps = [(0, 3, 2, 1), (0, 5, 4, 3), (n, n + 1, n + 2, n + 3), (n, n + 3, n + 4, n + 5)]
        self.add(verts, sides + caps)

    def lattice(self, sections, leg_width: float = ANGLE_WIDTH, brace_width: float = BRACE_WIDTH) -> None:
        """A lattice prism through `sections`: each a (4, 3) ring of corner points in
        order around the axis. Legs join corresponding corners, each section gets a
        ring of horizontals, each face of each panel an X brace."""
        sections = [np.asarray(s, float) for s in sections]
        for i, ring in enumerate(sections):
            centre = ring.mean(axis=0)
            for k in range(4):
                p, q = ring[k], ring[(k + 1) % 4]
                self.angle(p, q, (p + q) / 2 - centre, brace_width)
            if i + 1 == len(sections):
                break
            nxt = sections[i + 1]
            axis_mid = (centre + nxt.mean(axis=0)) / 2
            for k in range(4):
                p0, q0, p1, q1 = ring[k], ring[(k + 1) % 4], nxt[k], nxt[(k + 1) % 4]
                self.angle(p0, p1, p0 - centre, leg_width)
                face_out = (p0 + q0 + p1 + q1) / 4 - axis_mid
                self.angle(p0, q1, face_out, brace_width)
                self.angle(q0, p1, face_out, brace_width)

    def object(self, name: str, mat: str, bevel: float = 0.0):
        ob = kit.mesh_object(name, self.verts, self.faces, mat)
        if bevel > 0.0:
            P.add_bevel(ob, bevel, 1)
        return ob


def rectangle(cx: float, cy: float, z: float, hx: float, hy: float):
    """Corners of a horizontal rectangle, counter-clockwise seen from above."""
    return [(cx - hx, cy - hy, z), (cx + hx, cy - hy, z), (cx + hx, cy + hy, z), (cx - hx, cy + hy, z)]


def tapered_stations(z0: float, z1: float, half0: float, half1: float, panels: int):
    """Square sections from half-width half0 at z0 to half1 at z1, `panels` panels."""
    return [rectangle(0.0, 0.0, z0 + (z1 - z0) * i / panels, h, h)
            for i, h in enumerate(np.linspace(half0, half1, panels + 1))]


def lattice_pedestal(lattice_top: float, base_half: float, top_half: float, panels: int, *, leg_width: float,
                     brace_width: float, foot_half: float, cap_side: float, cap_thickness: float, cap_z: float) -> None:
    """A tapered lattice pedestal standing on four base plates (`foot_half` their half
    side) under a square cap plate centred at `cap_z`: the objects pedestal_lattice,
    base_plates and cap_plate, galvanised steel."""
    frame = MeshBuilder()
    frame.lattice(tapered_stations(0.05, lattice_top, base_half, top_half, panels),
                  leg_width=leg_width, brace_width=brace_width)
    frame.object("pedestal_lattice", "galvanised_steel", BEVEL_WIDTH)
    feet = MeshBuilder()
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * base_half, sy * base_half
            feet.box((x - foot_half, y - foot_half, 0.0), (x + foot_half, y + foot_half, 0.05))
    feet.object("base_plates", "galvanised_steel")
    P.box("cap_plate", (cap_side, cap_side, cap_thickness), (0.0, 0.0, cap_z), "galvanised_steel")


MAST_TOP = 22.0
BASE_HALF = 0.68
TOP_HALF = 0.2


def build() -> None:
    frame = MeshBuilder()
    frame.lattice(tapered_stations(0.25, MAST_TOP, BASE_HALF, TOP_HALF, 28))
    frame.object("mast_lattice", "galvanised_steel", BEVEL_WIDTH)

    base = MeshBuilder()
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * BASE_HALF, sy * BASE_HALF
            base.box((x - 0.04, y - 0.04, 0.0), (x + 0.04, y + 0.04, 0.25))  # leg stub
            base.box((x - 0.12, y - 0.12, 0.0), (x + 0.12, y + 0.12, 0.02))  # base plate
    base.object("base_plates", "galvanised_steel")

    P.box("top_plate", (0.5, 0.5, 0.02), (0.0, 0.0, MAST_TOP + 0.01), "galvanised_steel")
    spike = [(0.0, MAST_TOP + 0.02), (0.05, MAST_TOP + 0.02), (0.04, MAST_TOP + 0.3),
             (0.025, 24.0), (0.008, 24.95), (0.0, 25.0)]
    P.revolve("spike", spike, "galvanised_steel", 24)


def main() -> None:
    out = kit.parse_out()
    kit.new_scene()
    build()
    P.finish(ASSET_ID, out)
    P.write_asset_toml(out, ASSET_ID, "lightning_mast",
                       "25 m lattice steel lightning mast with a spike",
                       budgets=[0.01, 0.05, 0.2], collision="hull_per_part",
                       triangle_budget=80000, mass_kg=2400.0)


if __name__ == "__main__":
    main()
