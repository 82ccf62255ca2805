"""Image textures of the sources, as ir.Texture: what the mesh readers (through trimesh,
for glTF, COLLADA and OBJ/MTL alike) and the .blend reader find in a material.

trimesh hands images over decoded (PIL); they are encoded again as PNG with fixed
settings and no metadata, so the same source always gives the same bytes. A .blend's
packed image is taken as stored; an external one only from inside the source's folder
(the file is untrusted: it may name any path).
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np

from .. import ir

# trimesh PBRMaterial attribute -> IR slot
_PBR_ATTRIBUTES = {"baseColorTexture": "base_color", "normalTexture": "normal",
                   "metallicRoughnessTexture": "metallic_roughness", "occlusionTexture": "occlusion",
                   "emissiveTexture": "emissive"}


def png_bytes(image) -> bytes:
    """A PIL image as PNG bytes that depend on its pixels only."""
    buf = io.BytesIO()
    alpha = "A" in image.getbands() or "transparency" in image.info
    image.convert("RGBA" if alpha else "RGB").save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


def trimesh_textures(material, slots=ir.TEXTURE_SLOTS) -> dict[str, ir.Texture]:
    """slot -> texture of a trimesh material (PBRMaterial's maps among `slots`, or a
    SimpleMaterial's image as the base colour), named `<slot>_<12 hex of its hash>`:
    materials sharing an image (a glTF's body and wheels) share one file."""
    if material is None:
        return {}
    found = {}
    if hasattr(material, "baseColorTexture"):
        for attribute, slot in _PBR_ATTRIBUTES.items():
            image = getattr(material, attribute, None)
            if image is not None and slot in slots:
                found[slot] = image
    elif getattr(material, "image", None) is not None:
        found["base_color"] = material.image
    encoded = {slot: png_bytes(image) for slot, image in found.items()}
    return {slot: ir.Texture(f"{slot}_{hashlib.sha256(data).hexdigest()[:12]}", data) for slot, data in encoded.items()}


def trimesh_uvs(geom) -> np.ndarray | None:
    """(n, 2) float64 UVs of a trimesh geometry's vertices (origin bottom-left, as
    trimesh gives them for every format), or None."""
    uv = getattr(getattr(geom, "visual", None), "uv", None)
    if uv is None:
        return None
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(geom.vertices), 2) or not np.isfinite(uv).all():
        return None
    return uv


def with_textures(material: ir.Material, textures: dict[str, ir.Texture]) -> ir.Material:
    return material if not textures else ir.Material(
        material.name, material.base_color, material.metallic, material.roughness, material.emission,
        **{f"{slot}_texture": t for slot, t in textures.items()})


def blend_image(image, source: Path, stem: str, opened: dict | None = None) -> ir.Texture | None:
    """A bpy image as a texture: packed bytes as stored, else the file it names when
    that file lies inside the .blend's folder (recorded in `opened`, relative path ->
    sha256); None when neither (the caller warns). An image over the caps
    (ingest.images) is a UserError naming the .blend and the image."""
    from ..errors import UserError
    from . import images
    from .images import SourceFiles, image_problem, size_text

    packed = getattr(image, "packed_file", None)
    if packed is not None and packed.data:
        if int(getattr(packed, "size", 0) or 0) > images.MAX_IMAGE_BYTES:
            raise UserError(source, f"image {image.name!r}", f"packed image of {size_text(packed.size)}, over "
                                                             f"the {size_text(images.MAX_IMAGE_BYTES)} limit for an image")
        data = bytes(packed.data)
    else:
        raw = str(getattr(image, "filepath", "") or "")
        relative = raw[2:] if raw.startswith("//") else raw
        files = SourceFiles(source)
        try:
            path = files.locate(relative)
        except OSError:
            if opened is not None:
                opened.update(files.opened)  # where it was looked for, should it appear there
            return None
        if path.stat().st_size > images.MAX_IMAGE_BYTES:
            raise UserError(source, f"image {image.name!r}", f"{raw}: {size_text(path.stat().st_size)}, over "
                                                             f"the {size_text(images.MAX_IMAGE_BYTES)} limit for an image")
        data = path.read_bytes()
        files.record(path, data)
        if opened is not None:
            opened.update(files.opened)
    why = image_problem(data)
    if why is not None:
        raise UserError(source, f"image {image.name!r}", why)
    texture = ir.Texture(stem, data)
    try:
        texture.mime  # PNG or JPEG as found
    except ValueError:
        from PIL import Image

        try:
            texture = ir.Texture(stem, png_bytes(Image.open(io.BytesIO(data))))
        except Exception:  # an image PIL cannot read: the caller warns
            return None
    return texture
