"""How large a mesh or CAD source may be, judged by stat alone: the readers refuse a
file over the limit before they open it, and the build's planner refuses it before it
hashes the file for its task's key (a mistaken multi-gigabyte file would take seconds
to read, and then be refused all the same)."""

from __future__ import annotations

from pathlib import Path

from ..errors import UserError

MAX_BYTES = 512 * 1024 * 1024
# the suffixes of the readers that call check_size (readers.READERS: read_mesh, read_cad)
CHECKED_SUFFIXES = (".stl", ".obj", ".ply", ".glb", ".gltf", ".dae", ".step", ".stp")


def check_size(path: Path) -> None:
    """UserError for a missing file or one over 512 MB (checked by stat, never read)."""
    try:
        size = Path(path).stat().st_size
    except FileNotFoundError:
        raise UserError(path, None, "file not found") from None
    except OSError as e:
        raise UserError(path, None, f"cannot read: {e.strerror}") from None
    if size > MAX_BYTES:
        raise UserError(path, None, f"file is {size / 2**20:.0f} MB, over the {MAX_BYTES // 2**20} MB limit")
    if size == 0:
        raise UserError(path, None, "file is empty")


def refusal(path: Path) -> UserError | None:
    """The error its reader would stop on at once, by the file's size, for a source
    whose reader checks it; else None."""
    if Path(path).suffix.lower() not in CHECKED_SUFFIXES:
        return None
    try:
        check_size(path)
    except UserError as e:
        return e
    return None
