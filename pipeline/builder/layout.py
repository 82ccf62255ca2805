"""Where an asset's chain leaves its intermediate files in a build folder: the
source task's cleaned source and the geometry task's result (builder.irfile files).
Every task of the chain reads or writes them, so their code versions cover this."""

from __future__ import annotations

SOURCE_FOLDER = ".source"
IR_FOLDER = ".ir"


def source_path(asset_id: str) -> str:
    """Where an asset's source task leaves the cleaned source, relative to build/."""
    return f"{SOURCE_FOLDER}/{asset_id}/{asset_id}.ir"


def ir_path(asset_id: str) -> str:
    """Where an asset's geometry task leaves its result, relative to build/."""
    return f"{IR_FOLDER}/{asset_id}/{asset_id}.ir"
