"""The viewer task's action: the pages, twin.json and the sun table -> viewer/ but its
libraries (viewer.page)."""

from __future__ import annotations

from pathlib import Path

from .scene_record import scene_inputs


def build_viewer(staging: Path, sources: str, build: str, memo: str | None = None, memo_namespace: str = "") -> dict:
    """Task action: viewer/ but its libraries. `memo`: the cache folder whose memo
    keeps the sun tables, under `memo_namespace` (their code)."""
    from ..viewer import page
    from ..engine.memo import FileMemo

    record, manifests = scene_inputs(Path(build))
    sun_memo = None if memo is None else FileMemo(Path(memo), memo_namespace)
    return page.write(staging, sources=Path(sources), record=record, manifests=manifests, sun_memo=sun_memo)
