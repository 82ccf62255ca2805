"""The Gazebo world's static collisions, merged into a few mesh shapes.

A physics engine pays for every shape at every step (dartsim, with bullet's
broadphase, updates each one), and sdformat about 170 kB for every <collision> it
parses (tools/gzprobe): a site of thousands of placements each colliding on its own
neither steps in real time nor parses within its budget. So the collisions of every
grouped placement (world_sdf: none of them moves) are merged, per square cell of
CELL_M of the ground, into one mesh, written beside the world as
`collision/e<i>_n<j>.dae` (i, j: the cell's index east and north; a relative URI,
which gz-sim resolves against the world file) and drawn by one model of one link,
`collision_cells`, one <collision> `e<i>_n<j>` a cell, posed at the cell's corner.

What each placement adds, in the same place as its own collision would be (its
frame's pose, its scale): near ones (LOD 0, the few around the inspection points
where a robot works) every triangle of their package's collision meshes
(names.WHOLE_COLLISION_FILE); the others the box of each part of them (a
vertex-connected piece: a post, a tank, a fence panel), the footprint and height a
robot or a drone keeps clear of, at 12 triangles a part whatever the part's own
count. Placements that repeat one another exactly (devices piled on one insertion
point) add theirs once. A package without the collision file keeps its own
collision elements in its grouped model (world_sdf).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree

from ..export.names import WHOLE_COLLISION_FILE, fmt
from ..geometry.transform import xyz_rpy_to_matrix
from .placements import Placed

CELL_M = 100.0
FOLDER = "collision"
MODEL_NAME = "collision_cells"
LINK_NAME = "cells"
_DIGITS = 4  # 0.1 mm: what a collision needs, in a cell's frame (coordinates < CELL_M)
_COLLADA = "http://www.collada.org/2005/11/COLLADASchema"


def placement_key(pl: Placed) -> tuple:
    """What makes two placements draw and collide as one: the same asset, scale and
    LOD at the same pose (to 1 um and 1 nrad)."""
    return (pl.placement.asset_id, pl.placement.scale, pl.lod,
            *np.round(pl.pose[:3, 3], 6).tolist(), round(pl.yaw, 9))


class CollisionCells:
    """The merged collisions of one world: add() each placement, then write()."""

    def __init__(self, models: Path):
        self.models = Path(models)
        self._cells: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
        self._seen: set[tuple] = set()
        self._parts: dict[tuple[str, bool], tuple[np.ndarray, np.ndarray] | None] = {}

    def add(self, pl: Placed) -> bool:
        """Put the placement's collision in its cell. False when its package has no
        whole collision mesh (the caller keeps the placement's own collisions)."""
        asset, exact = pl.placement.asset_id, pl.lod == 0
        if (asset, exact) not in self._parts:
            self._parts[asset, exact] = _collision_parts(self.models / asset / WHOLE_COLLISION_FILE, exact)
        parts = self._parts[asset, exact]
        if parts is None:
            return False
        key = placement_key(pl)
        if key in self._seen:
            return True
        self._seen.add(key)
        x, y, z = pl.pose[:3, 3]
        world = xyz_rpy_to_matrix((x, y, z), (0.0, 0.0, pl.yaw))
        world[:3, :3] *= pl.placement.scale
        cell = (int(np.floor(x / CELL_M)), int(np.floor(y / CELL_M)))
        vertices, faces = parts
        self._cells.setdefault(cell, []).append((vertices @ world[:3, :3].T + world[:3, 3], faces))
        return True

    def write_meshes(self, folder: Path) -> None:
        """Each cell's mesh into folder/FOLDER, its earlier .dae files removed."""
        out = Path(folder) / FOLDER
        if out.is_dir():
            for old in out.glob("*.dae"):
                old.unlink()
        if not self._cells:
            return
        out.mkdir(parents=True, exist_ok=True)
        for (i, j), pieces in sorted(self._cells.items()):
            name, corner = _cell_name(i, j), _cell_corner(i, j)
            offsets = np.cumsum([0] + [len(v) for v, _ in pieces[:-1]])
            vertices = np.concatenate([v for v, _ in pieces]) - corner
            faces = np.concatenate([f + k for (_, f), k in zip(pieces, offsets)])
            vertices, faces = weld(vertices, faces)
            (out / f"{name}.dae").write_bytes(collada_bytes(name, vertices, faces))

    def model(self) -> etree._Element | None:
        """The static model whose collisions are the cells' meshes (FOLDER/<cell>.dae,
        write_meshes); None when no placement collides."""
        if not self._cells:
            return None
        model = etree.Element("model", name=MODEL_NAME)
        etree.SubElement(model, "static").text = "true"
        link = etree.SubElement(model, "link", name=LINK_NAME)
        for i, j in sorted(self._cells):
            name = _cell_name(i, j)
            collision = etree.SubElement(link, "collision", name=name)
            etree.SubElement(collision, "pose").text = " ".join(fmt(v) for v in (*_cell_corner(i, j).tolist(), 0.0, 0.0, 0.0))
            uri = etree.SubElement(etree.SubElement(etree.SubElement(collision, "geometry"), "mesh"), "uri")
            uri.text = f"{FOLDER}/{name}.dae"
        return model


def _cell_name(i: int, j: int) -> str:
    return f"e{i}_n{j}"


def _cell_corner(i: int, j: int) -> np.ndarray:
    return np.array([i * CELL_M, j * CELL_M, 0.0])


def _collision_parts(path: Path, exact: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices (n, 3) float64, faces (m, 3) int64) in the model frame of a package's
    whole collision mesh: every triangle (exact) or each part's box (part_box). None
    when the file is not there."""
    if not path.is_file():
        return None
    vertices, faces = read_collada_triangles(path)
    if exact or len(faces) == 0:
        return vertices, faces
    from ..geometry.collision import connected_parts

    boxes = [part_box(vertices[idx]) for idx in connected_parts(faces, len(vertices))]
    offsets = np.cumsum([0] + [len(v) for v, _ in boxes[:-1]])
    return (np.concatenate([v for v, _ in boxes]),
            np.concatenate([f + k for (_, f), k in zip(boxes, offsets)]))


def part_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The smaller of two boxes around `points: (n, 3)`: along the model's axes (a
    post, a tank, a panel) or along the points' principal axes (a diagonal brace).
    Returns vertices (8, 3) and outward faces (12, 3); each side at least 1 mm."""
    from ..geometry.collision import box_hull

    pts = np.asarray(points, dtype=np.float64)
    centre = pts.mean(axis=0)
    _, axes = np.linalg.eigh(np.cov((pts - centre).T) if len(pts) > 1 else np.eye(3))
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]  # a rotation, so the faces stay outward
    best = None
    for frame in (np.eye(3), axes):
        v, f = box_hull((pts - centre) @ frame, pad=1e-3)
        volume = float(np.prod(v.max(axis=0) - v.min(axis=0)))
        if best is None or volume < best[0]:
            best = (volume, v @ frame.T + centre, f)
    return best[1], best[2]


def read_collada_triangles(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle of a COLLADA file (its node transforms applied, in metres) as
    one indexed mesh: vertices (n, 3) float64, faces (m, 3) int64."""
    import collada

    doc = collada.Collada(str(path))
    vertices, faces, count = [], [], 0
    for geometry in doc.scene.objects("geometry"):
        for prim in geometry.primitives():
            if not isinstance(prim, collada.triangleset.BoundTriangleSet):
                continue
            v = np.asarray(prim.vertex, dtype=np.float64)
            vertices.append(v)
            faces.append(np.asarray(prim.vertex_index, dtype=np.int64).reshape(-1, 3) + count)
            count += len(v)
    if not vertices:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    unit = doc.assetInfo.unitmeter or 1.0
    return np.concatenate(vertices) * unit, np.concatenate(faces)


WELD_M = 1e-4  # 0.1 mm: Gazebo reads positions as float32 (ulp 7.6 um at 100 m, a cell's width) and merges equal ones


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One vertex for each group of positions within WELD_M of each other, the faces
    renumbered, degenerate faces dropped. Piled devices' boxes share corners, and
    Gazebo's loader merges corners it reads as equal, keeping one of their normals: a
    cell must hold them as one already for Gazebo to read the normals the file has."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(vertices)
    pairs = cKDTree(vertices).query_pairs(WELD_M, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = connected_components(graph, directed=False)
    _, first, inverse = np.unique(group, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return vertices[first], faces[keep]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals: each vertex's faces' area-weighted normals summed (up
    where they cancel or it has none)."""
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    face = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = np.zeros_like(v)
    for corner in range(3):
        np.add.at(out, f[:, corner], face)
    length = np.linalg.norm(out, axis=1)
    out[length <= 1e-12] = (0.0, 0.0, 1.0)
    length[length <= 1e-12] = 1.0
    return out / length[:, None]


def collada_bytes(name: str, vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A COLLADA 1.4.1 document of one triangle mesh (positions and vertex normals,
    metres, Z up)."""
    def sub(parent, tag, text=None, **attrib):
        el = etree.SubElement(parent, f"{{{_COLLADA}}}{tag}", {k: str(v) for k, v in attrib.items()})
        if text is not None:
            el.text = text
        return el

    root = etree.Element(f"{{{_COLLADA}}}COLLADA", nsmap={None: _COLLADA}, version="1.4.1")
    asset = sub(root, "asset")
    sub(sub(asset, "contributor"), "authoring_tool", "substation-twin")
    sub(asset, "created", "2000-01-01T00:00:00")
    sub(asset, "modified", "2000-01-01T00:00:00")
    sub(asset, "unit", name="meter", meter="1")
    sub(asset, "up_axis", "Z_UP")
    mesh = sub(sub(sub(root, "library_geometries"), "geometry", id=f"{name}-mesh", name=name), "mesh")
    source = sub(mesh, "source", id=f"{name}-positions")
    numbers = np.round(vertices, _DIGITS).ravel().tolist()
    sub(source, "float_array", " ".join(map(repr, numbers)), id=f"{name}-positions-array", count=len(numbers))
    accessor = sub(sub(source, "technique_common"), "accessor", source=f"#{name}-positions-array",
                   count=len(vertices), stride=3)
    for axis in "XYZ":
        sub(accessor, "param", name=axis, type="float")
    # dartsim ignores a submesh without a normal at each vertex (CustomMeshShape)
    normal_source = sub(mesh, "source", id=f"{name}-normals")
    normals = np.round(vertex_normals(vertices, faces), 3).ravel().tolist()
    sub(normal_source, "float_array", " ".join(map(repr, normals)), id=f"{name}-normals-array", count=len(normals))
    accessor = sub(sub(normal_source, "technique_common"), "accessor", source=f"#{name}-normals-array",
                   count=len(vertices), stride=3)
    for axis in "XYZ":
        sub(accessor, "param", name=axis, type="float")
    inputs = sub(mesh, "vertices", id=f"{name}-vertices")
    sub(inputs, "input", semantic="POSITION", source=f"#{name}-positions")
    sub(inputs, "input", semantic="NORMAL", source=f"#{name}-normals")
    triangles = sub(mesh, "triangles", count=len(faces))
    sub(triangles, "input", semantic="VERTEX", source=f"#{name}-vertices", offset=0)
    sub(triangles, "p", " ".join(map(str, np.asarray(faces).ravel().tolist())))
    scene = sub(sub(root, "library_visual_scenes"), "visual_scene", id="Scene")
    node = sub(scene, "node", id=name, name=name)
    sub(node, "instance_geometry", url=f"#{name}-mesh")
    sub(sub(root, "scene"), "instance_visual_scene", url="#Scene")
    return etree.tostring(root, xml_declaration=True, encoding="utf-8")
