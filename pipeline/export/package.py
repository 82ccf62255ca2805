"""One asset's model package: every format into models/<id>/, and one SDF model per
coarser LOD beside it (models/<id>__lod<k>/), the variants a scene includes by distance.

Used by the asset tasks and by the terrain task alike; the manifest is the caller's,
from what this returns.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Callable

from .. import ir
from ..digest import sha256_file
from ..errors import UserError
from ..fork_join import spread
from . import collada, gltf, names, sdf, textures, thumbnail, usd

# format -> write(asset, folder, ...) -> the package-relative paths written
WRITERS = {
    "textures": textures.write,
    "collada": collada.write,
    "sdf": sdf.write,
    "usd": usd.write,
    "gltf": gltf.write,
    "thumbnail": thumbnail.write,
}
# the formats written beside the rest when the worker has a core to spare: the
# COLLADA meshes (the largest share of a cold build), the glTF with the thumbnail
BESIDE = (("gltf", "thumbnail"), ("collada",))


def write_package(asset: ir.Asset, models: Path, alongside: Callable[[], object] | None = None,
                  memo=None) -> tuple[dict[str, str], list[str], object, dict]:
    """Every format of one asset into models/<id>/, LOD variants beside it, and
    `alongside()` (if given) with them; the formats of BESIDE each in a part of their
    own (fork_join.spread). `memo`: the COLLADA documents of earlier builds
    (collada.write). Returns (package-relative path -> sha256, LOD variant model
    names, what alongside returned, how many COLLADA documents were linked from the
    memo and how many made)."""
    folder = inside(models, asset.id)
    folder.mkdir(parents=True, exist_ok=True)
    options = {"collada": {"memo": memo}}

    def write(formats: tuple[str, ...]) -> dict:
        """The formats' files; what the memo did meanwhile (a part forked off counts
        in its own process)."""
        before = _memo_counts(memo)
        for fmt in formats:
            WRITERS[fmt](asset, folder, **options.get(fmt, {}))
        after = _memo_counts(memo)
        return {k: after[k] - before[k] for k in after}

    def the_rest():
        documents = write(tuple(fmt for fmt in WRITERS if not any(fmt in part for part in BESIDE)))
        lod_models = []
        for level in range(1, asset.lod_count):
            name = names.lod_model_name(asset.id, level)
            variant = inside(models, name)
            variant.mkdir(parents=True, exist_ok=True)
            sdf.write(asset, variant, lod=level, model_name=name)
            lod_models.append(name)
        return documents, lod_models, alongside() if alongside is not None else None

    (documents, lod_models, extra), *beside = spread([the_rest, *(partial(write, part) for part in BESIDE)])
    for counts in beside:
        documents = {k: documents[k] + counts[k] for k in documents}
    outputs = {str(p.relative_to(folder)): sha256_file(p) for p in sorted(folder.rglob("*")) if p.is_file()}
    return outputs, lod_models, extra, documents


def _memo_counts(memo) -> dict:
    """The COLLADA memo's documents linked and made so far ({} without a memo)."""
    return {"linked": memo.hits, "made": memo.puts} if memo is not None else {}


def inside(root: Path, name: str) -> Path:
    """root/name, refusing any name that would leave root (ids come from users)."""
    path = (root / name).resolve()
    if path.parent != root.resolve():
        raise UserError(root, name, "output path escapes the build folder")
    return path
