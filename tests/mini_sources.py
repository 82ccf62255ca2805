"""A small sources folder made from scratch, for end-to-end tests of the build.

Two levels, two mesh assets (an STL kiosk with unwelded facets and an OBJ pole), a
handful of INSERTs in a drawing rotated against grid north, one inspection point.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import ezdxf
import numpy as np
import trimesh

SITE = """
[site]
name = "mini"
floorplan = "floorplan/plan.dxf"
date = "2025-06-21"
timezone = "America/Bahia"
[plan]
crs = "EPSG:31984"
grid_origin = [{e0}, {n0}]
grid_rotation_deg = {rot}
grid_scale = {scale!r}
[[levels]]
name = "L1"
elevation = 48.0
[[levels]]
name = "L2"
elevation = 51.0
[terrain]
slope_ratio = 1.5
[lod]
screen_tolerance_px = 1.0
[[inspection_points]]
name = "eye"
position = [4.0, -6.0, 1.6]
level = "L1"
"""

PLACEMENTS = [  # tag, asset, level, x, y, z, rotation
    ("K-1", "kiosk", "L1", 0.0, 0.0, 0.0, 0.0),
    ("K-2", "kiosk", "L1", 8.0, 0.0, 0.0, 90.0),
    ("K-3", "kiosk", "L1", 16.0, 0.0, 0.3, 180.0),
    ("P-1", "pole", "L1", 4.0, 6.0, 0.0, 0.0),
    ("P-2", "pole", "L2", 4.0, 40.0, 0.0, 45.0),
    ("K-4", "kiosk", "L2", 12.0, 40.0, 0.0, 270.0),
]


def kiosk_mesh() -> trimesh.Trimesh:
    body = trimesh.creation.box(extents=(0.9, 0.6, 1.4))
    body.apply_translation((0, 0, 0.7))
    roof = trimesh.creation.box(extents=(1.0, 0.7, 0.08))
    roof.apply_translation((0, 0, 1.44))
    mesh = trimesh.util.concatenate([body, roof])
    # unwelded facets, as CAD exports them
    return trimesh.Trimesh(mesh.triangles.reshape(-1, 3), np.arange(len(mesh.faces) * 3).reshape(-1, 3), process=False)


def pole_mesh() -> trimesh.Trimesh:
    pole = trimesh.creation.cylinder(radius=0.12, height=8.0, sections=48)
    pole.apply_translation((0, 0, 4.0))
    head = trimesh.creation.icosphere(subdivisions=3, radius=0.35)
    head.apply_translation((0, 0, 8.2))
    return trimesh.util.concatenate([pole, head])


def write_plan(path: Path, placements=PLACEMENTS, units: int = 6, extra=None) -> None:
    scale = 1000.0 if units == 4 else 1.0
    doc = ezdxf.new("R2018", setup=False)
    doc.header["$INSUNITS"] = units
    msp = doc.modelspace()
    for name in sorted({p[1] for p in placements}):
        blk = doc.blocks.new(name)
        for tag in ("TAG", "LEVEL", "STATE"):
            blk.add_attdef(tag, (0, 0))
    for tag, asset, level, x, y, z, rot in placements:
        ins = msp.add_blockref(asset, (x * scale, y * scale, z * scale), dxfattribs={"rotation": rot})
        ins.add_attrib("TAG", tag)
        ins.add_attrib("LEVEL", level)
    for level, (x0, y0, x1, y1) in {"L1": (-4, -10, 22, 12), "L2": (-4, 30, 22, 50)}.items():
        pts = [(x0 * scale, y0 * scale), (x1 * scale, y0 * scale), (x1 * scale, y1 * scale), (x0 * scale, y1 * scale)]
        msp.add_lwpolyline(pts, close=True, dxfattribs={"layer": f"PLATFORM_{level}"})
    msp.add_text("note", dxfattribs={"layer": "ANNOTATION"})
    if extra:
        extra(msp)
    doc.saveas(path)


def make(root: Path, rotation_deg: float = 23.0, units: int = 6, e0: float = 561234.5, n0: float = 8595432.25,
         grid_scale: float = 1.0) -> Path:
    root = Path(root)
    (root / "floorplan").mkdir(parents=True, exist_ok=True)
    (root / "site.toml").write_text(textwrap.dedent(SITE.format(e0=e0, n0=n0, rot=rotation_deg, scale=grid_scale)))
    write_plan(root / "floorplan" / "plan.dxf", units=units)
    for asset, mesh, ext, category in (("kiosk", kiosk_mesh(), "stl", "kiosk"), ("pole", pole_mesh(), "obj", "pole")):
        d = root / "assets" / asset
        d.mkdir(parents=True, exist_ok=True)
        mesh.export(d / f"{asset}.{ext}")
        (d / "asset.toml").write_text(
            f'category = "{category}"\nsource = "{asset}.{ext}"\n[lod]\nbudgets_m = [0.004, 0.02]\n')
    return root
