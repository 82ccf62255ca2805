"""What the tasks after the scene read of it: placements.json and the placed models'
manifests."""

from __future__ import annotations

import json
from pathlib import Path


def scene_inputs(build: Path) -> tuple[dict, dict]:
    """placements.json and the placed models' manifests of a built scene."""
    from ..export import manifest

    record = json.loads((build / "scene" / "placements.json").read_text())
    used = sorted({p["asset"] for p in record["placements"]})
    return record, {a: manifest.read(build / "models" / a) for a in used}
