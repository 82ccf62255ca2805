"""Hand-made IR fixtures shared by the writer tests (SDF/COLLADA, USD, glTF).

`articulated_asset()` is small but exercises what writers get wrong: joint axes that
are not along Z, poses with rotations (one exactly at pitch = 90 degrees, one just
below it), a metallic and an emissive translucent material, a mesh with explicit
normals and UVs and one without, a shape key, a rotate and a material state binding,
two LOD levels, and one collision mesh per link.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline import ir


def rpy_matrix(xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64 pose from a translation and SDF roll-pitch-yaw
    (fixed axes X, then Y, then Z: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx
    m[:3, 3] = xyz
    return m


def box_mesh(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0), attributes: bool = False) -> ir.Mesh:
    """A closed box, 12 triangles, counter-clockwise from outside.

    attributes=False: 8 shared corners, no normals/UVs (writers compute them).
    attributes=True: 24 vertices (4 per face) with flat normals and per-face UVs.
    """
    half = np.asarray(size, dtype=np.float64) / 2.0
    c = np.asarray(center, dtype=np.float64)
    if not attributes:
        corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=np.float64)
        faces = [
            [0, 2, 1], [1, 2, 3],  # -z
            [4, 5, 6], [5, 7, 6],  # +z
            [0, 1, 4], [1, 5, 4],  # -y
            [2, 6, 3], [3, 6, 7],  # +y
            [0, 4, 2], [2, 4, 6],  # -x
            [1, 3, 5], [3, 7, 5],  # +x
        ]
        return ir.Mesh(vertices=c + corners * half, faces=faces)
    verts, norms, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)
            base = len(verts)
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                verts.append(c + (n + su * u + sv * v) * half)
                norms.append(n)
                uvs.append(((su + 1) / 2, (sv + 1) / 2))
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return ir.Mesh(vertices=verts, faces=faces, normals=norms, uvs=uvs)


def box_arrays(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """box_mesh's corners and faces as plain arrays (float64, int64) for the functions
    that take arrays, not an ir.Mesh."""
    m = box_mesh(size, center)
    return np.array(m.vertices, dtype=np.float64), np.array(m.faces, dtype=np.int64)


def tetra_mesh(scale: float = 1.0, center=(0.0, 0.0, 0.0)) -> ir.Mesh:
    """A closed tetrahedron (4 triangles): the coarse LOD of a box."""
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64) * scale / 2
    faces = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]
    return ir.Mesh(vertices=np.asarray(center) + v, faces=faces)


def articulated_asset() -> ir.Asset:
    """base --(revolute `arm_joint`)--> arm --(revolute `gauge_joint`)--> gauge,
    base --(prismatic `slide_joint`)--> slider.

    Joint pivots equal their child link frames (as the IR authors them); axes are
    unit vectors in the pivot frame, none along Z.
    """
    steel = ir.Material("steel", base_color=(0.55, 0.56, 0.58, 1.0), metallic=0.9, roughness=0.35)
    lamp = ir.Material("lamp_glass", base_color=(0.9, 0.2, 0.1, 0.6), metallic=0.0, roughness=0.1,
                       emission=(1.0, 0.3, 0.05))

    base_pose = rpy_matrix((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    arm_pose = rpy_matrix((0.2, -0.1, 1.1), (0.3, math.pi / 2, -0.4))  # exact gimbal lock
    gauge_pose = rpy_matrix((0.25, 0.4, 1.6), (-0.7, math.pi / 2 - 1e-7, 0.9))  # just below it
    slider_pose = rpy_matrix((-0.5, 0.3, 0.25), (0.1, -0.2, 2.5))

    base = ir.Link(
        name="base",
        pose=base_pose,
        mass=120.0,
        visuals=(
            ir.Visual("body", "steel", (box_mesh((1.2, 0.8, 0.5), (0, 0, 0.25)), tetra_mesh(1.0, (0, 0, 0.25))),
                      pose=rpy_matrix((0.0, 0.0, 0.0), (0.0, 0.0, 0.1))),
        ),
        collisions=(ir.Collision("body_collision", box_mesh((1.2, 0.8, 0.5), (0, 0, 0.25))),),
    )
    arm = ir.Link(
        name="arm",
        pose=arm_pose,
        mass=8.5,
        visuals=(
            ir.Visual("arm_shell", "steel",
                      (box_mesh((0.1, 0.1, 0.6), (0, 0, 0.3), attributes=True), tetra_mesh(0.3, (0, 0, 0.3))),
                      pose=rpy_matrix((0.01, 0.02, 0.03), (0.2, -0.3, 0.4))),
        ),
        collisions=(ir.Collision("arm_collision", box_mesh((0.1, 0.1, 0.6), (0, 0, 0.3)),
                                 pose=rpy_matrix((0.0, 0.0, 0.01), (0.0, 0.0, 0.0))),),
    )
    needle_mesh = box_mesh((0.02, 0.12, 0.005), (0, 0.05, 0))
    oil_base = box_mesh((0.08, 0.08, 0.1), (0, 0, 0.05))
    oil_full = ir.ShapeKey("full", oil_base.vertices * np.array([1.0, 1.0, 1.8]))
    oil = ir.Mesh(oil_base.vertices, oil_base.faces, shape_keys=(oil_full,))
    gauge = ir.Link(
        name="gauge",
        pose=gauge_pose,
        mass=0.4,
        visuals=(
            ir.Visual("needle", "steel", (needle_mesh,), pose=rpy_matrix((0, 0, 0.01), (0, 0, 0))),
            ir.Visual("oil_level", "lamp_glass", (oil,), pose=rpy_matrix((0.0, -0.05, 0.0), (math.pi / 2, 0, 0))),
        ),
        collisions=(ir.Collision("gauge_collision", box_mesh((0.1, 0.12, 0.1), (0, 0, 0.05))),),
    )
    slider = ir.Link(
        name="slider",
        pose=slider_pose,
        mass=3.0,
        visuals=(
            ir.Visual("slider_block", "steel", (box_mesh((0.3, 0.2, 0.1)), tetra_mesh(0.25))),
        ),
        collisions=(ir.Collision("slider_collision", box_mesh((0.3, 0.2, 0.1))),),
    )
    joints = (
        ir.Joint("arm_joint", "revolute", "base", "arm", pose=arm_pose,
                 axis=np.array([1.0, 0.0, 0.0]), lower=-0.5, upper=1.25, effort=200.0, velocity=0.5),
        ir.Joint("gauge_joint", "revolute", "arm", "gauge", pose=gauge_pose,
                 axis=np.array([0.0, 0.6, 0.8]), lower=-math.pi, upper=math.pi, effort=1.0, velocity=3.0),
        ir.Joint("slide_joint", "prismatic", "base", "slider", pose=slider_pose,
                 axis=np.array([0.0, 1.0, 0.0]), lower=0.0, upper=0.4, effort=500.0, velocity=0.1),
    )
    bindings = (
        ir.StateBinding("oil_level", "rotate", "needle", domain=(0.0, 1.0), range=(-2.0, 2.0), axis=(0.0, 0.0, 1.0)),
        ir.StateBinding("oil_level", "shape", "oil_level", domain=(0.0, 1.0), range=(0.0, 1.0), shape_key="full"),
        ir.StateBinding("alarm", "material", "oil_level", domain=(0.0, 1.0),
                        materials=("steel", "lamp_glass"), thresholds=(0.5,)),
    )
    lods = (
        ir.LodInfo(level=0, budget_m=0.0, error_m=0.0, triangles=0),
        ir.LodInfo(level=1, budget_m=0.05, error_m=0.04, triangles=0),
    )
    asset = ir.Asset(
        id="test_arm",
        category="test",
        links=(base, arm, gauge, slider),
        joints=joints,
        materials=(lamp, steel),
        bindings=bindings,
        lods=(),
        description="Hand-made articulated fixture",
        source="tests/fixtures_assets.py",
    )
    # Triangle counts come from the meshes themselves so they never disagree.
    counted = tuple(ir.LodInfo(i.level, i.budget_m, i.error_m, asset.triangle_count(i.level)) for i in lods)
    return asset.with_(lods=counted)
