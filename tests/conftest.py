"""Fixtures shared across test files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def sample_build(tmp_path_factory) -> Path:
    """The sample substation built once per session into a temporary folder (never
    the repo's build/): the tests that render, label or validate it share it."""
    out = tmp_path_factory.mktemp("sample") / "build"
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "build", "--sources", str(ROOT / "sources"),
                           "--out", str(out)], capture_output=True, text=True, cwd=ROOT, timeout=3600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out


@pytest.fixture
def src(tmp_path) -> Path:
    """The toy graph's sources (tests/toy_graph.py): a.txt and b.txt."""
    d = tmp_path / "src"
    d.mkdir()
    (d / "a.txt").write_text("alpha")
    (d / "b.txt").write_text("beta")
    return d
