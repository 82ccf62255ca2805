"""Mesh and STEP readers: units, up axis, bad files -> UserError naming the file."""

import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from pipeline.errors import UserError
from pipeline.ingest.cad import read_cad
from pipeline.ingest.mesh import read_mesh


def cfg(path, units=None, up=None, tol=0.001, scale=1.0, max_triangles=1_000_000):
    """What load_asset_config gives the readers; None leaves units and up axis to the file."""
    return SimpleNamespace(id="x", category="c", description="", source=Path(path), units=units, up_axis=up,
                           scale=scale, tessellation_tolerance_m=tol, tessellation_max_triangles=max_triangles)


def step_box_mm_yup(path):
    """A 100 x 200 x 300 mm box at (10, 20, 30) mm, written by gmsh (mm): Y is up."""
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("box")
        gmsh.model.occ.addBox(10, 20, 30, 100, 200, 300)
        gmsh.model.occ.synchronize()
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def test_step_mm_yup_lands_in_metres_zup(tmp_path):
    p = tmp_path / "box.step"
    step_box_mm_yup(p)
    a = read_cad(cfg(p, units="mm", up="Y", tol=0.0005))
    v = np.concatenate([m.mesh.vertices for _, m in a.visuals()])
    # Y-up -> Z-up: (x, y, z) -> (x, -z, y)
    np.testing.assert_allclose(v.min(axis=0), [0.01, -0.33, 0.02], atol=1e-6)
    np.testing.assert_allclose(v.max(axis=0), [0.11, -0.03, 0.22], atol=1e-6)
    assert dict(a.metadata)["tessellation_tolerance_m"] == "0.0005"
    m = next(a.visuals())[1].mesh
    tm = trimesh.Trimesh(m.vertices, m.faces)
    assert tm.volume == pytest.approx(0.1 * 0.2 * 0.3, rel=1e-6)  # outward after the rotation
    assert a.links[0].name == "base" and a.source == str(p)


def test_stl_mm_and_obj_y_up(tmp_path):
    b = trimesh.creation.box((100, 200, 300))
    b.export(tmp_path / "b.stl")
    a = read_mesh(cfg(tmp_path / "b.stl", units="mm"))
    v = a.links[0].visuals[0].mesh.vertices
    np.testing.assert_allclose(v.max(axis=0), [0.05, 0.1, 0.15])
    assert a.materials[0].name == "default"
    b.export(tmp_path / "b.obj")
    a = read_mesh(cfg(tmp_path / "b.obj", up="Y"))
    v = a.links[0].visuals[0].mesh.vertices
    np.testing.assert_allclose(v.max(axis=0), [50, 150, 100])


def test_glb_material_and_y_up(tmp_path):
    b = trimesh.creation.box((1, 2, 3))
    b.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name="steel", baseColorFactor=[255, 0, 0, 255], metallicFactor=1.0, roughnessFactor=0.25))
    trimesh.Scene(b).export(tmp_path / "s.glb")
    a = read_mesh(cfg(tmp_path / "s.glb"))
    assert a.materials[0].name == "steel" and a.materials[0].metallic == 1.0
    assert a.materials[0].base_color[0] == pytest.approx(1.0)
    v = a.links[0].visuals[0].mesh.vertices
    np.testing.assert_allclose(v.max(axis=0), [0.5, 1.5, 1.0])


def test_bad_files(tmp_path):
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(UserError, match="nan.obj.*non-finite"):
        read_mesh(cfg(nan))
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(UserError, match="empty.obj"):
        read_mesh(cfg(empty))
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(UserError, match="junk.ply"):
        read_mesh(cfg(junk))
    junk_step = tmp_path / "junk.step"
    junk_step.write_text("not a step file")
    with pytest.raises(UserError, match="junk.step"):
        read_cad(cfg(junk_step))
    big = tmp_path / "big.stl"
    with open(big, "wb") as fh:  # sparse: 2 GB apparent size, nothing written
        fh.truncate(2 * 1024**3)
    with pytest.raises(UserError, match="big.stl.*limit"):
        read_mesh(cfg(big))
    with pytest.raises(UserError, match="missing.stl"):
        read_mesh(cfg(tmp_path / "missing.stl"))
