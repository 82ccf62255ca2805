"""Several visuals of one link as one mesh in the link frame (a coarse LOD variant draws
each material of a link once: one visual for sdformat and the renderer, not dozens)."""

from __future__ import annotations

import numpy as np

from .. import ir
from .metrics import stored_normals


def merge_meshes(parts: list[tuple[np.ndarray, ir.Mesh]]) -> ir.Mesh:
    """parts: (pose (4, 4) of the mesh in the target frame, mesh) -> one mesh in the
    target frame. Normals are each part's own (or computed, as the writers do) turned
    with its pose; UVs are kept when every part has them. Shape keys are not merged:
    a visual with shape keys is never a part."""
    vertices, faces, normals, uvs = [], [], [], []
    offset = 0
    for pose, mesh in parts:
        rotation, translation = pose[:3, :3], pose[:3, 3]
        vertices.append(mesh.vertices @ rotation.T + translation)
        turned = stored_normals(mesh.vertices, mesh.faces, mesh.normals) @ np.linalg.inv(rotation)
        normals.append(turned / np.maximum(np.linalg.norm(turned, axis=1, keepdims=True), 1e-300))
        uvs.append(mesh.uvs)
        faces.append(mesh.faces.astype(np.int64) + offset)
        offset += len(mesh.vertices)
    return ir.Mesh(
        vertices=np.concatenate(vertices) if vertices else np.zeros((0, 3)),
        faces=np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64),
        normals=np.concatenate(normals) if normals else None,
        uvs=np.concatenate(uvs) if uvs and all(u is not None for u in uvs) else None,
    )
