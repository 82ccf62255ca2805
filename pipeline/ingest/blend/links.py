"""Articulation: joint Empties into joints, objects into the link of their nearest
joint-Empty ancestor, links in parent-first order and the asset's mass over them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ... import ir
from ...errors import UserError
from .arrays import MIN_AXIS_LENGTH
from .objects import prop, prop_number, prop_numbers, split_world, world_matrix
from .scene import Scene

BASE_LINK = "base"
JOINT_TYPES = ("revolute", "prismatic", "continuous", "fixed")
# Smallest share of the asset's mass a link gets, relative to the heaviest link: a link
# without volume (an intermediate pan link, a flat sign) still needs a positive mass.
MIN_MASS_SHARE = 0.01


def link_of(ob) -> str:
    """The link of a non-joint object, or of a joint Empty's parent side."""
    p = ob.parent
    while p is not None:
        if p.type == "EMPTY" and "joint" in p.keys():
            return f"{p.name}_link"
        p = p.parent
    return BASE_LINK


def read_joint(path: Path, empty, depsgraph) -> ir.Joint:
    """The joint a joint Empty's custom properties describe, its pose the Empty's
    world transform without scale."""
    kind = prop(empty, "joint")
    if kind not in JOINT_TYPES:
        raise UserError(path, empty.name, f"joint = {kind!r}: expected one of {', '.join(JOINT_TYPES)}")
    world = world_matrix(path, empty, depsgraph)
    pose, _ = split_world(path, empty, world)
    local_axis = np.array(prop_numbers(path, empty, "joint_axis", 3, default=(0.0, 0.0, 1.0)))
    if np.linalg.norm(local_axis) < MIN_AXIS_LENGTH:
        raise UserError(path, empty.name, f"joint_axis {tuple(local_axis)} has (near) zero length")
    # Through the Empty's full matrix (a scaled Empty shows its axis that way), then
    # into the unscaled pivot frame.
    axis = pose[:3, :3].T @ (world[:3, :3] @ local_axis)
    length = np.linalg.norm(axis)
    if length < MIN_AXIS_LENGTH:
        raise UserError(path, empty.name, "joint_axis has (near) zero length after the Empty's scale")
    lower = prop_number(path, empty, "joint_lower")
    upper = prop_number(path, empty, "joint_upper")
    if kind in ("continuous", "fixed"):
        lower = upper = None
    elif lower is not None and upper is not None and lower > upper:
        raise UserError(path, empty.name, f"joint_lower {lower} is above joint_upper {upper}")
    for key in ("joint_effort", "joint_velocity"):
        value = prop_number(path, empty, key)
        if value is not None and value < 0:
            raise UserError(path, empty.name, f"{key} {value} is negative")
    return ir.Joint(
        name=empty.name,
        type=kind,
        parent=link_of(empty),
        child=f"{empty.name}_link",
        pose=pose,
        axis=axis / length,
        lower=lower,
        upper=upper,
        effort=prop_number(path, empty, "joint_effort"),
        velocity=prop_number(path, empty, "joint_velocity"),
    )


def check_names(path: Path, scene: Scene) -> None:
    seen: dict[str, str] = {}
    for part in scene.parts:
        name = part.item.name
        if name in seen:
            raise UserError(path, part.obj, f"visual name {name!r} clashes with object {seen[name]!r}")
        seen[name] = part.obj


def assemble_links(path: Path, scene: Scene, link_pose, parent_of_link) -> list[ir.Link]:
    """Links parent-first (base, then breadth-first, siblings by name)."""
    visuals: dict[str, list] = {name: [] for name in link_pose}
    collisions: dict[str, list] = {name: [] for name in link_pose}
    for part in scene.parts:
        (visuals if isinstance(part.item, ir.Visual) else collisions)[part.link].append(part.item)
    for part in scene.parts:
        if isinstance(part.item, ir.Collision) and not visuals[part.link]:
            raise UserError(path, part.obj, f"collision mesh of link {part.link!r}, which has no visual geometry")
    order = [BASE_LINK]
    for name in order:
        order.extend(sorted(c for c, p in parent_of_link.items() if p == name))
    return [ir.Link(name, link_pose[name], tuple(visuals[name]), tuple(collisions[name])) for name in order]


def assign_mass(links: list[ir.Link], mass_kg: float) -> tuple[ir.Link, ...]:
    """Split `mass_kg` over links in proportion to the summed bounding-box volumes of
    their LOD0 visuals (each box in its visual's frame): cheap, needs no closed meshes,
    and good enough for a kinematic twin. Every link gets at least MIN_MASS_SHARE of
    the heaviest link's share."""
    weights = []
    for link in links:
        w = 0.0
        for v in link.visuals:
            lo, hi = v.mesh.bounds()
            w += float(np.prod(hi - lo))
        weights.append(w)
    top = max(weights, default=0.0)
    if top <= 0.0:
        weights = [1.0] * len(links)
    else:
        weights = [max(w, MIN_MASS_SHARE * top) for w in weights]
    total = sum(weights)
    return tuple(ir.Link(l.name, l.pose, l.visuals, l.collisions, mass_kg * w / total) for l, w in zip(links, weights))
