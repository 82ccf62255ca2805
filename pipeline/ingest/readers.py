"""`READERS`: a source file's suffix -> the reader that makes an ir.Asset of it
(DESIGN.md s.2). Each reader takes the asset's config.AssetConfig and returns plain
data; the source task (builder.source_task) and `twin info` call `read_source`.
"""

from __future__ import annotations

from .. import ir
from .blend import read_blend
from .cad import read_cad
from .mesh import SUFFIXES as MESH_SUFFIXES
from .mesh import read_mesh

READERS = {
    ".blend": read_blend,
    ".step": read_cad,
    ".stp": read_cad,
    **{suffix: read_mesh for suffix in MESH_SUFFIXES},
}


def read_source(cfg) -> ir.Asset:
    """cfg.source read by the reader for its suffix (any case). A suffix no reader
    takes goes to read_mesh, which refuses it by name."""
    return READERS.get(cfg.source.suffix.lower(), read_mesh)(cfg)
