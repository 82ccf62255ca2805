"""What the reader has gathered from a .blend's scene so far, and the asset's
metadata made from it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ... import ir
from .objects import prop


@dataclass
class Part:
    """One visual or collision before links are assembled."""

    link: str
    obj: str
    item: ir.Visual | ir.Collision
    rest: np.ndarray  # the object's linear rest S, to map authored axes


@dataclass
class Scene:
    """What the reader has gathered from the file so far."""

    links: list[ir.Link] = field(default_factory=list)
    joints: list[ir.Joint] = field(default_factory=list)
    materials: dict[str, ir.Material] = field(default_factory=dict)
    parts: list[Part] = field(default_factory=list)
    bindings: list[ir.StateBinding] = field(default_factory=list)
    # object name -> names of its visuals (one per material), for binding targets
    visuals_of: dict[str, tuple[str, ...]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    warnings: dict[str, str] = field(default_factory=dict)  # what is not carried -> the message
    opened: dict[str, str] = field(default_factory=dict)  # external images read: path in the folder -> sha256
    # objects and visuals whose shape-key weights asset.toml's bindings drive (driven_objects)
    driven: frozenset[str] = frozenset()
    terminals: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # `terminal.<name>` empties

    def drives(self, ob) -> bool:
        """Whether a shape binding sets the object's shape-key weights."""
        if prop(ob, "state_effect") == "shape":
            return True
        return any(t == ob.name or t.startswith(f"{ob.name}__") for t in self.driven)


def driven_objects(tables) -> frozenset[str]:
    """Targets (object or visual names) of asset.toml's shape bindings."""
    return frozenset(str(t["target"]) for t in tables if t.get("effect") == "shape")


def scene_metadata(scene: Scene) -> tuple[tuple[str, str], ...]:
    """Deterministic and free of Blender's version: only what the reader decided."""
    meta = [("source_format", "blend")]
    if scene.notes:
        meta.append(("notes", "; ".join(sorted(scene.notes))))
    meta.extend((f"warning.{k}", scene.warnings[k]) for k in sorted(scene.warnings))
    if scene.opened:
        import json

        meta.append(("opened", json.dumps(scene.opened, sort_keys=True)))
    return tuple(meta)
