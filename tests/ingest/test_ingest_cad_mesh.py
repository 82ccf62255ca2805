"""Mesh and STEP readers: units, up axis, bad files -> UserError naming the file."""

import os
import signal
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from helpers import CORPUS
from pipeline.errors import UserError
from pipeline.ingest.cad import read_cad
from pipeline.ingest.mesh import read_mesh


def cfg(path, units=None, up=None, tol=0.001, scale=1.0, max_triangles=1_000_000):
    """What load_asset_config gives the readers; None leaves units and up axis to the file."""
    return SimpleNamespace(id="x", category="c", description="", source=Path(path), units=units, up_axis=up,
                           scale=scale, tessellation_tolerance_m=tol, tessellation_max_triangles=max_triangles)


def step_box_mm_yup(path):
    """A 100 x 200 x 300 mm box at (10, 20, 30) mm, written by gmsh (mm): Y is up."""
    gmsh_step(path, lambda occ: occ.addBox(10, 20, 30, 100, 200, 300))


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


# --- real inputs: the corpus, in a sources tree as a user lays it out -------------------

corpus = pytest.mark.skipif(not CORPUS.is_dir(), reason="needs ../shared/corpus")


def asset_tree(root: Path, asset_id: str, files: list[Path], toml: str):
    """sources/assets/<asset_id>/ in `root` holding copies of `files` and `toml`; its
    asset.toml loaded as the build loads it."""
    import shutil

    from pipeline.config import load_asset_config

    folder = root / "sources" / "assets" / asset_id
    folder.mkdir(parents=True, exist_ok=True)
    for f in files:
        shutil.copy(f, folder / f.name)
    (folder / "asset.toml").write_text(toml)
    return load_asset_config(folder / "asset.toml")


def read(cfg):
    from pipeline.ingest.readers import read_source

    return read_source(cfg)


def model_points(asset) -> np.ndarray:
    """(n, 3) every visual vertex in the model frame."""
    return np.concatenate([v.mesh.vertices @ (link.pose @ v.pose)[:3, :3].T + (link.pose @ v.pose)[:3, 3]
                           for link, v in asset.visuals()])


def extents(asset) -> np.ndarray:
    p = model_points(asset)
    return p.max(axis=0) - p.min(axis=0)


def carried(asset) -> list[str]:
    """The HIER013 messages the checks give the asset (what reaches the report)."""
    from pipeline.validate.checks import check_asset

    return [f.message for f in check_asset(asset) if f.code == "HIER013"]


POLE = CORPUS / "mesh" / "telephone_pole" / "meshes" / "telephone_pole.dae"
POLE_SIZE = np.array([2.116, 0.235, 9.223])  # the corpus README's, COLLADA inches, Z up


@corpus
@pytest.mark.parametrize("extra, expected", [
    ("", POLE_SIZE),                                          # <unit meter="0.0254"> and <up_axis>Z_UP</up_axis>
    ('units = "cm"\n', POLE_SIZE / 0.0254 * 0.01),            # asset.toml's unit over the file's
    ('scale = 0.5\n', POLE_SIZE * 0.5),                       # scale after the file's unit
    ('units = "ft"\nscale = 2.0\n', POLE_SIZE / 0.0254 * 0.3048 * 2.0),
    ('up_axis = "Y"\n', POLE_SIZE[[0, 2, 1]]),                # a Y-up override: (x, y, z) -> (x, -z, y)
    ('up_axis = "X"\n', POLE_SIZE[[2, 1, 0]]),                # X up: (x, y, z) -> (-z, y, x)
])
def test_collada_unit_and_up_axis(tmp_path, extra, expected):
    import shutil

    cfg = asset_tree(tmp_path, "pole", [POLE], f'category = "pole"\nsource = "telephone_pole.dae"\n{extra}')
    shutil.copytree(POLE.parents[1] / "materials", cfg.folder / "materials")  # its images, as Gazebo lays them out
    asset = read(cfg)
    np.testing.assert_allclose(extents(asset), expected, rtol=1e-3)
    assert carried(asset) == []  # nothing in the file goes uncarried


@corpus
def test_collada_frame_is_recorded(tmp_path):
    cfg = asset_tree(tmp_path, "pole", [POLE], 'category = "pole"\nsource = "telephone_pole.dae"\n')
    meta = dict(read(cfg).metadata)
    assert meta["units_m"] == "0.0254 (file)" and meta["up_axis"] == "Z (file)"


def _y_up(v: np.ndarray) -> np.ndarray:
    return np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])


@corpus
@pytest.mark.parametrize("up, expected", [(None, (4.869, 2.792, 2.583)), ("Z", (4.869, 2.583, 2.792))])
def test_glb_is_y_up_unless_asset_toml_says(tmp_path, up, expected):
    toml = 'category = "truck"\nsource = "CesiumMilkTruck.glb"\n' + (f'up_axis = "{up}"\n' if up else "")
    cfg = asset_tree(tmp_path, "truck", [CORPUS / "mesh" / "CesiumMilkTruck.glb"], toml)
    asset = read(cfg)
    np.testing.assert_allclose(extents(asset), expected, rtol=1e-3)
    assert len(list(asset.visuals())) == 5  # three body primitives, two wheel instances
    (warning,) = carried(asset)
    assert warning.startswith("1 glTF animations are not carried")


def _gltf_arrays(path: Path) -> tuple[np.ndarray, list[np.ndarray], list[float]]:
    """The SimpleMorph file's base positions, target offsets and default weights, read
    with json and numpy alone (float VEC3 accessors in base64 buffers)."""
    import base64
    import json

    doc = json.loads(path.read_text())
    buffers = [base64.b64decode(b["uri"].split(",", 1)[1]) for b in doc["buffers"]]

    def vec3(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        stride = view.get("byteStride", 12)
        raw = buffers[view["buffer"]]
        return np.array([np.frombuffer(raw, np.float32, 3, start + k * stride) for k in range(acc["count"])],
                        dtype=np.float64)

    prim = doc["meshes"][0]["primitives"][0]
    return vec3(prim["attributes"]["POSITION"]), [vec3(t["POSITION"]) for t in prim["targets"]], \
        doc["meshes"][0]["weights"]


@corpus
def test_gltf_morph_targets_are_shape_keys_at_their_default_weights(tmp_path):
    src = CORPUS / "mesh" / "simple_morph" / "SimpleMorph.gltf"
    cfg = asset_tree(tmp_path, "morph", [src], 'category = "test"\nsource = "SimpleMorph.gltf"\n')
    asset = read(cfg)
    base, offsets, weights = _gltf_arrays(src)
    assert weights == [0.5, 0.5]
    (_, visual), = asset.visuals()
    mesh = visual.mesh
    # the rest mesh is what the file shows (its default weights), Y up turned to Z up
    np.testing.assert_allclose(mesh.vertices, _y_up(base + 0.5 * offsets[0] + 0.5 * offsets[1]), atol=1e-9)
    assert [k.name for k in mesh.shape_keys] == ["mesh0_target0", "mesh0_target1"]
    for key, offset in zip(mesh.shape_keys, offsets):
        np.testing.assert_allclose(key.vertices, _y_up(base + offset), atol=1e-9)
    assert "morph weights [0.5, 0.5] make its rest mesh" in dict(asset.metadata)["notes"]
    (warning,) = carried(asset)
    assert warning.startswith("1 glTF animations are not carried")


@corpus
def test_step_in_millimetres_with_density_in_centimetres(tmp_path):
    """as1: geometry contexts in mm; the cm units it also declares are its densities'."""
    from pipeline.ingest.cad import step_length_units

    src = CORPUS / "step" / "as1-oc-214-mat.stp"
    cfg = asset_tree(tmp_path, "as1", [src], 'category = "test"\nsource = "as1-oc-214-mat.stp"\n')
    assert step_length_units(cfg.source) == (0.001,)
    asset = read(cfg)
    np.testing.assert_allclose(extents(asset), (0.200, 0.150, 0.084), rtol=1e-3)
    assert len(list(asset.visuals())) == 18  # 5 solids instanced into 18 parts


@corpus
def test_step_in_inches_surface_model(tmp_path):
    src = CORPUS / "step" / "trj4_k1_top-tc-214.stp"
    toml = 'category = "test"\nsource = "trj4_k1_top-tc-214.stp"\ntessellation_tolerance_m = 1e-5\n'
    asset = read(asset_tree(tmp_path, "trj4", [src], toml))
    np.testing.assert_allclose(extents(asset), (0.127, 0.0483, 0.0127), rtol=1e-3)
    meta = dict(asset.metadata)
    assert meta["step_units_m"] == "0.0254" and meta["tessellation_tolerance_m"] == "1e-05"


# --- generated hard cases: every unit, a feet file, the guard, the memory limit --------

_MM_UNIT = __import__("re").compile(
    r"\(\s*LENGTH_UNIT\(\)\s*NAMED_UNIT\(\*\)\s*SI_UNIT\(\.MILLI\.,\s*\.METRE\.\)\s*\)")
_CONVERSIONS = {"in": ("INCH", 25.4), "ft": ("FOOT", 304.8)}


def relabel_step(text: str, unit: str, which: int | None = None) -> str:
    """A STEP file's millimetre length units (all, or the `which`-th) declared as
    `unit` instead, the numbers left as they are: SI prefixes in place, inch and foot
    as conversion-based units of the millimetre, as CAD systems write them."""
    si = {"m": "$", "cm": ".CENTI.", "mm": ".MILLI."}
    if unit in si:
        unit_text = f"( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT({si[unit]},.METRE.) )"
    else:
        unit_text = f"( CONVERSION_BASED_UNIT('{_CONVERSIONS[unit][0]}',#990001) LENGTH_UNIT() NAMED_UNIT(#990002) )"
    spans = [m.span() for m in _MM_UNIT.finditer(text)]
    for start, end in reversed(spans if which is None else [spans[which]]):
        text = text[:start] + unit_text + text[end:]
    if unit in si:
        return text
    mm = _CONVERSIONS[unit][1]
    extra = ("#990000 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );\n"
             f"#990001 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE({mm}),#990000);\n"
             "#990002 = DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.);\n")
    return text.replace("DATA;\n", "DATA;\n" + extra, 1)


def gmsh_step(path: Path, build) -> None:
    """A STEP file (millimetres) of the shapes `build(occ)` adds, written by gmsh."""
    gmsh = pytest.importorskip("gmsh")
    sigint = signal.getsignal(signal.SIGINT)  # initialize sets it to SIG_DFL, and finalize does not put it back
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("m")
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
        signal.signal(signal.SIGINT, sigint)


@pytest.fixture(scope="module")
def cylinder_mm(tmp_path_factory) -> str:
    """A cylinder of radius 1 and height 2 (file units), axis Z, written in mm."""
    p = tmp_path_factory.mktemp("step") / "cylinder.step"
    gmsh_step(p, lambda occ: occ.addCylinder(0, 0, 0, 0, 0, 2, 1))
    return p.read_text()


@pytest.mark.parametrize("unit, metres", [("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("in", 0.0254),
                                          ("ft", 0.3048)])
def test_step_every_unit_from_the_file_and_asset_toml(tmp_path, cylinder_mm, unit, metres):
    step = tmp_path / "c.step"
    step.write_text(relabel_step(cylinder_mm, unit))
    tol = metres / 2000  # the same mesh in every unit, its extents within 5e-4 of the circle's
    toml = f'category = "test"\nsource = "c.step"\ntessellation_tolerance_m = {tol}\n'
    asset = read(asset_tree(tmp_path / "file", "c", [step], toml))
    np.testing.assert_allclose(extents(asset), np.array([2.0, 2.0, 2.0]) * metres, rtol=1e-3)
    # asset.toml's unit over the file's: the numbers are read as inches
    asset = read(asset_tree(tmp_path / "over", "c", [step], toml + 'units = "in"\nscale = 2.0\n'))
    np.testing.assert_allclose(extents(asset), np.array([2.0, 2.0, 2.0]) * 0.0254 * 2.0, rtol=1e-3)


def _chord_deviation(asset, radius: float) -> float:
    """Largest gap between the cylinder and its triangles: r (1 - cos(pi / n)) for the n
    segments of its top rim."""
    p = model_points(asset)
    top = p[np.isclose(p[:, 2], p[:, 2].max(), atol=radius * 1e-9)]
    n = len(np.unique(np.round(np.arctan2(top[:, 1], top[:, 0]), 9)))
    return radius * (1.0 - np.cos(np.pi / n))


@pytest.mark.parametrize("tol", [0.001, 0.0002])  # finer than the angular tolerance's chords here
def test_feet_step_is_meshed_at_the_tolerance_asked_in_metres(tmp_path, cylinder_mm, tol):
    """cascadio's tol_linear is in millimetres: a feet file meshed at `tol` metres keeps
    its chords within tol and no finer than a quarter of it (305 times finer before)."""
    step = tmp_path / "c.step"
    step.write_text(relabel_step(cylinder_mm, "ft"))
    toml = f'category = "test"\nsource = "c.step"\ntessellation_tolerance_m = {tol}\n'
    asset = read(asset_tree(tmp_path, "c", [step], toml))
    p = model_points(asset)
    assert np.ptp(p[:, 2]) == pytest.approx(0.6096, rel=1e-6)
    assert np.linalg.norm(p[:, :2], axis=1).max() == pytest.approx(0.3048, rel=1e-6)
    deviation = _chord_deviation(asset, 0.3048)
    assert tol / 4 < deviation <= tol


def test_mixed_length_units_are_each_read_and_cannot_be_overridden(tmp_path):
    """Two solids, one in an inch context (gmsh writes the assembly's context first,
    then each solid's): OpenCASCADE reads each in its own unit; a single asset.toml
    unit cannot say what both are."""
    from pipeline.ingest.cad import step_length_units

    mm = tmp_path / "two.step"
    gmsh_step(mm, lambda occ: (occ.addBox(0, 0, 0, 10, 10, 10), occ.addBox(100, 0, 0, 10, 10, 10)))
    step = tmp_path / "mixed.step"
    step.write_text(relabel_step(mm.read_text(), "in", which=1))
    assert step_length_units(step) == (0.001, 0.0254)
    toml = 'category = "test"\nsource = "mixed.step"\n'
    asset = read(asset_tree(tmp_path / "a", "mixed", [step], toml))
    sizes = sorted(float(np.ptp(v.mesh.vertices[:, 0])) for _, v in asset.visuals())
    np.testing.assert_allclose(sizes, (0.010, 0.254), rtol=1e-6)
    cfg = asset_tree(tmp_path / "b", "mixed", [step], toml + 'units = "mm"\n')
    with pytest.raises(UserError) as e:
        read(cfg)
    assert e.value.file == str(cfg.path) and e.value.obj == "units"
    assert "several length units (mm, in)" in e.value.message


@pytest.fixture(scope="module")
def sphere_ft(tmp_path_factory) -> Path:
    """A sphere of 50 ft radius and a 20 ft box, in a file in feet."""
    d = tmp_path_factory.mktemp("sphere")
    gmsh_step(d / "mm.step", lambda occ: (occ.addSphere(0, 0, 0, 50), occ.addBox(100, 0, 0, 20, 20, 20)))
    (d / "sphere.step").write_text(relabel_step((d / "mm.step").read_text(), "ft"))
    return d / "sphere.step"


def test_a_tolerance_that_would_make_too_many_triangles_is_refused_first(tmp_path, sphere_ft):
    import time

    toml = 'category = "test"\nsource = "sphere.step"\ntessellation_tolerance_m = 1e-6\n'
    cfg = asset_tree(tmp_path, "sphere", [sphere_ft], toml)
    t0 = time.perf_counter()
    with pytest.raises(UserError) as e:
        read(cfg)
    assert time.perf_counter() - t0 < 60  # refused from the coarse pass, not after meshing
    assert e.value.file == str(cfg.path) and e.value.obj == "tessellation_tolerance_m"
    message = e.value.message
    assert "over tessellation_max_triangles = 1,000,000" in message and "nothing was tessellated" in message
    fits = float(message.split("about ")[-1].split(" m would")[0])
    # the tolerance it offers is the limit's: 20 times coarser, a twentieth of it
    toml = f'category = "test"\nsource = "sphere.step"\ntessellation_tolerance_m = {fits * 20}\n'
    asset = read(asset_tree(tmp_path / "fit", "sphere", [sphere_ft], toml))
    estimate = int(dict(asset.metadata)["tessellation_estimate"])
    assert asset.triangle_count() <= estimate <= 1_000_000 / 20 * 1.05


def test_estimate_is_above_the_count_it_predicts(tmp_path, sphere_ft, cylinder_mm):
    """The guard's estimate errs above the triangles made (a refusal is no close call)
    but not by orders of magnitude (it refuses no sensible tolerance)."""
    step = tmp_path / "c.step"
    step.write_text(cylinder_mm)
    for source, tol in ((sphere_ft, 0.05), (sphere_ft, 0.01), (step, 1e-5), (step, 1e-7)):
        toml = f'category = "test"\nsource = "{source.name}"\ntessellation_tolerance_m = {tol}\n'
        asset = read(asset_tree(tmp_path / f"{source.stem}{tol}", "s", [source], toml))
        estimate = int(dict(asset.metadata)["tessellation_estimate"])
        assert asset.triangle_count() <= estimate <= 6 * asset.triangle_count(), (source.name, tol)


def test_running_out_of_memory_tessellating_names_the_asset_and_the_knob(tmp_path, sphere_ft):
    """Under a memory limit (as a build's worker has), OpenCASCADE dies in the child
    process, and the reader says so naming asset.toml's tolerance: no crash here."""
    import subprocess
    import sys
    import textwrap

    toml = 'category = "test"\nsource = "sphere.step"\ntessellation_tolerance_m = 1e-4\n' \
           'tessellation_max_triangles = 1000000000\n'
    cfg = asset_tree(tmp_path, "sphere", [sphere_ft], toml)
    script = textwrap.dedent(f"""
        import re, resource
        from pipeline.config import load_asset_config
        from pipeline.errors import UserError
        from pipeline.ingest.cad import read_cad
        size = int(re.search(r"VmSize:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) * 1024
        resource.setrlimit(resource.RLIMIT_AS, (size + (300 << 20), resource.RLIM_INFINITY))
        try:
            read_cad(load_asset_config({str(cfg.path)!r}))
        except UserError as e:
            print("USER ERROR", e.file, e.obj, e.message, sep="|")
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    _, file, obj, message = proc.stdout.strip().splitlines()[-1].split("|")
    assert (file, obj) == (str(cfg.path), "tessellation_tolerance_m")
    assert "sphere.step" in message and ("memory limit" in message or "ran out of" in message)


def test_workers_run_under_the_memory_limit(tmp_path):
    from pipeline.engine.executors import local_pool
    from pipeline.engine.worker import Workers, default_memory, memory_limit, run_task

    pool = local_pool(Workers(1, 1, (), 6 << 30))
    try:
        out = pool.submit(run_task, _limit_of_this_process, {}, str(tmp_path)).result(timeout=120)
    finally:
        pool.shutdown()
    assert out["result"]["limit"] == 6 << 30
    assert default_memory(1) >= 4 << 30 and default_memory(64) == max(4 << 30, default_memory(1) // 64)
    assert memory_limit() is None or memory_limit() > 0


def _limit_of_this_process(staging) -> dict:
    from pipeline.engine.worker import memory_limit

    return {"limit": memory_limit()}


@corpus
def test_twin_build_says_what_a_source_does_not_carry(tmp_path):
    """The morph's animation reaches the user: a line at the end of twin build, and a
    HIER013 finding in its package's manifest (which twin validate reports)."""
    import json

    import mini_sources
    from helpers import twin

    src = mini_sources.make(tmp_path / "sources")  # asset_tree's sources folder
    asset_tree(tmp_path, "morph", [CORPUS / "mesh" / "simple_morph" / "SimpleMorph.gltf"],
               'category = "test"\nsource = "SimpleMorph.gltf"\n')
    build = ["build", "--sources", src, "--out", tmp_path / "out", "--only", "morph"]
    proc = twin(*build)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "morph: warning: 1 glTF animations are not carried" in proc.stderr
    manifest = json.loads((tmp_path / "out" / "models" / "morph" / "manifest.json").read_text())
    assert [f["code"] for f in manifest["findings"]["source"] if f["code"] == "HIER013"] == ["HIER013"]
    bad = twin(*build, "--memory-limit", "lots", timeout=300)
    assert bad.returncode == 2 and "--memory-limit" in bad.stderr


def collada(plain: bool = True, skinned: bool = True, doctype: str = "") -> str:
    """A tetrahedron with corners 1 cm along each axis (<unit meter=0.01>, Y_UP), placed
    as plain geometry and/or deformed by a one-joint skin controller."""
    skin = """<library_controllers><controller id="c"><skin source="#g">
 <bind_shape_matrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</bind_shape_matrix>
 <source id="j"><Name_array id="ja" count="1">b</Name_array><technique_common><accessor source="#ja" count="1"
  stride="1"><param name="JOINT" type="name"/></accessor></technique_common></source>
 <source id="ibm"><float_array id="ibma" count="16">1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</float_array><technique_common>
  <accessor source="#ibma" count="1" stride="16"><param name="TRANSFORM" type="float4x4"/></accessor></technique_common>
 </source>
 <source id="w"><float_array id="wa" count="1">1</float_array><technique_common><accessor source="#wa" count="1"
  stride="1"><param name="WEIGHT" type="float"/></accessor></technique_common></source>
 <joints><input semantic="JOINT" source="#j"/><input semantic="INV_BIND_MATRIX" source="#ibm"/></joints>
 <vertex_weights count="4"><input semantic="JOINT" source="#j" offset="0"/><input semantic="WEIGHT" source="#w"
  offset="1"/><vcount>1 1 1 1</vcount><v>0 0 0 0 0 0 0 0</v></vertex_weights>
</skin></controller></library_controllers>""" if skinned else ""
    nodes = ('<node id="plain"><instance_geometry url="#g"/></node>' if plain else "") + (
        '<node id="b" sid="b" type="JOINT"/><node id="rigged"><instance_controller url="#c">'
        '<skeleton>#b</skeleton></instance_controller></node>' if skinned else "")
    return f"""<?xml version="1.0" encoding="utf-8"?>{doctype}
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
<asset><unit meter="0.01" name="centimeter"/><up_axis>Y_UP</up_axis></asset>
<library_geometries><geometry id="g"><mesh>
 <source id="p"><float_array id="pa" count="12">0 0 0 1 0 0 0 1 0 0 0 1</float_array><technique_common><accessor
  source="#pa" count="4" stride="3"><param name="X" type="float"/><param name="Y" type="float"/><param name="Z"
  type="float"/></accessor></technique_common></source>
 <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
 <triangles count="4"><input semantic="VERTEX" source="#v" offset="0"/><p>0 2 1 0 1 3 0 3 2 1 2 3</p></triangles>
</mesh></geometry></library_geometries>{skin}
<library_visual_scenes><visual_scene id="s">{nodes}</visual_scene></library_visual_scenes>
<scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"""


def test_collada_controllers_are_said_and_plain_geometry_read(tmp_path):
    (tmp_path / "both.dae").write_text(collada())
    asset = read_mesh(cfg(tmp_path / "both.dae"))
    (_, visual), = asset.visuals()
    corners = {tuple(np.round(v, 9) + 0.0) for v in visual.mesh.vertices}
    # centimetres, and Y up turned to Z up: (x, y, z) -> (x, -z, y)
    assert corners == {(0.0, 0.0, 0.0), (0.01, 0.0, 0.0), (0.0, 0.0, 0.01), (0.0, -0.01, 0.0)}
    assert dict(asset.metadata)["warning.controller"].startswith("COLLADA controllers (1 skin) are not carried")
    (tmp_path / "skinned.dae").write_text(collada(plain=False))
    with pytest.raises(UserError, match=r"skinned.dae: no triangles in the file \(COLLADA controllers \(1 skin\)"):
        read_mesh(cfg(tmp_path / "skinned.dae"))


@corpus
def test_collada_animations_are_said(tmp_path):
    text = POLE.read_text()
    at = text.index("</asset>") + len("</asset>")
    animation = """<library_animations><animation id="spin">
 <source id="t"><float_array id="ta" count="2">0 1</float_array><technique_common><accessor source="#ta" count="2"
  stride="1"><param name="TIME" type="float"/></accessor></technique_common></source>
 <source id="a"><float_array id="aa" count="2">0 90</float_array><technique_common><accessor source="#aa" count="2"
  stride="1"><param name="ANGLE" type="float"/></accessor></technique_common></source>
 <sampler id="s"><input semantic="INPUT" source="#t"/><input semantic="OUTPUT" source="#a"/></sampler>
 <channel source="#s" target="node/rotateZ.ANGLE"/></animation></library_animations>"""
    (tmp_path / "pole.dae").write_text(text[:at] + animation + text[at:])
    asset = read_mesh(cfg(tmp_path / "pole.dae"))
    np.testing.assert_allclose(extents(asset), POLE_SIZE, rtol=1e-3)
    said = carried(asset)
    assert "1 COLLADA animations are not carried: the model is read as it stands" in said
    # the file came without its materials/ folder: each image it names is said too
    assert sorted(m for m in said if "COLLADA animations" not in m) == sorted(m for m in said if m.startswith(
        "pole.dae: material ") and "not found in the asset's folder" in m) and len(said) == 5


def test_hostile_mesh_files_are_refused_naming_the_file(tmp_path, capfd):
    """Entities, paths out of the source's folder, meshes this reader would read as
    zeros: each one clear error, nothing read from elsewhere, no trace printed."""
    import base64
    import json

    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"\x00" * 64)
    folder = tmp_path / "asset"
    folder.mkdir()
    dae = folder / "xxe.dae"
    dae.write_text(collada(skinned=False, doctype=f'<!DOCTYPE C [<!ENTITY x SYSTEM "file://{secret}">]>'))
    with pytest.raises(UserError, match="xxe.dae: COLLADA file declares a DOCTYPE"):
        read_mesh(cfg(dae))

    triangle = base64.b64encode(np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], np.float32).tobytes()).decode()
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]}],
           "bufferViews": [{"buffer": 0, "byteLength": 36}],
           "buffers": [{"byteLength": 36, "uri": f"data:application/octet-stream;base64,{triangle}"}]}
    cases = {
        "outside.gltf": ({"buffers": [{"byteLength": 36, "uri": "../secret.bin"}]}, "leaves the file's folder"),
        "image.gltf": ({"images": [{"uri": str(secret)}]}, r"images\[0\]: uri .* leaves the file's folder"),
        "draco.gltf": ({"extensionsUsed": ["KHR_draco_mesh_compression"],
                        "extensionsRequired": ["KHR_draco_mesh_compression"]}, "KHR_draco_mesh_compression"),
        "meshopt.gltf": ({"extensionsUsed": ["EXT_meshopt_compression"],
                          "extensionsRequired": ["EXT_meshopt_compression"]}, "EXT_meshopt_compression"),
    }
    (folder / "good.gltf").write_text(json.dumps(doc))
    assert read_mesh(cfg(folder / "good.gltf")).triangle_count() == 1
    for name, (changes, words) in cases.items():
        (folder / name).write_text(json.dumps({**doc, **changes}))
        with pytest.raises(UserError, match=f"{name}: .*{words}"):
            read_mesh(cfg(folder / name))

    obj = folder / "up.obj"
    obj.write_text("mtllib ../materials.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(UserError, match="up.obj: mtllib: '../materials.mtl' leaves the file's folder"):
        read_mesh(cfg(obj))
    (folder / "m.mtl").write_text(f"newmtl a\nmap_Kd {secret}\n")
    obj.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n")
    with pytest.raises(UserError, match="m.mtl: map_Kd: .* leaves the file's folder"):
        read_mesh(cfg(obj))
    assert "Traceback" not in capfd.readouterr().err


@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "glb"])
@pytest.mark.parametrize("extra, factor", [("", 1.0), ('units = "mm"\nscale = 2.0\n', 0.002), ('units = "ft"\n', 0.3048)])
def test_each_mesh_format_in_a_sources_tree(tmp_path, ext, extra, factor):
    """A 1 x 2 x 3 box: STL, OBJ and PLY declare nothing (metres, Z up), glTF is Y up."""
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    box.export(tmp_path / f"box.{ext}")
    cfg = asset_tree(tmp_path, "box", [tmp_path / f"box.{ext}"], f'category = "test"\nsource = "box.{ext}"\n{extra}')
    size = np.array([1.0, 3.0, 2.0] if ext == "glb" else [1.0, 2.0, 3.0])
    np.testing.assert_allclose(extents(read(cfg)), size * factor, rtol=1e-9)
