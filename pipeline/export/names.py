"""Names shared by every writer, the scene assembly and the runtime, so a visual can be
found in each format without parsing it: one rule, written once."""

from __future__ import annotations

import re

_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


def safe_name(name: str) -> str:
    """An identifier valid in USD, SDF and file names: [A-Za-z_][A-Za-z0-9_]*."""
    s = _UNSAFE.sub("_", name)
    if not s or s[0].isdigit():
        s = "_" + s
    return s


def mesh_file(link: str, visual: str, lod: int) -> str:
    """Package-relative COLLADA file of one visual at one LOD."""
    return f"meshes/{safe_name(link)}__{safe_name(visual)}__lod{lod}.dae"


def merged_visual_name(material: str) -> str:
    """A LOD variant's visual that draws every visual of a link with this material."""
    return f"{safe_name(material)}__merged"


def merged_mesh_file(link: str, material: str, lod: int) -> str:
    """Package-relative COLLADA file of a link's visuals of one material, merged, at one LOD."""
    return f"meshes/{safe_name(link)}__{safe_name(material)}__merged_lod{lod}.dae"


def merged_collision_name() -> str:
    """A LOD variant's collision that stands for a link's collision meshes."""
    return "collision__merged"


def merged_collision_file(link: str) -> str:
    return f"meshes/{safe_name(link)}__collision__merged.dae"


def whole_mesh_file(lod: int) -> str:
    """Package-relative COLLADA file of the whole model at rest at one LOD: every visual
    of every link in the model frame, one submesh per material (a grouped placement in
    the Gazebo world draws it as one visual)."""
    return f"meshes/whole__lod{lod}.dae"


WHOLE_COLLISION_FILE = "meshes/whole__collision.dae"  # every collision mesh, model frame

MOVABLE_JOINTS = ("revolute", "prismatic", "continuous")


def whole_link_mesh_file(link: str, lod: int) -> str:
    """Package-relative COLLADA file of one link of an articulated model at one LOD:
    every visual of the link in the link frame, one submesh per material (the Gazebo
    world draws a grouped placement's moving links, each as one visual, on joints)."""
    return f"meshes/whole__{safe_name(link)}__lod{lod}.dae"


def joint_command_topic(tag: str, joint: str) -> str:
    """The gz-transport topic on which the Gazebo world listens for the position of a
    placement's joint (ignition.msgs.Double): the world's JointPositionController of
    that joint subscribes to it (scene.world_joints) and the live twin publishes on it
    (bridges.gazebo). The form of gz-sim's default `/model/<model>/joint/<joint>/0/cmd_pos`,
    with the placement's tag as the model."""
    return f"/model/{tag}/joint/{joint}/0/cmd_pos"


def collision_file(link: str, collision: str) -> str:
    return f"meshes/{safe_name(link)}__{safe_name(collision)}__collision.dae"


def usd_file(asset_id: str) -> str:
    return f"{asset_id}.usdc"


def gltf_file(asset_id: str) -> str:
    return f"{asset_id}.glb"


def usd_visual_path(asset_id: str, link: str, visual: str) -> str:
    """Prim path of a visual's Xform in the asset's USD (the mesh is its child `mesh`)."""
    return f"/{safe_name(asset_id)}/{safe_name(link)}/{safe_name(visual)}"


def usd_link_path(asset_id: str, link: str) -> str:
    return f"/{safe_name(asset_id)}/{safe_name(link)}"


def lod_model_name(asset_id: str, lod: int) -> str:
    """SDF model folder of an asset's LOD variant; LOD 0 is the package itself."""
    return asset_id if lod == 0 else f"{asset_id}__lod{lod}"


def fmt(x: float) -> str:
    """Shortest round-trip text of a float, the same on every platform; no -0."""
    x = float(x)
    if x == 0.0:
        return "0"
    r = repr(x)
    return r[:-2] if r.endswith(".0") else r


_POINT_ZERO = re.compile(r"\.0(?= |$)")
_MINUS_ZERO = re.compile(r"(?<![^ ])-0(?= |$)")


def fmt_join(values) -> str:
    """" ".join(fmt(x) for x in values), with repr and the edits done at C speed (a
    mesh's arrays hold hundreds of thousands of floats)."""
    text = " ".join(map(repr, map(float, values)))
    return _MINUS_ZERO.sub("0", _POINT_ZERO.sub("", text))


SCENE_ROOT = "/Site"


def scene_placement_path(tag: str) -> str:
    """Prim path of a placement in the scene stage build/scene/<site>.usda; the asset's
    prims (links, visuals) are below it, e.g. <this>/<link>/<visual>."""
    return f"{SCENE_ROOT}/Placements/{safe_name(tag)}"
