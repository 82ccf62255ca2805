"""The placed view of a package: what the scene and the tiles read of it, as one file.

The scene and the tiles depend on it (builder.tasks), not on the package task, so a
package edit that leaves it the same (a description: it changes model.config, the
USD's documentation and the manifest's text, none of which they read) stops at the
view, by the engine's early cutoff on what a task made. What they read: the manifest
(bounds, LODs, variants, bindings, joints, terminals...), the glTF, every model.sdf and
mesh of the package and its LOD variants (the world copies grouped models from them
and asks which meshes exist). The view holds the manifest without the keys below and
the hash of every other file, so any change of those reruns both.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..digest import sha256_file
from ..files import atomic_write

VIEW_FOLDER = ".placed"
# manifest keys no scene or tiles writer reads: the package's own text and record (the
# files' hashes are taken here, from the files)
UNREAD_KEYS = ("description", "source", "findings", "outputs")
# package files they never open (the stage names the USD layer by its path only)
UNREAD_FILES = ("model.config", "thumbnail.png", "manifest.json")


def view_path(asset_id: str) -> str:
    """Where an asset's placed view is, relative to build/."""
    return f"{VIEW_FOLDER}/{asset_id}/view.json"


def placed_view(models: Path, asset_id: str) -> dict:
    """The view of models/<asset_id> and its LOD variants' folders."""
    models = Path(models)
    manifest = json.loads((models / asset_id / "manifest.json").read_text(encoding="utf-8"))
    unread = set(UNREAD_FILES) | {f"{asset_id}.usdc"}
    files = {}
    for folder in [models / asset_id, *sorted(models.glob(f"{asset_id}__lod*"))]:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            if path.name not in unread or path.parent != folder:
                files[path.relative_to(models).as_posix()] = sha256_file(path)
    return {"manifest": {k: v for k, v in sorted(manifest.items()) if k not in UNREAD_KEYS}, "files": files}


def build_view(staging: Path, build: str, asset: str) -> dict:
    """Task action: .placed/<asset>/view.json from the package in build/models/."""
    view = placed_view(Path(build) / "models", asset)
    atomic_write(Path(staging) / view_path(asset), json.dumps(view, sort_keys=True, separators=(",", ":")) + "\n")
    return {"files": len(view["files"])}
