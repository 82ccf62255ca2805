"""What a source's numbers mean: its length unit and up axis (DESIGN.md s.2, s.3).

A reader says what its file declares (None where it declares nothing) and gets a
`Frame`: asset.toml `units` and `up_axis` override the file's own, `scale` multiplies
after units. `Frame.matrix()` takes file coordinates to model metres, Z up;
`transform_asset` does the same to an asset that has links, joints and bindings.
Everything here is plain numpy on ir dataclasses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import ir

METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}

# Proper rotations taking each up axis to +Z: Y-up turns +90 deg about X ((x, y, z) ->
# (x, -z, y)), X-up -90 deg about Y ((x, y, z) -> (-z, y, x)).
UP_TO_Z = {
    "Z": np.eye(3),
    "Y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "X": np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
}


@dataclass(frozen=True)
class Frame:
    """metres_per_unit: of the file's numbers; units_from / up_from: "asset.toml",
    "file" (declared in it) or "default" (the format's convention, or metres and Z for
    a format that declares nothing); scale: asset.toml's factor after units."""

    metres_per_unit: float
    units_from: str
    up_axis: str
    up_from: str
    scale: float = 1.0

    @property
    def factor(self) -> float:
        return self.metres_per_unit * self.scale

    @property
    def rotation(self) -> np.ndarray:
        return UP_TO_Z[self.up_axis]

    def matrix(self) -> np.ndarray:
        """(4, 4) float64 from file coordinates to model metres, Z up."""
        m = np.eye(4)
        m[:3, :3] = self.rotation * self.factor
        return m

    @property
    def is_identity(self) -> bool:
        return self.factor == 1.0 and self.up_axis == "Z"

    def metadata(self) -> tuple[tuple[str, str], ...]:
        """What the reader decided, for the manifest; nothing for metres, Z up."""
        if self.is_identity and "asset.toml" not in (self.units_from, self.up_from):
            return ()
        return (
            ("units_m", f"{self.metres_per_unit!r} ({self.units_from})"),
            ("scale", repr(self.scale)),
            ("up_axis", f"{self.up_axis} ({self.up_from})"),
        )


def resolve(cfg, file_metres: float | None, file_up: str | None, default_up: str = "Z") -> Frame:
    """The frame of cfg.source: asset.toml's units and up_axis where given, else the
    file's, else metres and `default_up`."""
    units = getattr(cfg, "units", None)
    up = getattr(cfg, "up_axis", None)
    if units is not None:
        metres, units_from = METRES[units], "asset.toml"
    elif file_metres is not None:
        metres, units_from = float(file_metres), "file"
    else:
        metres, units_from = 1.0, "default"
    if up is not None:
        up_axis, up_from = up, "asset.toml"
    elif file_up is not None:
        up_axis, up_from = file_up, "file"
    else:
        up_axis, up_from = default_up, "default"
    return Frame(metres, units_from, up_axis, up_from, float(getattr(cfg, "scale", 1.0)))


def _rigid(pose: np.ndarray, factor: float, rotation: np.ndarray | None) -> np.ndarray:
    """A pose with its translation scaled, then (a model-frame pose) turned."""
    p = np.array(pose, dtype=np.float64)
    p[:3, 3] *= factor
    if rotation is not None:
        r = np.eye(4)
        r[:3, :3] = rotation
        p = r @ p
    return p


def _mesh(mesh: ir.Mesh, factor: float) -> ir.Mesh:
    keys = tuple(ir.ShapeKey(k.name, k.vertices * factor) for k in mesh.shape_keys)
    return replace(mesh, vertices=mesh.vertices * factor, shape_keys=keys)


def transform_asset(asset: ir.Asset, frame: Frame) -> ir.Asset:
    """The asset in model metres, Z up: every length times frame.factor (vertices, shape
    keys, pose translations, prismatic limits and speeds, translate ranges), and the
    model frame turned by frame.rotation. A uniform scale and a proper rotation keep
    every visual's frame rigid and every face's winding."""
    if frame.is_identity:
        return asset
    f, rot = frame.factor, frame.rotation
    links = tuple(
        replace(
            link,
            pose=_rigid(link.pose, f, rot),
            visuals=tuple(replace(v, pose=_rigid(v.pose, f, None), lods=tuple(_mesh(m, f) for m in v.lods))
                          for v in link.visuals),
            collisions=tuple(replace(c, pose=_rigid(c.pose, f, None), mesh=_mesh(c.mesh, f)) for c in link.collisions),
        )
        for link in asset.links
    )
    joints = []
    for j in asset.joints:
        lengths = j.type == "prismatic"
        joints.append(replace(
            j,
            pose=_rigid(j.pose, f, rot),
            lower=j.lower * f if lengths and j.lower is not None else j.lower,
            upper=j.upper * f if lengths and j.upper is not None else j.upper,
            velocity=j.velocity * f if lengths and j.velocity is not None else j.velocity,
        ))
    bindings = tuple(replace(b, range=(b.range[0] * f, b.range[1] * f)) if b.effect == "translate" else b
                     for b in asset.bindings)
    terminals = tuple((n, tuple(float(v) for v in rot @ np.asarray(p) * f)) for n, p in asset.terminals)
    return asset.with_(links=links, joints=tuple(joints), bindings=bindings, terminals=terminals)
