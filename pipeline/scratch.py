"""Temporary folders that worker processes leave nothing behind in.

Blender makes a `blender_*` session folder in the system temp folder when bpy is
imported and removes it only in its own exit handler, which a worker that ends with
os._exit (a build's pool worker, for a fast exit) or is killed never runs; a
renderer's scratch frame outlives its process in the same way. So each worker keeps
everything temporary in a folder of its own (TMPDIR and the tempfile module point
there before bpy is imported), removed when it exits; a pool's owner keeps those
folders in one of its own, which it removes whatever became of its workers.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import weakref

_OWN: list[str] = []  # in a worker: the folder use_temp_folder made


def pool_folder(prefix: str = "twin_pool_") -> str:
    """A fresh folder in the system temp folder for a pool's workers (remove_with)."""
    return tempfile.mkdtemp(prefix=prefix)


def remove_with(owner: object, folder: str) -> None:
    """Remove `folder` when `owner` (the pool) is collected, or at exit at the latest."""
    weakref.finalize(owner, shutil.rmtree, folder, True)


def use_temp_folder(parent: str | None = None) -> str:
    """In a worker process, before anything makes a temporary file: a folder of its own
    (in `parent`, or the system temp folder) for everything temporary, Blender's
    session folder included; removed at exit (remove_temp_folder for an os._exit)."""
    folder = tempfile.mkdtemp(prefix="twin_worker_", dir=parent)
    os.environ["TMPDIR"] = folder
    tempfile.tempdir = folder
    _OWN.append(folder)
    atexit.register(remove_temp_folder)
    return folder


def remove_temp_folder() -> None:
    """Remove the worker's own temp folder (an exit that skips atexit calls this first)."""
    while _OWN:
        shutil.rmtree(_OWN.pop(), ignore_errors=True)
