"""Author sources/assets/junction_box/junction_box.stl: a marshalling kiosk exported the
way CAD packages export STL (ASSETS.md): metres, Z up, front (door) facing -Y.

The kiosk is a set of boxes and faceted cylinders. Each triangle carries its own three
corners (nothing is welded, so every shared corner appears several times) and touching
parts are separate shells. Three zero-area slivers sit on edges of the cabinet, as a
tessellator leaves them: three distinct but collinear corners, never a repeated index.
The cleaning stage of the pipeline must weld the duplicates and drop the slivers.

Written with numpy as binary STL with a fixed header, so reruns give the same bytes.

    .venv/bin/python sources/authoring/junction_box.py [--out DIR]
"""

from __future__ import annotations

import math

import numpy as np

from surge_arrester import parse_out, write_asset_toml

ASSET_ID = "junction_box"
STL_HEADER = b"substation-twin junction_box, metres, Z up"

# Cabinet body extents (metres); everything else is placed relative to it.
BODY_MIN = np.array([-0.40, -0.25, 0.25])
BODY_MAX = np.array([0.40, 0.25, 1.45])
GLAND_SEGMENTS = 48
HINGE_SEGMENTS = 16


def box(lo, hi) -> np.ndarray:
    """(12, 3, 3) float64: triangles of the box [lo, hi], counter-clockwise from outside."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corner = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    pts = lo + corner * (hi - lo)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return np.array([pts[[a, b, c]] for a, b, c, d in quads] +
                    [pts[[a, c, d]] for a, b, c, d in quads])


def cylinder_z(center_xy, z0: float, z1: float, radius: float, segments: int) -> np.ndarray:
    """(4 * segments, 3, 3) float64: a closed faceted cylinder along +Z."""
    a = 2.0 * math.pi * np.arange(segments) / segments
    ring = np.stack([center_xy[0] + radius * np.cos(a), center_xy[1] + radius * np.sin(a)], axis=1)
    nxt = np.roll(ring, -1, axis=0)
    bottom = np.column_stack([ring, np.full(segments, z0)])
    bottom_n = np.column_stack([nxt, np.full(segments, z0)])
    top, top_n = bottom.copy(), bottom_n.copy()
    top[:, 2] = top_n[:, 2] = z1
    c0 = np.broadcast_to([center_xy[0], center_xy[1], z0], (segments, 3))
    c1 = np.broadcast_to([center_xy[0], center_xy[1], z1], (segments, 3))
    side_a = np.stack([bottom, bottom_n, top_n], axis=1)
    side_b = np.stack([bottom, top_n, top], axis=1)
    cap_bottom = np.stack([c0, bottom_n, bottom], axis=1)
    cap_top = np.stack([c1, top, top_n], axis=1)
    return np.concatenate([side_a, side_b, cap_bottom, cap_top])


def cylinder_minus_y(x: float, z: float, y_start: float, length: float, radius: float,
                     segments: int) -> np.ndarray:
    """A closed faceted cylinder from y_start towards -Y (made along +Z, then turned by
    +90 degrees about X: a rotation, so winding and outward orientation are kept)."""
    tris = cylinder_z((0.0, 0.0), 0.0, length, radius, segments)
    turned = np.stack([tris[..., 0], -tris[..., 2], tris[..., 1]], axis=-1)
    return turned + (x, y_start, z)


def plinth_and_glands() -> list[np.ndarray]:
    """Four legs, the gland plate under the body and two rows of cable glands."""
    parts = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * 0.35, sy * 0.20
            parts.append(box((x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, BODY_MIN[2])))
    parts.append(box((-0.38, -0.23, BODY_MIN[2] - 0.01), (0.38, 0.23, BODY_MIN[2])))
    for row_y in (-0.08, 0.08):
        for k in range(6):
            x = -0.25 + 0.1 * k
            parts.append(cylinder_z((x, row_y), 0.15, BODY_MIN[2] - 0.01, 0.02, GLAND_SEGMENTS))
            parts.append(cylinder_z((x, row_y), 0.20, 0.225, 0.027, 6))  # hexagon nut
    return parts


def roof() -> list[np.ndarray]:
    """Overhanging roof plate, rain hood and two lifting eyes up to 1.6 m."""
    top = BODY_MAX[2]
    return [
        box((-0.45, -0.30, top), (0.45, 0.30, top + 0.05)),
        box((-0.43, -0.28, top + 0.05), (0.43, 0.28, top + 0.11)),
        box((-0.30, -0.02, top + 0.11), (-0.26, 0.02, 1.60)),
        box((0.26, -0.02, top + 0.11), (0.30, 0.02, 1.60)),
    ]


def door() -> list[np.ndarray]:
    """Door leaf on the -Y face with handle, lock barrel, nameplate and three hinges."""
    y_face = BODY_MIN[1]
    parts = [
        box((-0.36, y_face - 0.015, 0.30), (0.36, y_face, 1.40)),
        box((0.28, y_face - 0.05, 0.80), (0.30, y_face - 0.015, 0.95)),
        box((-0.10, y_face - 0.018, 1.22), (0.10, y_face - 0.015, 1.30)),
    ]
    parts.append(cylinder_minus_y(0.29, 1.00, y_face - 0.015, 0.02, 0.012, HINGE_SEGMENTS))
    for z in (0.40, 0.85, 1.30):
        parts.append(cylinder_z((-0.375, y_face - 0.012), z - 0.04, z + 0.04, 0.012, HINGE_SEGMENTS))
    return parts


def louvres() -> list[np.ndarray]:
    """Eight ventilation slats on each end (X) face."""
    parts = []
    for side in (-1, 1):
        x_face = BODY_MAX[0] if side > 0 else BODY_MIN[0]
        x_out = x_face + side * 0.02
        for k in range(8):
            z = 0.9 + 0.05 * k
            parts.append(box((min(x_face, x_out), -0.15, z), (max(x_face, x_out), 0.15, z + 0.012)))
    return parts


def slivers() -> np.ndarray:
    """(3, 3, 3) float64: zero-area triangles along three cabinet edges; each has three
    distinct collinear corners (its middle one at a third of the edge, where no other
    corner lies)."""
    lo, hi = BODY_MIN, BODY_MAX
    edges = [
        ((lo[0], lo[1], hi[2]), (hi[0], lo[1], hi[2])),   # top front edge
        ((hi[0], lo[1], lo[2]), (hi[0], lo[1], hi[2])),   # front right upright
        ((lo[0], hi[1], lo[2]), (hi[0], hi[1], lo[2])),   # bottom back edge
    ]
    out = []
    for a, b in edges:
        a, b = np.array(a), np.array(b)
        out.append([a, a + (b - a) / 3.0, b])
    return np.array(out)


def kiosk_triangles() -> np.ndarray:
    """(m, 3, 3) float64: every triangle of the kiosk, slivers included, in a fixed order."""
    parts = [box(BODY_MIN, BODY_MAX)] + plinth_and_glands() + roof() + door() + louvres()
    return np.concatenate(parts + [slivers()])


def write_binary_stl(path, triangles: np.ndarray, header: bytes) -> None:
    """Binary STL: 80-byte header, count, then per facet normal, 3 corners, attribute 0.
    Zero-area facets get a zero normal, as exporters write them."""
    tris = np.asarray(triangles, np.float64)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 1e-12)
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
    data = np.zeros(len(tris), dtype=record)
    data["normal"] = n
    data["corners"] = tris
    with open(path, "wb") as f:
        f.write(header.ljust(80, b" ")[:80])
        f.write(np.uint32(len(tris)).tobytes())
        f.write(data.tobytes())


def main() -> None:
    out = parse_out()
    folder = out / ASSET_ID
    folder.mkdir(parents=True, exist_ok=True)
    write_binary_stl(folder / f"{ASSET_ID}.stl", kiosk_triangles(), STL_HEADER)
    write_asset_toml(folder, {
        "category": "junction_box",
        "description": "Marshalling kiosk as exported STL: unwelded facets, three zero-area slivers",
        "source": f"{ASSET_ID}.stl",
        "units": "m",
        "up_axis": "Z",
        "triangle_budget": 20000,
        "mass_kg": 120.0,
    }, [0.002, 0.01, 0.04], "box")


if __name__ == "__main__":
    main()
