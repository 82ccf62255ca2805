"""Triangles of a .glb in its scene frame, for measuring a peer tool's output against
ours with the same metric (pipeline.geometry.metrics).

Only what the bench needs: the default scene's mesh nodes (children composed),
triangle primitives, float POSITION and integer indices with any byteStride.
`lod=k` takes each visual's k-th MSFT_lod node's mesh (our model files keep the
coarser levels out of the scene, under the visual's MSFT_lod list).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import glb


def _mesh_triangles(doc: dict, binary: bytes, mesh: int, matrix: np.ndarray):
    for prim in doc["meshes"][mesh]["primitives"]:
        if prim.get("mode", 4) != 4 or "POSITION" not in prim["attributes"]:
            continue
        pos = glb.accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
        if "indices" in prim:
            idx = glb.accessor(doc, binary, prim["indices"]).reshape(-1, 3).astype(np.int64)
        else:
            idx = np.arange(len(pos), dtype=np.int64).reshape(-1, 3)
        yield pos @ matrix[:3, :3].T + matrix[:3, 3], idx


def triangles(path: Path, lod: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """vertices (n, 3) float64 and faces (m, 3) int64 of every mesh node of the default
    scene, in the scene frame. Instancing extensions are ignored (model files only)."""
    doc, binary = glb.read(path)
    verts, faces, offset = [], [], 0
    scene = doc["scenes"][doc.get("scene", 0)]

    def walk(i: int, parent: np.ndarray):
        nonlocal offset
        node = doc["nodes"][i]
        m = parent @ glb.node_matrix(node)
        mesh = node.get("mesh")
        ids = node.get("extensions", {}).get("MSFT_lod", {}).get("ids", [])
        if lod > 0 and ids:
            mesh = doc["nodes"][ids[min(lod, len(ids)) - 1]].get("mesh", mesh)
        if mesh is not None:
            for v, f in _mesh_triangles(doc, binary, mesh, m):
                verts.append(v)
                faces.append(f + offset)
                offset += len(v)
        for c in node.get("children", []):
            walk(c, m)

    for root in scene.get("nodes", []):
        walk(root, np.eye(4))
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def lod_count(path: Path) -> int:
    """1 + the longest MSFT_lod list of the file's nodes."""
    doc, _ = glb.read(path)
    return 1 + max((len(n.get("extensions", {}).get("MSFT_lod", {}).get("ids", [])) for n in doc["nodes"]), default=0)
