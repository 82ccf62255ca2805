"""The structural, CAD and mesh sample assets (sources/authoring/ASSETS.md): the STEP and
STL scripts reproduce their committed files byte for byte, the files load with the
stated extents and faults, every asset.toml loads, and two .blend assets regenerate to
the same content."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOT
from pipeline.config import load_asset_config

AUTHORING = ROOT / "sources" / "authoring"
ASSETS = ROOT / "sources" / "assets"

CAD_IDS = ["surge_arrester", "post_insulator"]
BLEND_IDS = ["busbar_support", "rigid_busbar", "gantry", "lightning_mast", "lighting_pole",
             "control_house", "fence_segment", "wave_trap"]
ALL_IDS = CAD_IDS + ["junction_box"] + BLEND_IDS


def author(asset_id: str, out: Path) -> None:
    """Run sources/authoring/<asset_id>.py writing into `out`, as make_all.py would."""
    subprocess.run([sys.executable, str(AUTHORING / f"{asset_id}.py"), "--out", str(out)],
                   check=True, capture_output=True, cwd=AUTHORING)


def source_file(asset_id: str) -> Path:
    return load_asset_config(ASSETS / asset_id / "asset.toml").source


# --- byte-identical regeneration -------------------------------------------------------


@pytest.mark.parametrize("asset_id", CAD_IDS + ["junction_box"])
def test_script_reproduces_committed_file(asset_id, tmp_path):
    author(asset_id, tmp_path)
    committed = source_file(asset_id)
    regenerated = tmp_path / asset_id / committed.name
    assert regenerated.read_bytes() == committed.read_bytes()
    assert (tmp_path / asset_id / "asset.toml").read_text() == (ASSETS / asset_id / "asset.toml").read_text()


def test_step_header_is_pinned():
    text = source_file("surge_arrester").read_text()
    header = text[: text.index("ENDSEC;")]
    assert "FILE_NAME('surge_arrester.step','2025-01-01T00:00:00'" in header


# --- STEP content ----------------------------------------------------------------------


def tessellate(step: Path, tmp_path: Path, tolerance_mm: float):
    """The STEP file as one trimesh scene, through cascadio (OpenCASCADE). The GLB it
    writes is in metres whatever the STEP unit: OpenCASCADE converts on reading."""
    import cascadio
    import trimesh

    glb = tmp_path / (step.stem + ".glb")
    cascadio.step_to_glb(str(step), str(glb), tol_linear=tolerance_mm, tol_angular=0.5)
    return trimesh.load(str(glb))


@pytest.mark.parametrize("asset_id, size_m, up_index", [
    ("surge_arrester", (0.7, 5.0, 0.7), 1),   # Y up
    ("post_insulator", (0.4, 0.4, 4.0), 2),   # Z up
])
def test_step_loads_with_expected_extents(asset_id, size_m, up_index, tmp_path):
    cfg = load_asset_config(ASSETS / asset_id / "asset.toml")
    assert cfg.units == "mm"
    assert cfg.up_axis == ("Y" if up_index == 1 else "Z")
    step_text = cfg.source.read_text()
    assert "SI_UNIT(.MILLI.,.METRE.)" in step_text
    scene = tessellate(cfg.source, tmp_path, cfg.tessellation_tolerance_m * 1000.0)
    lo, hi = scene.bounds
    assert np.allclose(hi - lo, size_m, atol=0.002)
    assert lo[up_index] == pytest.approx(0.0, abs=1e-6)   # stands on the ground
    triangles = sum(len(g.faces) for g in scene.geometry.values())
    assert 20_000 <= triangles <= 80_000


def test_step_loads_through_trimesh():
    import trimesh

    scene = trimesh.load(str(source_file("post_insulator")), file_type="step")
    assert len(scene.geometry) > 30           # separate solids: flanges, core, sheds
    assert scene.extents[2] == pytest.approx(4.0, abs=0.002)


# --- STL faults ------------------------------------------------------------------------


def read_binary_stl(path: Path) -> np.ndarray:
    """(m, 3, 3) float32 triangle corners of a binary STL, read with numpy."""
    raw = path.read_bytes()
    count = int(np.frombuffer(raw, "<u4", 1, 80)[0])
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
    assert len(raw) == 84 + count * record.itemsize
    return np.frombuffer(raw, record, count, 84)["corners"]


def test_stl_has_unwelded_facets_and_three_slivers():
    tris = read_binary_stl(source_file("junction_box"))
    corners = tris.reshape(-1, 3)
    unique, index = np.unique(corners, axis=0, return_inverse=True)
    faces = index.reshape(-1, 3)
    # Unwelded: far more corner records than distinct points.
    assert len(unique) < len(corners) / 3
    areas = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    assert int((areas < 1e-9).sum()) == 3
    # The slivers are collinear, not collapsed: no face repeats a welded index.
    assert not np.any((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2]))
    assert 2_000 <= len(tris) <= 10_000
    assert np.allclose(corners.max(axis=0) - corners.min(axis=0), (0.9, 0.6, 1.6), atol=1e-4)
    assert corners[:, 2].min() == pytest.approx(0.0, abs=1e-6)


def test_stl_shells_face_outwards():
    import trimesh

    mesh = trimesh.load(str(source_file("junction_box")))   # welds on load
    shells = mesh.split(only_watertight=True)
    assert len(shells) > 40
    assert all(s.volume > 0 for s in shells)


# --- asset.toml ------------------------------------------------------------------------


@pytest.mark.parametrize("asset_id", ALL_IDS)
def test_asset_toml_loads(asset_id):
    cfg = load_asset_config(ASSETS / asset_id / "asset.toml")
    assert cfg.id == asset_id
    assert cfg.source.is_file()
    assert cfg.source.stem == asset_id
    assert cfg.source.stat().st_size < 1_000_000


# --- .blend content --------------------------------------------------------------------


def blend_digest(path: Path) -> str:
    """digest_blend of helper A's digest.py, in a fresh process (bpy holds one file)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from digest import digest_blend; "
            "print(digest_blend(sys.argv[2]))")
    done = subprocess.run([sys.executable, "-c", code, str(AUTHORING), str(path)],
                          check=True, capture_output=True, text=True)
    digest = done.stdout.strip().splitlines()[-1]
    assert len(digest) == 64  # a sha256 hex digest, not an error message
    return digest


@pytest.mark.blender
@pytest.mark.parametrize("asset_id", ["rigid_busbar", "lighting_pole"])
def test_blend_regenerates_same_content(asset_id, tmp_path):
    pytest.importorskip("bpy")
    author(asset_id, tmp_path)
    committed = ASSETS / asset_id / f"{asset_id}.blend"
    assert blend_digest(tmp_path / asset_id / f"{asset_id}.blend") == blend_digest(committed)
