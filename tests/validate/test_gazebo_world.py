"""What a Gazebo world is made of: primitive collisions, LOD variants that draw each
material of a link once, placements grouped by variant, all read back by Gazebo's own
loaders (tools/gzprobe) and by dartsim."""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from fixtures_assets import articulated_asset, box_mesh, rpy_matrix, tetra_mesh
from pipeline import ir
from pipeline.export import collada as collada_writer
from pipeline.export import names
from pipeline.export import sdf as sdf_writer
from pipeline.export.variants import MAX_PRIMITIVES, kept_apart, variant_collisions, variant_visuals
from pipeline.geometry.collision import connected_parts
from pipeline.geometry.primitives import fit_primitive, signed_volume
from pipeline.geometry.transform import xyz_rpy_to_matrix
from pipeline.scene.world_collisions import MODEL_NAME as CELLS_MODEL, read_collada_triangles
from collision_cells import assert_in_cells, cell_parts
from pipeline.validate import gazebo

SAFE = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)


def _prism(sides: int, radius: float, length: float) -> ir.Mesh:
    """A closed regular prism along z, centred at the origin, outward faces."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    vertices = np.vstack([np.c_[ring, np.full(sides, -length / 2)], np.c_[ring, np.full(sides, length / 2)],
                          [[0, 0, -length / 2], [0, 0, length / 2]]])
    faces = []
    for i in range(sides):
        j = (i + 1) % sides
        faces += [[i, j, sides + j], [i, sides + j, sides + i], [2 * sides, j, i], [2 * sides + 1, sides + i, sides + j]]
    return ir.Mesh(vertices=vertices, faces=faces)


def _moved(mesh: ir.Mesh, pose: np.ndarray) -> ir.Mesh:
    return ir.Mesh(vertices=mesh.vertices @ pose[:3, :3].T + pose[:3, 3], faces=mesh.faces)


def _inside(shape, vertices: np.ndarray) -> bool:
    local = (vertices - shape.pose[:3, 3]) @ shape.pose[:3, :3]
    if shape.kind == "box":
        return bool(np.all(np.abs(local) <= np.asarray(shape.size) / 2 + 1e-9))
    radius, length = shape.size
    return bool(np.all(np.hypot(local[:, 0], local[:, 1]) <= radius + 1e-9) and np.all(np.abs(local[:, 2]) <= length / 2 + 1e-9))


# --- primitives -----------------------------------------------------------------------

def test_a_turned_box_is_a_box_of_its_size():
    pose = rpy_matrix((3.0, -2.0, 1.5), (0.3, -0.2, 1.1))
    mesh = _moved(box_mesh((0.4, 1.2, 2.5)), pose)
    shape = fit_primitive(mesh.vertices, mesh.faces)
    assert shape.kind == "box" and shape.fill == pytest.approx(1.0)
    assert sorted(shape.size) == pytest.approx([0.4, 1.2, 2.5])
    np.testing.assert_allclose(shape.pose[:3, 3], [3.0, -2.0, 1.5], atol=1e-12)
    assert _inside(shape, mesh.vertices)


def test_an_axis_aligned_box_keeps_the_mesh_axes():
    mesh = box_mesh((0.9, 0.6, 1.6), (0, 0, 0.8))
    shape = fit_primitive(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(shape.pose[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(shape.size, [0.9, 0.6, 1.6])


def test_a_sixteen_sided_post_is_a_cylinder():
    pose = rpy_matrix((1.0, 2.0, 3.0), (math.pi / 2, 0.0, 0.4))
    mesh = _moved(_prism(16, 0.15, 4.0), pose)
    shape = fit_primitive(mesh.vertices, mesh.faces)
    assert shape.kind == "cylinder"
    assert shape.size == pytest.approx((0.15, 4.0))
    assert abs(float(shape.pose[:3, 2] @ pose[:3, 2])) == pytest.approx(1.0)  # the post's axis
    assert _inside(shape, mesh.vertices)


@pytest.mark.parametrize("mesh", [tetra_mesh(1.0), _prism(3, 0.5, 1.0), _prism(6, 0.5, 1.0)],
                         ids=["tetrahedron", "triangular prism", "hexagonal prism"])
def test_shapes_that_are_neither_stay_meshes(mesh):
    assert signed_volume(mesh.vertices, mesh.faces) > 0
    assert fit_primitive(mesh.vertices, mesh.faces) is None


# --- LOD variants ---------------------------------------------------------------------

def _lattice_asset() -> ir.Asset:
    """One link, six visuals of two materials at two levels, seven box collisions."""
    steel = ir.Material("steel", metallic=0.9, roughness=0.3)
    paint = ir.Material("paint", base_color=(0.2, 0.4, 0.1, 1.0))
    visuals = [ir.Visual(f"member_{i}", "steel" if i % 2 else "paint",
                         (box_mesh((0.1, 0.1, 2.0), (0, 0, 1.0), attributes=True), tetra_mesh(0.2, (0, 0, 1.0))),
                         pose=rpy_matrix((i * 0.5, 0.1 * i, 0.0), (0.0, 0.2 * i, 0.3 * i))) for i in range(6)]
    collisions = [ir.Collision(f"c{i}", box_mesh((0.1, 0.1, 2.0), (0, 0, 1.0)), pose=rpy_matrix((i * 0.5, 0, 0)))
                  for i in range(MAX_PRIMITIVES + 3)]
    return ir.Asset("lattice", "structure", (ir.Link("base", visuals=visuals, collisions=collisions),),
                    materials=(steel, paint))


def test_a_variant_draws_each_material_of_a_link_once(tmp_path):
    asset = _lattice_asset()
    link = asset.links[0]
    merged = variant_visuals(asset, link, 1)
    assert sorted(v.name for v in merged) == ["paint__merged", "steel__merged"]
    assert variant_visuals(asset, link, 0) and len(variant_visuals(asset, link, 0)) == 6
    written = collada_writer.write(asset, tmp_path)
    for v in merged:
        assert v.mesh_file in written
        parts = [(p.pose, p.lod(1)) for p in v.parts]
        mesh = v.mesh(1)
        assert mesh.triangle_count == sum(m.triangle_count for _, m in parts)
        expected = np.concatenate([m.vertices @ pose[:3, :3].T + pose[:3, 3] for pose, m in parts])
        np.testing.assert_allclose(mesh.vertices, expected, atol=1e-12)
    sdf_writer.write(asset, tmp_path / "v1", lod=1, model_name="lattice__lod1")
    model = etree.parse(str(tmp_path / "v1" / "model.sdf"), SAFE).getroot()
    assert len(model.findall(".//visual")) == 2
    # past MAX_PRIMITIVES boxes a variant's link has one merged collision mesh; LOD 0 keeps the boxes
    assert [c.name for c in variant_collisions(link, 1)] == [names.merged_collision_name()]
    assert all(c.shape is not None for c in variant_collisions(link, 0))
    assert names.merged_collision_file("base") in written


def test_bound_and_keyed_visuals_stay_apart():
    asset = articulated_asset()
    apart = kept_apart(asset)
    assert apart, "the fixture binds visuals and has a shape key"
    for link in asset.links:
        for v in variant_visuals(asset, link, 1):
            if v.merged:
                assert not apart & {p.name for p in v.parts}


def test_gazebo_reads_merged_meshes_exactly(tmp_path):
    if not gazebo.available() and not os.environ.get("CI"):
        pytest.skip(gazebo.PROBE_HINT)
    written = [tmp_path / p for p in collada_writer.write(_lattice_asset(), tmp_path) if "merged" in p]
    reports = gazebo.probe_meshes(written)
    assert len(written) == 3 and gazebo.mesh_findings(written, reports, str) == []


# --- the world ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def site(request):
    """The run's mini build (mini_sources' defaults: the plan 23 deg off grid north,
    in metres) as Gazebo loads it."""
    if not gazebo.available() and not os.environ.get("CI"):
        pytest.skip(gazebo.PROBE_HINT)
    _, out = request.getfixturevalue("mini_build")
    world = next((out / "scene").glob("*.sdf"))
    return out, world, gazebo.probe_world(world, [out / "models"], physics_s=0.2)


def _grouped(root) -> list:
    """The world's models of grouped placements (a frame each)."""
    return [m for m in root.findall("world/model") if m.find("frame") is not None]


def _whole_collision(out: Path, asset: str) -> tuple[np.ndarray, np.ndarray]:
    return read_collada_triangles(out / "models" / asset / names.WHOLE_COLLISION_FILE)


def test_gazebo_loads_the_world_with_every_placement(site):
    out, world, seen = site
    assert seen["world"]["errors"] == []
    tags = {p["tag"] for p in json.loads((out / "scene" / "placements.json").read_text())["placements"]}
    root = etree.parse(str(world), SAFE).getroot()
    included = {i.findtext("name") for i in root.iter("include")} - {"terrain"}
    framed = {f.get("name") for f in root.findall("world/model/frame")}
    assert included | framed == tags and not included & framed
    # every visual of a grouped placement hangs on its frame; their collisions are the
    # world's cells'
    for model in _grouped(root):
        for el in model.iter("visual", "collision"):
            tag = el.find("pose").get("relative_to")
            assert tag in framed and el.get("name").startswith(tag + "__")


def test_gazebo_reads_the_world_meshes_as_written(site):
    _, _, seen = site
    paths = sorted({use["path"] for m in seen["models"] for use in m["meshes"]})
    assert paths and all(paths)
    assert gazebo.mesh_findings([Path(p) for p in paths], seen["meshes"], str) == []


def _world_points(uses: list[dict], place: np.ndarray) -> np.ndarray:
    """(n, 3) every vertex of the visual meshes Gazebo placed (`uses`: the probe's rows,
    with model_from_mesh), read from the files with pycollada, in the world frame."""
    import collada

    points = []
    for use in uses:
        m = place @ np.array(use["model_from_mesh"]).reshape(4, 4)
        for geometry in collada.Collada(use["path"]).scene.objects("geometry"):
            for prim in geometry.primitives():
                v = np.asarray(prim.vertex, dtype=np.float64)
                points.append(v @ m[:3, :3].T + m[:3, 3])
    return np.concatenate(points)


def test_a_grouped_placement_is_where_its_include_would_be(site, tmp_path):
    """What a placement drawn in a grouped model shows (its one whole-model visual)
    is what its variant placed alone at the frame's pose (as an include would place
    it) shows with all its visuals: the same vertices, each where Gazebo puts it."""
    out, world, seen = site
    root = etree.parse(str(world), SAFE).getroot()
    for model in _grouped(root):
        frame = model.find("frame")
        tag, pose = frame.get("name"), [float(v) for v in frame.findtext("pose").split()]
        alone = tmp_path / "alone.sdf"  # beside the shared build, not in it
        alone.write_text(f'<?xml version="1.0"?><sdf version="1.9"><world name="w"><include><uri>model://{model.get("name")}</uri>'
                         f'<name>{tag}</name><pose>{" ".join(map(str, pose))}</pose></include></world></sdf>\n')
        single = gazebo.probe_world(alone, [out / "models"])["models"][0]
        theirs = _world_points([u for u in single["meshes"] if u["kind"] == "visual"],
                               np.array(single["world_from_model"]).reshape(4, 4))
        grouped = next(m for m in seen["models"] if m["name"] == model.get("name"))
        mine_names = {v.findtext("geometry/mesh/uri") for v in model.iter("visual") if v.get("name") == f"{tag}__whole"}
        if not mine_names:  # the finest level of a model with coarser ones: each visual as in its variant
            assert model.get("name") == model.get("name").split("__lod")[0]
            mine = [u for u in grouped["meshes"] if u["kind"] == "visual"]
            for use in single["meshes"]:
                if use["kind"] == "visual":
                    world_from_mesh = np.array(single["world_from_model"]).reshape(4, 4) @ np.array(
                        use["model_from_mesh"]).reshape(4, 4)
                    assert any(np.allclose(np.array(u["model_from_mesh"]).reshape(4, 4), world_from_mesh, atol=1e-9)
                               for u in mine if u["uri"] == use["uri"])
            continue
        assert len(mine_names) == 1 and "whole__lod" in next(iter(mine_names))
        # its row: the whole model's visual sits at its frame (the pose relative to it is 0)
        mine = [u for u in grouped["meshes"] if u["kind"] == "visual" and u["uri"] in mine_names and np.allclose(
            np.array(u["model_from_mesh"]).reshape(4, 4)[:3, 3], pose[:3], atol=1e-9)]
        assert len(mine) == 1
        ours = _world_points(mine, np.array(grouped["world_from_model"]).reshape(4, 4))
        assert len(ours) == len(theirs)
        np.testing.assert_allclose(np.sort(ours, axis=0), np.sort(theirs, axis=0), atol=1e-6)
        # one visual and one collision a placement
        assert len([v for v in model.iter("visual") if v.find("pose").get("relative_to") == tag]) == 1
        assert len([c for c in model.iter("collision") if c.find("pose").get("relative_to") == tag]) <= 1
    assert any(m.find("link/visual").get("name").endswith("__whole") for m in _grouped(root))


def collides_where_placed(root, seen: dict, out: Path, placements: dict[str, dict]) -> int:
    """Assert that every grouped placement's collision is in the world's collision
    cells where its own would be: each vertex of its package's collision meshes,
    posed by its frame, is a vertex of a cell's mesh (near, LOD 0: every triangle) or
    inside one of the cell's boxes (far). Returns the placements checked."""
    parts = cell_parts(seen)
    checked = 0
    for model in _grouped(root):
        drawn = {el.find("pose").get("relative_to") for el in model.iter("visual")}
        for frame in model.findall("frame"):
            tag = frame.get("name")
            if tag not in drawn:
                continue  # it repeats a placement drawn before, whose collision stands for both
            row = placements[tag]
            pose = [float(v) for v in frame.findtext("pose").split()]
            m = xyz_rpy_to_matrix(pose[:3], pose[3:])
            vertices, _ = _whole_collision(out, row["asset"])
            assert_in_cells(vertices @ m[:3, :3].T + m[:3, 3], parts, row["lod"] == 0, tag)
            checked += 1
    return checked


def test_grouped_placements_collide_in_the_cells_where_they_stand(site):
    out, world, seen = site
    root = etree.parse(str(world), SAFE).getroot()
    assert all(c.findtext("geometry/mesh/uri").startswith("collision/") for c in root.iter("collision")
               if c.getparent().getparent().get("name") == CELLS_MODEL)
    placements = {p["tag"]: p for p in json.loads((out / "scene" / "placements.json").read_text())["placements"]}
    assert collides_where_placed(root, seen, out, placements) == len(placements)


def test_validation_reads_the_collision_cells_as_gazebo_does(site, tmp_path):
    """check_build loads the meshes the world names beside itself and compares them
    with the files: none on the built world, a finding naming the cell when one is
    cut short."""
    out, world, _ = site
    shutil.copytree(out / "scene", tmp_path / "scene")
    copy = tmp_path / "scene" / world.name
    clean = gazebo.check_build(out / "models", copy, {}, tmp_path, physics_s=0.0)
    assert clean.scene == []
    cell = sorted((tmp_path / "scene" / "collision").glob("*.dae"))[0]
    cell.write_bytes(cell.read_bytes()[: len(cell.read_bytes()) // 2])
    found = gazebo.check_build(out / "models", copy, {}, tmp_path, physics_s=0.0).scene
    assert found and {f.site for f in found} == {f"{world.name}/collision/{cell.name}"}
    assert {f.code for f in found} <= {"GZ001", "GZ010"}


def test_dartsim_builds_and_steps_the_world(site):
    _, _, seen = site
    physics = seen["physics"]
    assert physics["ok"] and physics["failed_shapes"] == 0 and physics["collision_detector"] == "bullet"
    assert physics["mesh_shapes"] + physics["primitive_shapes"] == seen["world"]["collisions"] > 0
    assert physics["steps"] == 200


def test_devices_piled_on_one_point_are_drawn_and_collide_once(site, tmp_path):
    """Placements of one asset at one pose (real drawings pile blocks on one insertion
    point) each keep their frame (name and pose), but one visual and one collision
    stand for them all: a renderer would draw the same triangles in the same place and
    dartsim test every copy against every other at each step. Near (LOD 0: each visual
    and collision as in the package) and far (the whole model, its collision in the
    world's cells)."""
    from pipeline.scene.placements import Placed, yaw_matrix
    from pipeline.scene.world_collisions import CollisionCells
    from pipeline.scene.world_sdf import grouped_model

    out, _, _ = site
    spot = [Placed(ir.Placement(f"K-{i}", "kiosk", "L1", 0.0, 0.0), yaw_matrix(0.5, (3.0, 4.0, 1.0)), 0.5)
            for i in range(5)]
    apart = Placed(ir.Placement("K-9", "kiosk", "L1", 9.0, 0.0), yaw_matrix(0.5, (12.0, 4.0, 1.0)), 0.5)
    turned = Placed(ir.Placement("K-8", "kiosk", "L1", 0.0, 0.0), yaw_matrix(0.7, (3.0, 4.0, 1.0)), 0.7)
    drawn: set = set()
    model = grouped_model("kiosk", out / "models" / "kiosk" / "model.sdf", [*spot, apart, turned], drawn=drawn)
    assert [f.get("name") for f in model.findall("frame")] == ["K-0", "K-1", "K-2", "K-3", "K-4", "K-9", "K-8"]
    for kind in ("visual", "collision"):
        posed = sorted({el.find("pose").get("relative_to") for el in model.findall(f"link/{kind}")})
        assert posed == ["K-0", "K-8", "K-9"], kind
    again = grouped_model("kiosk", out / "models" / "kiosk" / "model.sdf", spot[:1], name="K-0b", drawn=drawn)
    assert again.findall("link/visual") == again.findall("link/collision") == []  # shared by every model of one world
    # the same at a coarse level, where each placement draws the whole model and
    # collides in its cell
    far = [Placed(p.placement, p.pose, p.yaw, lod=1) for p in (*spot, apart)]
    cells, drawn = CollisionCells(out / "models"), set()
    model = grouped_model("kiosk__lod1", out / "models" / "kiosk__lod1" / "model.sdf", far, cells=cells, drawn=drawn)
    assert [v.get("name") for v in model.findall("link/visual")] == ["K-0__whole", "K-9__whole"]
    assert model.findall("link/collision") == []
    # near ones in the cells too: every triangle of their collision meshes
    model = grouped_model("kiosk", out / "models" / "kiosk" / "model.sdf", [*spot, turned], cells=cells, drawn=drawn)
    assert model.findall("link/collision") == [] and len(model.findall("frame")) == 6
    cells.write_meshes(tmp_path)
    merged = cells.model()
    (cell,) = merged.findall("link/collision")  # all within one cell
    seen = next(iter(gazebo.probe_meshes([tmp_path / cell.findtext("geometry/mesh/uri")]).values()))
    vertices, faces = _whole_collision(out, "kiosk")
    boxes = 12 * len(connected_parts(faces, len(vertices)))
    # far K-0 once for the five, far K-9; near K-0 once for the five, near K-8
    assert seen["ok"] and seen["triangles"] == 2 * boxes + 2 * len(faces)


# --- a generated site of many bays ------------------------------------------------------

@pytest.fixture(scope="module")
def bays(request, tmp_path_factory):
    """The mini sources' layout repeated over many bays by bench.plans.at_scale (300
    placements, 40 of them piled on the first INSERT's point, as real drawings pile
    blocks), built beside a copy of the mini build (its packages come from the cache),
    as Gazebo loads it."""
    from helpers import twin
    from pipeline.bench import plans

    if not gazebo.available() and not os.environ.get("CI"):
        pytest.skip(gazebo.PROBE_HINT)
    src, out = request.getfixturevalue("mini_build")
    folder = tmp_path_factory.mktemp("bays")
    shutil.copytree(src, folder / "src")
    shutil.copytree(out, folder / "build", symlinks=True)
    plan = plans.at_scale(folder / "src", folder / "bays", 300, 40)
    done = twin("build", "--sources", plan, "--out", folder / "build", "--json", timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    out = folder / "build"
    world = out / "scene" / "mini.sdf"
    return out, world, gazebo.probe_world(world, [out / "models"], physics_s=0.2)


def test_many_bays_parse_and_every_placement_is_named_where_it_stands(bays):
    out, world, seen = bays
    assert seen["world"]["errors"] == []
    placements = {p["tag"]: p for p in json.loads((out / "scene" / "placements.json").read_text())["placements"]}
    root = etree.parse(str(world), SAFE).getroot()
    frames = {f.get("name"): f for m in _grouped(root) for f in m.findall("frame")}
    assert len(placements) == 300 and set(frames) == set(placements)
    for tag, frame in frames.items():
        pose = [float(v) for v in frame.findtext("pose").split()]
        np.testing.assert_allclose(pose[:3], placements[tag]["enu"], atol=2e-6)
        assert pose[5] == pytest.approx(placements[tag]["yaw_rad"], abs=2e-9)
    # the piled copies are frames alone: one visual draws each distinct placement
    piled = [t for t in placements if "-P" in t]
    drawn = {v.find("pose").get("relative_to") for m in _grouped(root) for v in m.iter("visual")}
    assert len(piled) == 40 and len(set(piled) - drawn) >= 40 - 6  # six INSERTs piled in turn
    assert len(drawn) == len(placements) - len(set(piled) - drawn)


def test_many_bays_collide_in_a_few_shapes_where_they_stand(bays):
    """Every drawn placement's collision is in its cell, and only there (the world's
    other collisions are the terrain's); dartsim builds every shape and steps the
    world."""
    out, world, seen = bays
    root = etree.parse(str(world), SAFE).getroot()
    placements = {p["tag"]: p for p in json.loads((out / "scene" / "placements.json").read_text())["placements"]}
    drawn = {v.find("pose").get("relative_to") for m in _grouped(root) for v in m.iter("visual")}
    assert collides_where_placed(root, seen, out, placements) == len(drawn)
    physics = seen["physics"]
    assert physics["ok"] and physics["failed_shapes"] == 0 and physics["steps"] == 200
    shapes = physics["mesh_shapes"] + physics["primitive_shapes"]
    assert shapes == seen["world"]["collisions"]
    per_model = {m["name"]: sum(u["kind"] == "collision" for u in m["meshes"]) + m["primitive_collisions"]
                 for m in seen["models"]}
    assert {name for name, n in per_model.items() if n} == {"terrain", CELLS_MODEL}
    assert 1 < per_model[CELLS_MODEL] <= len(drawn) / 4


def test_many_bays_keep_stateful_placements_addressable(bays, tmp_path):
    """Placements of an asset the runtime drives (own_model: bound ones) stay models of
    their own, named by their tags, among hundreds of grouped ones; their collisions
    stay theirs."""
    from pipeline.scene import world_sdf
    from pipeline.scene.placements import Placed, yaw_matrix

    out, _, _ = bays
    record = json.loads((out / "scene" / "placements.json").read_text())
    placed = [Placed(ir.Placement(p["tag"], p["asset"], p["level"], 0.0, 0.0), yaw_matrix(p["yaw_rad"], p["enu"]),
                     p["yaw_rad"], p["lod"]) for p in record["placements"]]
    world = tmp_path / "scene" / "own.sdf"
    world.parent.mkdir()
    world_sdf.write(world, site_name="own", origin_llh=(-12.7, -38.3, 48.0), placed=placed,
                    terrain_model=record["terrain"], sun={"intensity": 1.0, "elevation_deg": 40, "azimuth_deg": 30},
                    models=out / "models", own_model=frozenset({"pole"}))
    seen = gazebo.probe_world(world, [out / "models"], meshes=False, physics_s=0.05)
    assert seen["world"]["errors"] == []
    poles = {p.placement.tag for p in placed if p.placement.asset_id == "pole"}
    models = {m["name"]: m for m in seen["models"]}
    assert poles and poles <= set(models)
    for tag in poles:
        assert any(u["kind"] == "collision" for u in models[tag]["meshes"]) or models[tag]["primitive_collisions"]
    assert seen["physics"]["ok"] and seen["physics"]["failed_shapes"] == 0
