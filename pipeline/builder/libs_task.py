"""The viewer:libs task's action: three.js and CesiumJS from tools/node_modules ->
viewer/lib/ (viewer.libs)."""

from __future__ import annotations

from pathlib import Path


def build_libs(staging: Path) -> dict:
    """Task action: viewer/lib/."""
    from ..viewer import libs

    return libs.copy(staging)
