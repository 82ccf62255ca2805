"""The package's images: textures/<name>.<png|jpg>, the bytes as the source had them.

The COLLADA effects, the USD shaders and the SDF <pbr> maps reference these files; the
glTF embeds the same bytes.
"""

from __future__ import annotations

from pathlib import Path

from pipeline import ir


def texture_file(texture: ir.Texture) -> str:
    """Package-relative path of a texture's image."""
    return f"textures/{texture.name}{texture.suffix}"


def write(asset: ir.Asset, folder: Path) -> list[str]:
    written = []
    for texture in asset.textures().values():
        rel = texture_file(texture)
        path = Path(folder) / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(texture.data)
        written.append(rel)
    return written
