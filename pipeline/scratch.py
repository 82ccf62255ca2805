"""Temporary folders that worker processes leave nothing behind in.

Blender makes a `blender_*` session folder in the system temp folder when bpy is
imported and removes it only in its own exit handler, which a worker that ends with
os._exit (a build's pool worker, for a fast exit) or is killed never runs; a
renderer's scratch frame outlives its process in the same way. So each worker keeps
everything temporary in a folder of its own (TMPDIR and the tempfile module point
there before bpy is imported), removed when it exits; a pool's owner keeps those
folders in one of its own, which it removes whatever became of its workers.

An owner that is killed removes nothing, so every folder made here holds a lock file
that its owner keeps locked (flock) for as long as it lives: the kernel releases the
lock when the process ends, however it ends. Making a folder first removes the ones
of the same kind whose lock nobody holds any more.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import shutil
import tempfile
import weakref

_OWN: list[str] = []  # in a worker: the folder use_temp_folder made
_HELD: dict[str, int] = {}  # folder -> the descriptor that holds its lock
OWNER_LOCK = ".owner"


def pool_folder(prefix: str = "twin_pool_", parent: str | None = None) -> str:
    """A fresh folder in `parent` (the system temp folder) for a pool's workers (remove_with)."""
    return _locked_folder(prefix, parent)


def remove_with(owner: object, folder: str) -> None:
    """Remove `folder` when `owner` (the pool) is collected, or at exit at the latest."""
    weakref.finalize(owner, remove_folder, folder)


def use_temp_folder(parent: str | None = None) -> str:
    """In a worker process, before anything makes a temporary file: a folder of its own
    (in `parent`, or the system temp folder) for everything temporary, Blender's
    session folder included; removed at exit (remove_temp_folder for an os._exit)."""
    folder = _locked_folder("twin_worker_", parent)
    os.environ["TMPDIR"] = folder
    tempfile.tempdir = folder
    _OWN.append(folder)
    atexit.register(remove_temp_folder)
    return folder


def remove_temp_folder() -> None:
    """Remove the worker's own temp folder (an exit that skips atexit calls this first)."""
    while _OWN:
        remove_folder(_OWN.pop())


def remove_abandoned(prefix: str, parent: str | None = None) -> list[str]:
    """Remove the folders named `prefix*` in `parent` (the system temp folder) whose
    owner has ended without removing them; the removed folders."""
    root = parent or tempfile.gettempdir()
    removed = []
    try:
        entries = [e for e in os.scandir(root) if e.name.startswith(prefix) and e.is_dir(follow_symlinks=False)]
    except OSError:
        return removed
    for entry in entries:
        if entry.path in _HELD:
            continue
        try:  # no O_CREAT: a folder without its lock file is still being made, or not ours
            fd = os.open(os.path.join(entry.path, OWNER_LOCK), os.O_RDWR | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # its owner lives
        else:
            shutil.rmtree(entry.path, ignore_errors=True)
            removed.append(entry.path)
        finally:
            os.close(fd)
    return removed


def _locked_folder(prefix: str, parent: str | None) -> str:
    remove_abandoned(prefix, parent)
    folder = tempfile.mkdtemp(prefix=prefix, dir=parent)
    # locked under another name, then renamed: no other process sees the lock file unlocked
    staged = os.path.join(folder, OWNER_LOCK + ".new")
    fd = os.open(staged, os.O_CREAT | os.O_RDWR | os.O_CLOEXEC, 0o600)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.rename(staged, os.path.join(folder, OWNER_LOCK))
    _HELD[folder] = fd
    return folder


def remove_folder(folder: str) -> None:
    """Remove a folder made here, and let go of its lock."""
    shutil.rmtree(folder, ignore_errors=True)
    fd = _HELD.pop(folder, None)
    if fd is not None:
        os.close(fd)
