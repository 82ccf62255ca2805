"""Texture coordinates with xatlas, for meshes that need them.

Our materials are untextured, so UVs are generated only on request: for every mesh
without UVs when `UvOptions(force=True)`, or when its visual's material name is in
`UvOptions(materials=...)`. xatlas splits vertices along chart seams, so the result
has more vertices; `vmapping` says which original vertex each one copies.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .. import ir
from ..errors import UserError
from .clean import centred


@dataclass(frozen=True)
class UvOptions:
    """force: unwrap every mesh without UVs; materials: unwrap meshes with these materials."""

    force: bool = False
    materials: tuple[str, ...] = ()


def unwrap(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """xatlas parametrisation of `vertices: (n, 3)`, `faces: (m, 3)`.

    Returns vertices (k, 3) float64 (copies of input vertices, k >= n used ones),
    faces (m, 3) int64 in the same order and winding as the input, uvs (k, 2) float64
    in [0, 1], and vmapping (k,) int64: the input vertex each output vertex copies.
    xatlas runs in float32 on coordinates relative to the bounding-box centre.
    """
    import xatlas

    v = np.asarray(vertices, dtype=np.float64)
    local, _ = centred(v)
    vmapping, indices, uvs = xatlas.parametrize(local.astype(np.float32), np.asarray(faces, dtype=np.uint32))
    vmapping = vmapping.astype(np.int64)
    return v[vmapping], indices.astype(np.int64).reshape(-1, 3), uvs.astype(np.float64), vmapping


def unwrap_mesh(mesh: ir.Mesh) -> ir.Mesh:
    """The mesh with xatlas UVs; normals and shape keys follow the split vertices."""
    v, f, uv, vmap = unwrap(mesh.vertices, mesh.faces)
    return ir.Mesh(
        v, f,
        normals=None if mesh.normals is None else mesh.normals[vmap],
        uvs=uv,
        shape_keys=tuple(ir.ShapeKey(k.name, k.vertices[vmap]) for k in mesh.shape_keys),
    )


def uv_step(options: UvOptions = UvOptions()) -> Callable[[ir.Asset], ir.Asset]:
    """Step: UVs for every LOD of the visuals that need them (see module docstring)."""
    wanted = set(options.materials)

    def step(asset: ir.Asset) -> ir.Asset:
        links = []
        for link in asset.links:
            visuals = []
            for vis in link.visuals:
                if not (options.force or vis.material in wanted):
                    visuals.append(vis)
                    continue
                lods, done = [], {}
                for m in vis.lods:
                    if m.uvs is not None or m.triangle_count == 0:
                        lods.append(m)
                        continue
                    if not np.isfinite(m.vertices).all():
                        raise UserError(asset.source, vis.name, "non-finite vertex coordinates")
                    # a frozen visual repeats one Mesh object: unwrap it once, keep sharing
                    if id(m) not in done:
                        done[id(m)] = unwrap_mesh(m)
                    lods.append(done[id(m)])
                visuals.append(replace(vis, lods=tuple(lods)))
            links.append(replace(link, visuals=tuple(visuals)))
        return asset.with_(links=tuple(links))

    return step
