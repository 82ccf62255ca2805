"""What a coarse LOD variant draws: a link's visuals merged by material.

A LOD k >= 1 model (models/<id>__lod<k>/) is what a scene places away from the
inspection points. Each of its visuals costs sdformat and the renderer the same whatever
its size, so a link draws each material once: the visuals that share a material become
one mesh in the link frame (meshes/<link>__<material>__merged_lod<k>.dae). A visual that
a state binding drives, or that has shape keys, stays itself (the runtime moves or
recolours it alone); so does a material's only visual, which reuses its own file.
Collisions: at every level a collision mesh that is a box or a cylinder is that shape
(geometry/primitives.py); in a variant the link's other collision meshes (a lattice's
hulls, one per part) become one mesh, meshes/<link>__collision__merged.dae.
Both the COLLADA and the SDF writer take the grouping from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import ir
from ..geometry.merge import merge_meshes
from ..geometry.primitives import Primitive, fit_primitive
from . import names


@dataclass(frozen=True)
class VariantVisual:
    """One visual of a variant's link. parts: the IR visuals it draws (one, or the
    merged ones in link order); pose: (4, 4) in the link frame."""

    name: str
    material: str
    mesh_file: str
    pose: np.ndarray
    parts: tuple[ir.Visual, ...]

    @property
    def merged(self) -> bool:
        return len(self.parts) > 1

    def mesh(self, level: int) -> ir.Mesh:
        """The mesh this visual draws at `level`, in its own frame."""
        if not self.merged:
            return self.parts[0].lod(level)
        return merge_meshes([(v.pose, v.lod(level)) for v in self.parts])


def kept_apart(asset: ir.Asset) -> frozenset[str]:
    """Visuals never merged: those a state binding drives and those with shape keys."""
    bound = {b.target for b in asset.bindings}
    keyed = {v.name for _, v in asset.visuals() if any(m.shape_keys for m in v.lods)}
    return frozenset(bound | keyed)


def variant_visuals(asset: ir.Asset, link: ir.Link, level: int, keep: frozenset[str] = frozenset()) -> list[VariantVisual]:
    """The visuals of `link` in the LOD `level` variant (level 0: the package's own,
    one per IR visual). keep: more visual names to leave unmerged."""
    apart = kept_apart(asset) | keep

    def alone(v: ir.Visual) -> VariantVisual:
        return VariantVisual(v.name, v.material, names.mesh_file(link.name, v.name, level if level < len(v.lods)
                                                                   else len(v.lods) - 1), v.pose, (v,))

    if level == 0:
        return [alone(v) for v in link.visuals]
    groups: dict[str, list[ir.Visual]] = {}
    out: list[VariantVisual] = []
    for v in link.visuals:
        if v.name in apart:
            out.append(alone(v))
        else:
            groups.setdefault(v.material, []).append(v)
    for material, parts in groups.items():
        if len(parts) == 1:
            out.append(alone(parts[0]))
        else:
            out.append(VariantVisual(names.merged_visual_name(material), material,
                                     names.merged_mesh_file(link.name, material, level), np.eye(4), tuple(parts)))
    return out


MAX_PRIMITIVES = 4


@dataclass(frozen=True)
class VariantCollision:
    """One collision of a variant's link: a primitive shape (mesh_file None) or a mesh.
    pose: (4, 4) in the link frame; parts: the IR collisions it stands for."""

    name: str
    pose: np.ndarray
    shape: Primitive | None
    mesh_file: str | None
    parts: tuple[ir.Collision, ...]

    def mesh(self) -> ir.Mesh:
        """The merged mesh (in the link frame) of a collision that stands for several."""
        return merge_meshes([(c.pose, c.mesh) for c in self.parts])


def variant_collisions(link: ir.Link, level: int) -> list[VariantCollision]:
    """The collisions of `link` in the LOD `level` variant (level 0: the package's own).
    A variant keeps at most MAX_PRIMITIVES primitives a link; past that (a lattice of
    boxes) they join the merged mesh too, since a physics engine pays per shape."""
    out, meshes = [], []
    shapes = [(col, fit_primitive(col.mesh.vertices, col.mesh.faces)) for col in link.collisions]
    too_many = level > 0 and sum(shape is not None for _, shape in shapes) > MAX_PRIMITIVES
    for col, shape in shapes:
        if shape is not None and not too_many:
            out.append(VariantCollision(col.name, col.pose @ shape.pose, shape, None, (col,)))
        else:
            meshes.append(col)
    if level == 0 or len(meshes) < 2:
        out += [VariantCollision(c.name, c.pose, None, names.collision_file(link.name, c.name), (c,)) for c in meshes]
    else:
        out.append(VariantCollision(names.merged_collision_name(), np.eye(4), None,
                                    names.merged_collision_file(link.name), tuple(meshes)))
    return out
