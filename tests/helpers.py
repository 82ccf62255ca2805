"""Helpers the test files share (conftest.py holds the fixtures built on them): the
`twin` command in a fresh process, hashes of a build's files, and a folder made once
per test run whichever pytest-xdist worker asks for it first."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import traceback
from pathlib import Path
from typing import Callable

import pytest
from filelock import FileLock

ROOT = Path(__file__).resolve().parent.parent  # the checkout
SOURCES = ROOT / "sources"  # the sample's sources
TESTS = ROOT / "tests"  # the helpers and fixtures test files import or run as scripts
DATA = TESTS / "data"  # small hand-made fixtures: bad/ and clean/
# public test files beside the checkout, when there (a worktree in /work/wt/<name> has
# them one folder further up)
CORPUS = next((p / "shared" / "corpus" for p in (ROOT.parent, ROOT.parent.parent) if (p / "shared" / "corpus").is_dir()),
              ROOT.parent / "shared" / "corpus")


def unavailable(message: str) -> None:
    """A tool the test needs is not here: skipped, failed in CI (which installs them all)."""
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


def twin(*args, cwd: Path | None = ROOT, timeout: float = 1800, env: dict | None = None) -> subprocess.CompletedProcess:
    """`twin ARGS` in a fresh interpreter (this one, the checkout's pipeline), its
    output captured as text; `env`: its environment (default: this one's)."""
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=env)


def tree_hashes(out: Path, *folders: str) -> dict[str, str]:
    """sha256 of every file a user gets under `out` (under its `folders` when given),
    by path relative to `out`; the build's hidden bookkeeping at its top (the cache,
    the state) is left out."""
    roots = [out / f for f in folders] if folders else [out]
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for root in roots for p in sorted(root.rglob("*"))
            if p.is_file() and not p.relative_to(out).parts[0].startswith(".")}


def digest(*paths: Path) -> str:
    """One sha256 over the files under `paths` (names and bytes), caches skipped."""
    h = hashlib.sha256()
    for top in paths:
        files = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file())
        for p in files:
            if "__pycache__" in p.parts:
                continue
            h.update(str(p.relative_to(top.parent)).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def shared_root(tmp_path_factory) -> Path:
    """The temporary folder every worker of this run sees: under pytest-xdist a folder
    beside the workers' own base folders (one per run), else the run's base folder.
    Either way at the depth of a test's base folder, so that a made folder and a
    test's copy of it (tmp_path/<name>) sit equally deep: a build task's key holds
    the paths of its inputs relative to the build folder, the checkout's
    tools/node_modules among them, and a copy keeps its keys only at the same depth."""
    base = tmp_path_factory.getbasetemp()
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return base
    (base.parent / "shared").mkdir(exist_ok=True)
    return base.parent / "shared"


def made_once(tmp_path_factory, name: str, inputs: list[Path], make: Callable[[Path], None]) -> Path:
    """A folder `make(folder)` fills once per test run, named after `name` and the
    inputs' hash. The first worker to ask makes it under a file lock; the others wait
    and share it (read only). A failed make is recorded so that every later asker
    fails at once with the same message instead of making it again."""
    folder = shared_root(tmp_path_factory) / f"{name}-{digest(*inputs)[:16]}"
    done, failed = folder.with_name(folder.name + ".done"), folder.with_name(folder.name + ".failed")
    with FileLock(str(folder) + ".lock"):
        if failed.exists():
            raise AssertionError(f"{name}, made by another worker, failed:\n{failed.read_text()}")
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir(parents=True)
            try:
                make(folder)
            except BaseException:
                failed.write_text(traceback.format_exc()[-6000:])
                raise
            done.touch()
    return folder
