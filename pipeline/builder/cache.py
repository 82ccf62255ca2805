"""A content-addressed store of task outputs, keyed by task key.

Layout: <root>/<key[:2]>/<key>/files/<output paths...> and meta.json (written last).
An entry appears by one directory rename, so a build killed at any moment leaves
either a whole entry or none: never a poisoned one. Restoring copies each file to a
temporary name beside its destination and renames it into place.

A cache may be shared by builds of several build folders (`--cache DIR`), running at
once: each holds a shared lock on it while it runs (`in_use`), and only a build that
finds no other sweeps the temporary entries that killed builds left.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import uuid
from contextlib import contextmanager
from pathlib import Path

from ..digest import sha256_file

CACHE_FOLDER = ".cache"  # in the build folder, unless a build is given another (--cache)
USERS_FILE = ".users"  # locked shared by every build using the cache


def cache_root(build: Path, cache: Path | None = None) -> Path:
    return Path(cache) if cache is not None else Path(build) / CACHE_FOLDER


class Cache:
    def __init__(self, root: Path):
        self.root = Path(root)

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
        os.replace(staging, tmp / "files")
        (tmp / "meta.json").write_text(json.dumps(meta, sort_keys=True, indent=1))
        final = self.entry(key)
        final.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.replace(tmp, final)
        except OSError:  # another build stored the same key first: same content
            shutil.rmtree(tmp, ignore_errors=True)
        return meta

    def restore(self, key: str, build: Path) -> dict:
        """Place the entry's files into `build`, each by temp-and-rename; returns meta."""
        meta = self.meta(key)
        src_root = self.entry(key) / "files"
        for rel, digest in sorted(meta["files"].items()):
            dest = Path(build) / rel
            if dest.is_file() and dest.stat().st_size == (src_root / rel).stat().st_size and sha256_file(dest) == digest:
                continue
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.with_name(f".{dest.name}.tmp-{uuid.uuid4().hex[:8]}")
            shutil.copyfile(src_root / rel, tmp)
            os.replace(tmp, dest)
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
            yield self
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def clean_tmp(self) -> None:
        """Remove leftovers of killed builds (never complete entries; memo files too)."""
        if self.root.is_dir():
            for p in self.root.glob(".tmp-*"):
                if p.is_dir():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
