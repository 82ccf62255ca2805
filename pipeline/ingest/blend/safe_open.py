"""Opening an untrusted .blend with nothing stored in it run.

The file is opened with Python auto-execution off, so text blocks registered to run
on load are skipped. Blender still evaluates the depsgraph while loading; with
auto-execution off it only runs a scripted driver whose bytecode passes its
whitelist (math names only): an expression calling `open` is refused, not run.
`mute_python_drivers` then mutes every Python-expression driver before the reader
evaluates anything, so such properties keep their stored values and nothing depends
on that whitelist; Blender's simple-expression drivers (no Python at all) still
work. The reader lists the muted drivers in the asset's metadata (`notes`).
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
from pathlib import Path

from ...errors import UserError
from .not_carried import _listed


@contextlib.contextmanager
def _quiet_blender():
    """Blender's C logger prints 'Read blend: ...' on file descriptor 1 for every open,
    and the driver evaluation of the load tells stderr to "enable auto-execution" for
    each Python driver it refused: the reader says what was not run in its own words
    (untrusted_code_warning), and errors still arrive as exceptions."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def open_untrusted(path: Path) -> None:
    """Load `path` as Blender's main file without running anything stored in it.

    Every open replaces the whole main database, so nothing leaks between files."""
    if not path.is_file():
        raise UserError(path, None, "file not found")
    import bpy

    # Both switches: the preference governs later reloads, `use_scripts=False` this
    # load; with them off Blender runs no registered text block, and no driver
    # expression beyond its math-only whitelist (mute_python_drivers mutes those too).
    bpy.context.preferences.filepaths.use_scripts_auto_execute = False
    try:
        with _quiet_blender():
            bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False, use_scripts=False)
    except RuntimeError as e:
        reason = str(e).strip().splitlines()[0] if str(e).strip() else "unreadable"
        reason = reason.removeprefix("Error: ")
        saved = header_version(path)
        if saved is not None and saved > tuple(bpy.app.version[:2]):
            reason += (f" (saved by Blender {saved[0]}.{saved[1]}, newer than the Blender "
                       f"{bpy.app.version_string} reading it)")
        raise UserError(path, None, f"not a readable .blend file (truncated or corrupt?): {reason}") from None


_HEADER = re.compile(rb"^BLENDER(?:[-_][vV](\d)(\d\d)|\d\d-\d\d[vV](\d\d)(\d\d))")


def header_version(path: Path) -> tuple[int, int] | None:
    """(major, minor) Blender version in an uncompressed .blend's header, e.g.
    BLENDER-v279 (2.79) or BLENDER17-01v0500 (5.0); None when compressed or not one."""
    with open(path, "rb") as fh:
        head = fh.read(17)
    m = _HEADER.match(head)
    if m is None:
        return None
    major, minor = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    return int(major), int(minor)


# ID collections whose blocks can carry drivers (animation_data).
_ANIMATABLE = (
    "objects", "meshes", "shape_keys", "materials", "node_groups", "scenes", "curves",
    "lights", "cameras", "worlds", "textures", "armatures", "lattices", "metaballs",
)


def mute_python_drivers() -> list[str]:
    """Mute every scripted driver that is not a simple expression; returns them as
    `<id name>.<data path>[<index>]`, sorted."""
    import bpy

    owners = []
    for attr in _ANIMATABLE:
        for block in getattr(bpy.data, attr, ()):
            owners.append(block)
            tree = getattr(block, "node_tree", None)
            if tree is not None:
                owners.append(tree)
    muted = []
    for block in owners:
        ad = getattr(block, "animation_data", None)
        if ad is None:
            continue
        for fc in ad.drivers:
            if fc.driver.type == "SCRIPTED" and not fc.driver.is_simple_expression and not fc.mute:
                fc.mute = True
                muted.append(f"{block.name}.{fc.data_path}[{fc.array_index}]")
    if muted:
        bpy.context.evaluated_depsgraph_get().update()
    return sorted(muted)


def untrusted_code_warning(path: Path, muted: list[str]) -> dict[str, str]:
    """One warning naming the file, when it holds Python that was not run: the
    drivers mute_python_drivers muted and the text blocks registered to run on load."""
    import bpy

    texts = sorted(t.name for t in bpy.data.texts if t.use_module)
    if not muted and not texts:
        return {}
    what = []
    if muted:
        what.append(f"{len(muted)} Python driver{'s' if len(muted) > 1 else ''} ({_listed(muted)})")
    if texts:
        what.append(f"{len(texts)} script{'s' if len(texts) > 1 else ''} set to run on load ({_listed(texts)})")
    was = "was" if len(muted) + len(texts) == 1 else "were"
    return {"scripts": f"{path.name}: its {' and '.join(what)} {was} not run: code inside a source file is "
                       "untrusted input, so the build never runs it; driven properties keep the values saved "
                       "in the file"}

