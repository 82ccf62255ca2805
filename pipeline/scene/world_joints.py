"""The Gazebo world's moving parts: the joints of grouped placements, which gz-sim moves.

A grouped model is static, and gz-sim moves nothing in a static model. So for each
LOD variant with movable joints (export.names.MOVABLE_JOINTS: a disconnect switch's
blade and columns) the world holds, beside the variant's static grouped model (which
draws each placement's fixed links only, world_sdf), non-static models of moving
parts that hold, for every placement of the variant:

- each moving link (the child of a movable joint, and every link below one) as
  `<TAG>__<link>`, at the placement's pose composed with the link's pose in the
  variant, with the link's inertial and one <visual> `whole` of its whole mesh at the
  variant's LOD (names.whole_link_mesh_file; a package without one gets a copy of the
  link's visuals), and no collision: the placement's collision stays in the world's
  merged cells (world_collisions), at rest;
- each joint below the fixed links as `<TAG>__<joint>`, a joint from a fixed link
  hung on `world` (dartsim roots it there: SDFFeatures::ConstructSdfJoint), so that the
  fixed parts stay where they are and the moving links turn about the joint;
- per movable joint one JointPositionController (gz-sim Fortress,
  src/systems/joint_position_controller) listening on names.joint_command_topic(TAG,
  joint), the topic the live twin publishes on, with use_velocity_commands (the joint
  is driven at a velocity, not by a PID force against the blade's weight) and
  cmd_max at the joint's velocity limit (the speed the switch opens at).

A model of moving parts holds up to PER_MODEL placements, `<variant>__moving<k>` for
the k-th run of them in tag order (`<variant>__moving` when one run holds all; a
scaled placement's is `<TAG>__moving`). sdformat 12 spends more on a <model> than on
a <link> and a <joint> together, and little on a <plugin> (tools/gzprobe measures
each), so a model per placement would cost most. But dartsim makes a model one
skeleton and solves each skeleton's constraints (the joints' servo and limits) as one
problem, which grows faster than its joints where they chain (a column carrying a
blade): one model for every switch steps slowest, and models of a few placements step
about as fast as a model each (tools/gzprobe --physics on the sample world).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from .. import safe_xml
from ..errors import UserError
from ..export.names import MOVABLE_JOINTS, fmt, joint_command_topic, whole_link_mesh_file
from ..geometry.transform import matrix_to_xyz_rpy, xyz_rpy_to_matrix
from .placements import Placed

PLUGIN_FILE = "ignition-gazebo-joint-position-controller-system"
PLUGIN_NAME = "ignition::gazebo::systems::JointPositionController"
MODEL_SUFFIX = "__moving"
PER_MODEL = 8  # placements a model of moving parts holds (the module's docstring)
SEPARATOR = "__"


@dataclass(frozen=True)
class Articulation:
    """A variant's model.sdf split at its movable joints: the links that stay (the
    root link and those fixed to it), the links that move, and the joints among the
    moving links and from the fixed ones to them (the variant's own elements)."""

    links: dict[str, etree._Element]
    fixed: tuple[str, ...]
    moving: tuple[str, ...]
    joints: tuple[etree._Element, ...]

    @property
    def movable(self) -> tuple[etree._Element, ...]:
        return tuple(j for j in self.joints if j.get("type") in MOVABLE_JOINTS)


def articulation(source_model: etree._Element) -> Articulation | None:
    """The split of a variant's <model>, or None when no joint of it moves."""
    links = {link.get("name"): link for link in source_model.findall("link")}
    joints = source_model.findall("joint")
    children: dict[str, list[etree._Element]] = {}
    for joint in joints:
        children.setdefault(joint.findtext("parent"), []).append(joint)
    moving: list[str] = []

    def below(link: str, moved: bool) -> None:
        for joint in children.get(link, []):
            child = joint.findtext("child")
            child_moves = moved or joint.get("type") in MOVABLE_JOINTS
            if child_moves and child not in moving:
                moving.append(child)
            below(child, child_moves)

    roots = [name for name in links if all(j.findtext("child") != name for j in joints)]
    for root in roots:
        below(root, False)
    if not moving:
        return None
    kept = tuple(j for j in joints if j.findtext("child") in moving)
    return Articulation(links, tuple(n for n in links if n not in moving), tuple(moving), kept)


def read_articulation(model_sdf: Path) -> Articulation | None:
    """The split of a variant's model.sdf; a joint posed relative to another frame than
    its child link (which the package writer never does) is a UserError naming it."""
    art = articulation(safe_xml.parse(model_sdf, remove_blank_text=True).getroot().find("model"))
    for joint in art.joints if art is not None else ():
        pose = joint.find("pose")
        if pose is not None and pose.get("relative_to") not in (None, "", joint.findtext("child")):
            raise UserError(model_sdf, joint.get("name"), f"a joint posed relative to {pose.get('relative_to')!r}"
                            " cannot be placed in the world's model of moving parts (only its child link's frame)")
    return art


def pose_of(el) -> np.ndarray:
    """(4, 4) float64 of an SDF element's <pose> text (identity without one)."""
    text = el.findtext("pose")
    values = [float(v) for v in text.split()] if text else [0.0] * 6
    return xyz_rpy_to_matrix(values[:3], values[3:6])


def pose_text(matrix: np.ndarray) -> str:
    xyz, rpy = matrix_to_xyz_rpy(matrix)
    return " ".join(fmt(v) for v in (*xyz.tolist(), *rpy.tolist()))


def scale_geometry(item, s: float) -> None:
    """An SDF visual's or collision's geometry drawn `s` times its size (uniform)."""
    geometry = item.find("geometry")
    if geometry is None:
        return
    mesh = geometry.find("mesh")
    if mesh is not None:
        scale = mesh.find("scale")
        old = [float(v) for v in scale.text.split()] if scale is not None else [1.0, 1.0, 1.0]
        if scale is None:
            scale = etree.SubElement(mesh, "scale")
        scale.text = " ".join(fmt(v * s) for v in old)
    for path in ("box/size", "cylinder/radius", "cylinder/length", "sphere/radius", "capsule/radius",
                 "capsule/length", "ellipsoid/radii"):
        for el in geometry.findall(path):
            el.text = " ".join(fmt(float(v) * s) for v in el.text.split())


def scale_element(item: etree._Element, offset: np.ndarray, scale: float, relative_to: str | None = None):
    """`item` (a <visual> or <collision>) posed at `offset` @ its own pose, for a
    placement drawn `scale` times its size (its offset and geometry scaled);
    `relative_to`: the frame its pose is given in (None: its link's). Returns item."""
    pose = item.find("pose")
    if pose is None:
        pose = etree.Element("pose")
        item.insert(0, pose)
    at = offset @ pose_of(item)
    if scale != 1.0:
        at[:3, 3] *= scale
        scale_geometry(item, scale)
    pose.text = pose_text(at)
    if relative_to is not None:
        pose.set("relative_to", relative_to)
    return item


def _text(parent, tag: str, text) -> etree._Element:
    el = etree.SubElement(parent, tag)
    el.text = str(text)
    return el


def placement_matrix(pl: Placed) -> np.ndarray:
    """The placement's frame in the world, as world_sdf poses its frame (x, y, z, yaw)."""
    x, y, z = pl.pose[:3, 3]
    return xyz_rpy_to_matrix((x, y, z), (0.0, 0.0, pl.yaw))


def link_visuals(models: Path, pl: Placed, art: Articulation, link: str, name: str) -> list[etree._Element]:
    """What draws `link` of a placement, posed in the link's frame: one <visual>
    `name` of its whole mesh at the placement's LOD, or, when its package has none
    (LOD 0 of an asset with coarser levels, or a package written before them), a copy
    of each of the link's visuals, named `<name>__<visual>`."""
    asset = pl.placement.asset_id
    rel = whole_link_mesh_file(link, pl.lod)
    if (models / asset / rel).is_file():
        visual = etree.Element("visual", name=name)
        _text(visual, "pose", "0 0 0 0 0 0")
        _text(etree.SubElement(etree.SubElement(visual, "geometry"), "mesh"), "uri", f"model://{asset}/{rel}")
        return [visual]
    out = []
    for source in art.links[link].findall("visual"):
        visual = copy.deepcopy(source)
        visual.set("name", f"{name}{SEPARATOR}{source.get('name')}")
        out.append(visual)
    return out


def moving_model(name: str, models: Path, members: list[Placed], art: Articulation) -> etree._Element:
    """The non-static model `name` (`<variant>__moving`) of the members' moving links,
    joints and joint position controllers (the module's docstring)."""
    model = etree.Element("model", name=name)
    for pl in members:
        tag, scale = pl.placement.tag, pl.placement.scale
        frame = placement_matrix(pl)
        for name in art.moving:
            source = art.links[name]
            offset = pose_of(source)
            offset[:3, 3] *= scale
            link = etree.SubElement(model, "link", name=f"{tag}{SEPARATOR}{name}")
            _text(link, "pose", pose_text(frame @ offset))
            inertial = source.find("inertial")
            if inertial is not None:
                link.append(copy.deepcopy(inertial))
            for visual in link_visuals(models, pl, art, name, "whole"):
                link.append(scale_element(visual, np.eye(4), scale))
        for source in art.joints:
            model.append(_joint(tag, source, art, scale))
        for source in art.movable:
            model.append(_controller(tag, source))
    return model


def _joint(tag: str, source: etree._Element, art: Articulation, scale: float) -> etree._Element:
    """The placement's copy of a joint: its links renamed, a fixed parent as `world`;
    its pose (relative to the child link, SDF's default) and axis as authored."""
    joint = copy.deepcopy(source)
    joint.set("name", f"{tag}{SEPARATOR}{source.get('name')}")
    parent = source.findtext("parent")
    joint.find("parent").text = "world" if parent in art.fixed else f"{tag}{SEPARATOR}{parent}"
    joint.find("child").text = f"{tag}{SEPARATOR}{source.findtext('child')}"
    pose = joint.find("pose")
    if pose is not None and pose.get("relative_to"):
        pose.set("relative_to", joint.findtext("child"))  # its child link, renamed (read_articulation)
    if pose is not None and scale != 1.0:
        at = pose_of(joint)
        at[:3, 3] *= scale
        pose.text = pose_text(at)
    return joint


def _controller(tag: str, source: etree._Element) -> etree._Element:
    """gz-sim's JointPositionController of one joint of a placement."""
    plugin = etree.Element("plugin", filename=PLUGIN_FILE, name=PLUGIN_NAME)
    _text(plugin, "joint_name", f"{tag}{SEPARATOR}{source.get('name')}")
    _text(plugin, "topic", joint_command_topic(tag, source.get("name")))
    _text(plugin, "use_velocity_commands", "true")
    speed = source.findtext("axis/limit/velocity")
    if speed is not None and float(speed) > 0:
        # with velocity commands the controller moves the joint at most at cmd_max
        _text(plugin, "cmd_max", fmt(float(speed)))
        _text(plugin, "cmd_min", fmt(-float(speed)))
    return plugin
