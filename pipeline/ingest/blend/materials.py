"""A .blend material as an `ir.Material`: its Principled BSDF's values and the
images linked to it (textures.blend_image), else its viewport colour."""

from __future__ import annotations

import math
import re
from pathlib import Path

from ... import ir
from ...errors import UserError
from ..textures import blend_image
from .scene import Scene

DEFAULT_MATERIAL = "default"


def material(bpy, path: Path, name: str, warnings: dict | None = None, opened: dict | None = None) -> ir.Material:
    """Principled BSDF inputs of material `name`: their unlinked values, and the image
    of an Image Texture node linked to Base Color, Normal (through a Normal Map node) or
    Emission Color, whose factor is then white as in Blender; a material without one
    falls back to its viewport colour, metallic and roughness. An image that cannot be
    had (external, outside the .blend's folder or missing) is a warning; an external
    image read is recorded in `opened` (path relative to the folder -> sha256)."""
    if name == DEFAULT_MATERIAL and name not in bpy.data.materials:
        return ir.Material(DEFAULT_MATERIAL)
    mat = bpy.data.materials.get(name)
    if mat is None:
        raise UserError(path, name, "material not found in the file")
    bsdf = _principled(mat)
    if bsdf is None:
        r, g, b, a = (float(c) for c in mat.diffuse_color)
        return ir.Material(name, (r, g, b, a), float(mat.metallic), float(mat.roughness))
    inputs = bsdf.inputs
    r, g, b = (float(c) for c in inputs["Base Color"].default_value[:3])
    alpha = float(inputs["Alpha"].default_value)
    strength = float(inputs["Emission Strength"].default_value)
    emission = tuple(float(c) * strength for c in inputs["Emission Color"].default_value[:3])
    values = (r, g, b, alpha, float(inputs["Metallic"].default_value), float(inputs["Roughness"].default_value), *emission)
    if not all(math.isfinite(v) for v in values):
        raise UserError(path, name, "material has NaN or infinite values")
    textures, missing = _textures(path, name, inputs, opened)
    if missing and warnings is not None:
        warnings["textures"] = ", ".join(filter(None, [warnings.get("textures"), *missing]))
    if "base_color" in textures:
        r, g, b = 1.0, 1.0, 1.0
    if "emissive" in textures:
        emission = (strength, strength, strength)
    return ir.Material(
        name,
        base_color=(r, g, b, alpha),
        metallic=float(inputs["Metallic"].default_value),
        roughness=float(inputs["Roughness"].default_value),
        emission=emission,
        **{f"{slot}_texture": t for slot, t in textures.items()},
    )


_TEXTURE_SOCKETS = {"base_color": "Base Color", "normal": "Normal", "emissive": "Emission Color"}


def _textures(path: Path, name: str, inputs, opened: dict | None = None) -> tuple[dict[str, ir.Texture], list[str]]:
    """slot -> texture of the Principled inputs' linked images, and what could not be read."""
    found, missing = {}, []
    for slot, socket in _TEXTURE_SOCKETS.items():
        image = _linked_image(inputs[socket]) if socket in inputs else None
        if image is None:
            continue
        texture = blend_image(image, path, f"{_safe_stem(name)}_{slot}", opened)
        if texture is None:
            where = str(getattr(image, "filepath", "") or "")
            missing.append(f"{name}.{socket} image {image.name!r}" + (f" at {where!r}" if where else "")
                           + " (not packed, not found inside the .blend's folder)")
        else:
            found[slot] = texture
    return found, missing


def _linked_image(socket):
    """The image of an Image Texture node feeding `socket`, directly or through a Normal
    Map node; None for anything else (a procedural texture is not carried)."""
    for link in socket.links:
        node = link.from_node
        if node.type == "NORMAL_MAP" and "Color" in node.inputs:
            return _linked_image(node.inputs["Color"])
        if node.type == "TEX_IMAGE" and node.image is not None:
            return node.image
    return None


def _safe_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "material"


def _principled(mat):
    """The Principled BSDF feeding the material output, else the first one."""
    if mat.node_tree is None:
        return None
    nodes = [n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"]
    for node in nodes:
        if any(link.to_node.type == "OUTPUT_MATERIAL" for out in node.outputs for link in out.links):
            return node
    return nodes[0] if nodes else None


def referenced_materials(scene: Scene) -> list[str]:
    """Materials the bindings switch to, which no triangle need use."""
    return sorted({m for b in scene.bindings for m in b.materials})


def material_or_error(config_path: Path, where: str, name: str) -> ir.Material:
    """Material `name` of the open file for asset.toml's binding `where`."""
    import bpy

    if name not in bpy.data.materials:
        raise UserError(config_path, f"{where}.materials", f"material {name!r} is not in the source file")
    return material(bpy, config_path, name)
