"""One writer module per output format; `WRITERS` maps a format to its module.

Each module exposes `write(asset: ir.Asset, folder: Path, ...) -> list[str]` and
nothing else; `package` writes them all into one model folder. Modules are imported when first asked for, so importing this package
costs nothing (pxr, pycollada and pillow load only when their writer runs).
"""

from __future__ import annotations

import importlib

WRITERS = {
    "collada": "collada",
    "sdf": "sdf",
    "usd": "usd",
    "gltf": "gltf",
    "thumbnail": "thumbnail",
    "textures": "textures",
}
PACKAGE_FORMATS = ("textures", "collada", "sdf", "usd", "gltf", "thumbnail")


def writer(fmt: str):
    """The `write` function of format `fmt`."""
    return importlib.import_module(f".{WRITERS[fmt]}", __name__).write
