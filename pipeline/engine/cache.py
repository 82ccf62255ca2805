"""A content-addressed store of task outputs, keyed by task key.

Layout: <root>/<key[:2]>/<key>/files/<output paths...> and meta.json (written last).
An entry appears by one directory rename, so a build killed at any moment leaves
either a whole entry or none: never a poisoned one. Restoring copies each file to a
temporary name beside its destination and renames it into place.

A cache may be shared by builds of several build folders (`--cache DIR`), running at
once: each holds a shared lock on it while it runs (`in_use`), and only a build that
finds no other sweeps the temporary entries that killed builds left.

A cache is bounded (`prune`): a build that stored something and finds itself the
cache's only user removes the least recently used entries and memo files until the
cache is within its limit (`--cache-limit`), never an entry its own build folder
holds. Use is recorded as the mtime of an entry's meta.json and of a memo file,
renewed when either is used, so a CI job that restores the folder keeps what its
builds still use. Sizing the cache takes a walk over every file in it (thousands
for the sample), so the walk leaves its total in USAGE_FILE, every
entry and memo file stored after adds its bytes there (`add_usage`: an upper bound,
links counted whole), and a build walks the cache again only when that total is
over the limit.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import shutil
import uuid
from contextlib import contextmanager
from pathlib import Path

from ..digest import sha256_file
from ..files import atomic_path, atomic_write

CACHE_FOLDER = ".cache"  # in the build folder, unless a build is given another (--cache)
USERS_FILE = ".users"  # locked shared by every build using the cache
USAGE_FILE = ".usage"  # bytes: the last walk's total plus what was stored since (add_usage)
DEFAULT_LIMIT = 2 << 30  # bytes: room for several cold builds of the sample
MEMO_FOLDER = "memo"  # where engine.memo keeps its entries


def cache_root(build: Path, cache: Path | None = None) -> Path:
    return Path(cache) if cache is not None else Path(build) / CACHE_FOLDER


class Cache:
    def __init__(self, root: Path):
        self.root = Path(root)
        self._users: int | None = None  # the USERS_FILE descriptor while in use

    def entry(self, key: str) -> Path:
        return self.root / key[:2] / key

    def has(self, key: str) -> bool:
        return (self.entry(key) / "meta.json").is_file()

    def meta(self, key: str) -> dict:
        return json.loads((self.entry(key) / "meta.json").read_text())

    def put(self, key: str, staging: Path, result: dict) -> dict:
        """Move a finished task's staging folder into the store; returns its meta."""
        files = sorted(p for p in Path(staging).rglob("*") if p.is_file())
        meta = {
            "key": key,
            "files": {str(p.relative_to(staging)): sha256_file(p) for p in files},
            "result": result,
        }
        if self.has(key):
            shutil.rmtree(staging, ignore_errors=True)
            return self.meta(key)
        tmp = self.root / f".tmp-{uuid.uuid4().hex}"
        (tmp).mkdir(parents=True)
        text = json.dumps(meta, sort_keys=True, indent=1)
        stored = sum(p.stat().st_size for p in files) + len(text.encode())
        os.replace(staging, tmp / "files")
        (tmp / "meta.json").write_text(text)
        final = self.entry(key)
        final.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.replace(tmp, final)
            add_usage(self.root, stored)
        except OSError:  # another build stored the same key first: same content
            shutil.rmtree(tmp, ignore_errors=True)
        return meta

    def opened_by(self, base_key: str) -> list[str]:
        """The files a task of this base key (graph.Task.base_key) opened when it last
        ran into this cache (empty when unknown)."""
        try:
            names = json.loads((self.root / base_key[:2] / f"{base_key}.opened.json").read_text())
        except (OSError, ValueError):
            return []
        return [n for n in names if isinstance(n, str)] if isinstance(names, list) else []

    def keep_opened(self, base_key: str, names: list[str]) -> None:
        """Record the files a run of the task opened (a small file beside the entries,
        which pruning leaves: a later run rewrites it)."""
        try:
            atomic_write(self.root / base_key[:2] / f"{base_key}.opened.json", json.dumps(sorted(names)))
        except OSError:
            pass  # a build folder without its own record reruns the task once

    def used(self, key: str) -> None:
        """Record that a build used the entry (the last use decides what `prune` keeps)."""
        try:
            os.utime(self.entry(key) / "meta.json")
        except OSError:
            pass

    def restore(self, key: str, build: Path) -> dict:
        """Place the entry's files into `build`, each by temp-and-rename; returns meta."""
        self.used(key)
        meta = self.meta(key)
        src_root = self.entry(key) / "files"
        for rel, digest in sorted(meta["files"].items()):
            dest = Path(build) / rel
            if dest.is_file() and dest.stat().st_size == (src_root / rel).stat().st_size and sha256_file(dest) == digest:
                continue
            with atomic_path(dest) as tmp:
                shutil.copyfile(src_root / rel, tmp)
        return meta

    @contextmanager
    def in_use(self):
        """Held by a build for as long as it writes here. The first build on the cache
        sweeps what killed builds left; one that starts beside another leaves the other's
        temporary entries alone."""
        self.root.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.root / USERS_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                self.clean_tmp()
            except BlockingIOError:
                pass  # another build is writing here
            fcntl.flock(fd, fcntl.LOCK_SH)
            self._users = fd
            yield self
        finally:
            self._users = None
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def prune(self, limit: int, keep: set[str]) -> dict:
        """Remove the least recently used entries and memo files until the cache holds
        at most `limit` bytes, never the entries `keep` names (the build folder's).
        Within `in_use`, only when no other build uses the cache (nothing is taken from
        under a build that is restoring it). Files linked from several places (the
        memo's COLLADA documents) count a share of their size in each. The walk over
        the cache is spared while USAGE_FILE says it is within the limit. Returns
        {"bytes": before, "removed": count, "freed": bytes, "walked": whether it
        walked} (empty when not alone)."""
        if self._users is not None:
            try:
                fcntl.flock(self._users, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return {}
        try:
            known = _read_usage(self.root)
            if known is not None and known <= limit:
                return {"bytes": known, "removed": 0, "freed": 0, "walked": False}
            items = self._items()
            total = sum(size for _, size, _, _ in items)
            removed, freed = 0, 0
            for _, size, path, key in sorted(items):
                if total - freed <= limit:
                    break
                if key in keep:
                    continue
                self._remove(path)
                removed, freed = removed + 1, freed + size
            _write_usage(self.root, math.ceil(total - freed))
            return {"bytes": total, "removed": removed, "freed": freed, "walked": True}
        finally:
            if self._users is not None:
                fcntl.flock(self._users, fcntl.LOCK_SH)

    def _items(self) -> list[tuple[float, float, Path, str | None]]:
        """(last use, bytes, path, entry key or None for a memo file) of everything kept."""
        items = []
        for shard in _scan(self.root):
            if shard.name.startswith(".") or not shard.is_dir(follow_symlinks=False):
                continue
            for item in _scan(shard.path):
                try:
                    if shard.name == MEMO_FOLDER:
                        items += [(st.st_mtime, _share(st), Path(path), None) for path, st in _files(item.path)]
                    elif item.is_dir(follow_symlinks=False):
                        used = os.stat(os.path.join(item.path, "meta.json")).st_mtime
                        items.append((used, sum(_share(st) for _, st in _files(item.path)), Path(item.path), item.name))
                except OSError:
                    continue  # gone meanwhile, or not an entry (no meta.json)
        return items

    def _remove(self, path: Path) -> None:
        """An entry disappears by one rename (a killed prune leaves a whole entry or a
        temporary folder `clean_tmp` sweeps), a memo file by one unlink."""
        try:
            if path.is_dir():
                tmp = self.root / f".tmp-{uuid.uuid4().hex}"
                os.replace(path, tmp)
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                path.unlink()
        except OSError:
            pass

    def clean_tmp(self) -> None:
        """Remove the temporary entries killed builds left (never complete ones)."""
        if self.root.is_dir():
            for p in self.root.glob(".tmp-*"):
                if p.is_dir():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)


_USAGE_DIGITS = 20  # fixed width: each update is one write of the whole number, in place


def add_usage(root: Path, nbytes: int) -> None:
    """Add `nbytes` stored in the cache at `root` to USAGE_FILE, if a walk left one (any
    process: builds sharing the cache, their workers' memos), under a lock of its own."""
    try:
        fd = os.open(Path(root) / USAGE_FILE, os.O_RDWR)
    except OSError:
        return  # no total yet: the next prune walks the cache
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        value = int(os.pread(fd, _USAGE_DIGITS, 0)) + int(nbytes)
        os.pwrite(fd, str(value).zfill(_USAGE_DIGITS).encode(), 0)
    except (OSError, ValueError):
        pass  # unreadable: _read_usage says so, and the next prune walks
    finally:
        os.close(fd)


def _read_usage(root: Path) -> int | None:
    try:
        text = (Path(root) / USAGE_FILE).read_bytes()
        return int(text) if len(text) == _USAGE_DIGITS else None
    except (OSError, ValueError):
        return None


def _write_usage(root: Path, nbytes: int) -> None:
    try:
        atomic_write(Path(root) / USAGE_FILE, str(int(nbytes)).zfill(_USAGE_DIGITS), parents=False)
    except OSError:
        pass  # the next prune walks again


def _scan(path) -> list[os.DirEntry]:
    try:
        with os.scandir(path) as it:
            return sorted(it, key=lambda e: e.name)
    except OSError:
        return []


def _files(path: str):
    """(path, stat) of every file under a folder (os.scandir: the cache holds thousands)."""
    for entry in _scan(path):
        if entry.is_dir(follow_symlinks=False):
            yield from _files(entry.path)
        else:
            yield entry.path, entry.stat(follow_symlinks=False)


def _share(st: os.stat_result) -> float:
    """A file's share of its bytes: a file linked from n places is paid for once."""
    return st.st_size / max(1, st.st_nlink)


def parse_size(text: str) -> int:
    """Bytes of "2G", "500M", "64K" or a plain number."""
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
    text = text.strip().upper().removesuffix("B")
    scale = units.get(text[-1:], 1)
    number = float(text[:-1] if text[-1:] in units else text)
    if not 0 <= number < float("inf"):
        raise ValueError(f"not a size: {text!r}")
    return int(number * scale)
