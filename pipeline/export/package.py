"""One asset's model package: every format into models/<id>/, and one SDF model per
coarser LOD beside it (models/<id>__lod<k>/), the variants a scene includes by distance.

Used by the asset tasks and by the terrain task alike; the manifest is the caller's,
from what this returns.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from .. import ir
from ..digest import sha256_file
from ..errors import UserError
from ..fork_join import spread
from . import PACKAGE_FORMATS, names, sdf, writer


def write_package(asset: ir.Asset, models: Path, alongside: Callable[[], object] | None = None,
                  memo=None) -> tuple[dict[str, str], list[str], object, dict]:
    """Every format of one asset into models/<id>/, LOD variants beside it, and
    `alongside()` (if given) with them. When the worker has a core to spare, in three
    parts side by side: the COLLADA meshes (the largest share in a cold build), the
    glTF with the thumbnail, and the rest here. `memo`: the COLLADA documents of
    earlier builds (collada.write). Returns (package-relative path -> sha256, LOD
    variant model names, what alongside returned, how many COLLADA documents were
    linked from the memo and how many made)."""
    folder = inside(models, asset.id)
    folder.mkdir(parents=True, exist_ok=True)

    def the_rest():
        for fmt in PACKAGE_FORMATS:
            if fmt not in ("collada", "gltf", "thumbnail"):
                writer(fmt)(asset, folder)
        lod_models = []
        for level in range(1, asset.lod_count):
            name = names.lod_model_name(asset.id, level)
            variant = inside(models, name)
            variant.mkdir(parents=True, exist_ok=True)
            sdf.write(asset, variant, lod=level, model_name=name)
            lod_models.append(name)
        return lod_models, alongside() if alongside is not None else None

    def gltf_and_thumbnail():
        return [writer(fmt)(asset, folder) for fmt in ("gltf", "thumbnail")]

    def meshes():
        writer("collada")(asset, folder, memo)
        return {"linked": memo.hits, "made": memo.puts} if memo is not None else {}

    (lod_models, extra), _, documents = spread([the_rest, gltf_and_thumbnail, meshes])
    outputs = {str(p.relative_to(folder)): sha256_file(p) for p in sorted(folder.rglob("*")) if p.is_file()}
    return outputs, lod_models, extra, documents


def inside(root: Path, name: str) -> Path:
    """root/name, refusing any name that would leave root (ids come from users)."""
    path = (root / name).resolve()
    if path.parent != root.resolve():
        raise UserError(root, name, "output path escapes the build folder")
    return path
