"""SDF + COLLADA writers on the hand-made articulated asset, read back by the real
validators (libsdformat, pycollada's schema) and by lxml with SDF 1.9 frame semantics."""

from __future__ import annotations

import math
from dataclasses import replace

import collada
import numpy as np
import pytest
from lxml import etree

from fixtures_assets import articulated_asset, box_mesh, rpy_matrix, tetra_mesh
from pipeline import ir
from pipeline.errors import UserError
from pipeline.export import collada as collada_writer
from pipeline.export import names
from pipeline.export import sdf as sdf_writer
from pipeline.geometry.primitives import fit_primitive
from pipeline.validate import external

ASSET_ID = "test_arm"


def _write_package(parent, asset, lods=(1,)):
    main = parent / asset.id
    files = collada_writer.write(asset, main) + sdf_writer.write(asset, main)
    for k in lods:
        name = names.lod_model_name(asset.id, k)
        sdf_writer.write(asset, parent / name, lod=k, model_name=name)
    return files


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    parent = tmp_path_factory.mktemp("models")
    asset = articulated_asset()
    files = _write_package(parent, asset)
    return parent, asset, files


def _parse(path):
    return etree.parse(str(path), etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False))


def _pose(el) -> np.ndarray:
    """4x4 of an element's <pose> child (identity when absent); only euler_rpy is used."""
    p = el.find("pose")
    if p is None or not (p.text or "").strip():
        return np.eye(4)
    x, y, z, r, pi, ya = (float(t) for t in p.text.split())
    return rpy_matrix((x, y, z), (r, pi, ya))


def _model_frames(model) -> dict[str, np.ndarray]:
    """Link and joint frames in the model frame, per SDF 1.9: a link pose defaults to
    __model__, a joint pose to its child link; `relative_to` overrides either."""
    elements = {el.get("name"): el for el in model if el.tag in ("link", "joint")}
    frames: dict[str, np.ndarray] = {"__model__": np.eye(4)}

    def frame(name, depth=0):
        assert depth < 50, "relative_to cycle"
        if name not in frames:
            el = elements[name]
            p = el.find("pose")
            default = "__model__" if el.tag == "link" else el.findtext("child")
            base = (p.get("relative_to") if p is not None else None) or default
            frames[name] = frame(base, depth + 1) @ _pose(el)
        return frames[name]

    for name in elements:
        frame(name)
    return frames


def _uris(root):
    return [u.text for u in root.iter("uri")]


def test_every_dae_passes_the_collada_schema(built):
    parent, asset, files = built
    daes = [f for f in files if f.endswith(".dae")]
    expected = {names.mesh_file(link.name, v.name, k) for link, v in asset.visuals() for k in range(len(v.lods))}
    expected |= {names.collision_file(link.name, c.name) for link in asset.links for c in link.collisions}
    # the whole model at rest, a file per LOD, and all its collisions in one (the Gazebo world's grouped form)
    expected |= {names.whole_mesh_file(k) for k in range(1 if asset.lod_count > 1 else 0, asset.lod_count)}
    expected |= {names.WHOLE_COLLISION_FILE}
    # an articulated asset's links, each at rest at each of those LODs (the world's moving parts)
    assert any(j.type in names.MOVABLE_JOINTS for j in asset.joints)
    expected |= {names.whole_link_mesh_file(link.name, k) for link in asset.links
                 for k in range(1 if asset.lod_count > 1 else 0, asset.lod_count)}
    assert daes == sorted(expected)
    for rel in daes:
        result = external.collada_schema(parent / ASSET_ID / rel)
        assert result.status == "passed", (rel, result.messages)


def test_a_level_its_variant_merges_is_not_written_and_every_file_is_named(tmp_path):
    """Two steel visuals of one link merge in the LOD 1 variant: their own LOD 1 files
    would be named by no SDF, so the package holds the merged file instead, and the
    visual files it holds are exactly those its models name (the world's whole-model
    files aside). A coarse variant cannot draw a visual apart by an override."""
    asset = articulated_asset()
    base = asset.links[0]
    plate = ir.Visual("plate", "steel", (box_mesh((0.4, 0.4, 0.05), (0, 0, 0.55)), tetra_mesh(0.4, (0, 0, 0.55))))
    asset = asset.with_(links=(replace(base, visuals=(*base.visuals, plate)), *asset.links[1:]))
    parent = tmp_path / "models"
    files = _write_package(parent, asset)
    for visual in ("body", "plate"):
        assert names.mesh_file("base", visual, 0) in files and names.mesh_file("base", visual, 1) not in files
    assert names.merged_mesh_file("base", "steel", 1) in files
    named = {u[len(f"model://{ASSET_ID}/"):] for folder in (ASSET_ID, names.lod_model_name(ASSET_ID, 1))
             for u in _uris(_parse(parent / folder / "model.sdf")) if u.endswith(".dae")}
    visual_files = {f for f in files if f.endswith(".dae") and not f.startswith("meshes/whole__")
                    and not f.endswith("__collision.dae")}
    assert visual_files == {f for f in named if not f.endswith("__collision.dae")}
    assert names.mesh_file("arm", "arm_shell", 1) in named  # alone with its material: drawn apart, written
    with pytest.raises(ValueError, match="LOD 0 only"):
        sdf_writer.write(asset, tmp_path / "x", lod=1, visual_overrides={"plate": (None, "lamp_glass")})


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # pycollada's np.matrix
def test_dae_content_reads_back(built):
    parent, asset, _ = built
    for link, visual in asset.visuals():
        for k, mesh in enumerate(visual.lods):
            path = parent / ASSET_ID / names.mesh_file(link.name, visual.name, k)
            doc = collada.Collada(str(path))
            assert doc.assetInfo.upaxis == "Z_UP"
            assert doc.assetInfo.unitmeter == 1.0 and doc.assetInfo.unitname == "meter"
            assert doc.assetInfo.created.year == 2000
            (node,) = doc.scene.nodes
            assert node.xmlnode.get("name") == visual.name
            (tris,) = list(doc.scene.objects("geometry"))[0].primitives()
            # The text keeps float64 exactly (shortest round-trip); pycollada reads float32.
            arrays = {a.get("id"): a.text for a in _parse(path).getroot().iter("{*}float_array")}
            positions = np.array(arrays[f"{names.safe_name(visual.name)}-positions-array"].split(), dtype=np.float64)
            np.testing.assert_array_equal(positions.reshape(-1, 3), mesh.vertices)
            np.testing.assert_allclose(tris.vertex, mesh.vertices, atol=1e-6, rtol=0)
            np.testing.assert_array_equal(tris.vertex_index, mesh.faces)
            np.testing.assert_allclose(np.linalg.norm(tris.normal, axis=1), 1.0, atol=1e-6)
            if mesh.normals is not None:
                np.testing.assert_allclose(tris.normal, mesh.normals, atol=1e-7, rtol=0)
            else:  # smooth normals of a centred box point away from its centre
                outward = mesh.vertices - mesh.vertices.mean(axis=0)
                assert (np.einsum("ij,ij->i", tris.normal, outward) > 0).all()
            if mesh.uvs is not None:
                np.testing.assert_allclose(tris.texcoordset[0], mesh.uvs, atol=1e-7, rtol=0)
            else:
                assert len(tris.texcoordset) == 0
            phong = asset.material(visual.material).phong()
            (effect,) = doc.effects
            assert doc.materials[0].name == visual.material
            assert effect.shadingtype == "phong"
            assert tuple(effect.emission) == phong.emissive
            assert tuple(effect.diffuse) == phong.diffuse
            assert effect.shininess == phong.shininess
            # opacity is <transparency> (A_ONE), the diffuse alpha 1 (gz-rendering multiplies them)
            assert effect.transparency == asset.material(visual.material).alpha
            assert effect.diffuse[3] == 1.0


def test_sdf_packages_pass_libsdformat(built):
    parent, _, _ = built
    for folder in (ASSET_ID, names.lod_model_name(ASSET_ID, 1)):
        result = external.ign_sdf(parent / folder / "model.sdf", [parent])
        if result.status == "skipped":
            pytest.skip(result.messages[0])
        assert result.status == "passed", result.messages
        config = _parse(parent / folder / "model.config").getroot()
        assert config.findtext("name") == folder
        assert config.find("sdf").get("version") == "1.9" and config.findtext("sdf") == "model.sdf"


def test_every_mesh_uri_resolves_and_lod_variant_reuses_main_meshes(built):
    parent, asset, _ = built
    main = _uris(_parse(parent / ASSET_ID / "model.sdf"))
    lod1 = _uris(_parse(parent / names.lod_model_name(ASSET_ID, 1) / "model.sdf"))
    for uri in main + lod1:
        assert uri.startswith(f"model://{ASSET_ID}/meshes/"), uri
        assert (parent / uri[len("model://"):]).is_file(), uri
    assert not (parent / names.lod_model_name(ASSET_ID, 1) / "meshes").exists()
    visual_uris = [u for u in lod1 if not u.endswith("__collision.dae")]
    # Visuals with two LODs use lod1; single-LOD ones (shape key, state binding) lod0.
    expected = [f"model://{ASSET_ID}/{names.mesh_file(link.name, v.name, min(1, len(v.lods) - 1))}"
                for link, v in asset.visuals()]
    assert visual_uris == expected
    assert any(u.endswith("__lod1.dae") for u in visual_uris) and any(u.endswith("__lod0.dae") for u in visual_uris)


def _assert_kinematics_match(sdf_path, asset):
    model = _parse(sdf_path).getroot().find("model")
    frames = _model_frames(model)
    assert model.find("static") is None
    for link in asset.links:
        np.testing.assert_allclose(frames[link.name], link.pose, atol=1e-9, rtol=0)
        link_el = model.find(f"link[@name='{link.name}']")
        assert float(link_el.findtext("inertial/mass")) == link.mass
        for v in link.visuals:
            np.testing.assert_allclose(_pose(link_el.find(f"visual[@name='{v.name}']")), v.pose, atol=1e-9, rtol=0)
        for c in link.collisions:
            # a collision mesh that is a box or a cylinder is written as that shape, posed at its centre
            shape = fit_primitive(c.mesh.vertices, c.mesh.faces)
            el = link_el.find(f"collision[@name='{c.name}']")
            assert (el.find("geometry/mesh") is None) == (shape is not None)
            expected = c.pose if shape is None else c.pose @ shape.pose
            np.testing.assert_allclose(_pose(el), expected, atol=1e-9, rtol=0)
    for joint in asset.joints:
        el = model.find(f"joint[@name='{joint.name}']")
        assert (el.get("type"), el.findtext("parent"), el.findtext("child")) == (joint.type, joint.parent, joint.child)
        np.testing.assert_allclose(frames[joint.name], joint.pose, atol=1e-9, rtol=0)
        xyz = el.find("axis/xyz")
        assert xyz.get("expressed_in") in (None, joint.name)  # the joint frame
        np.testing.assert_allclose([float(t) for t in xyz.text.split()], joint.axis, atol=1e-12, rtol=0)
        for tag in ("lower", "upper", "effort", "velocity"):
            assert float(el.findtext(f"axis/limit/{tag}")) == getattr(joint, tag)


def test_joints_links_and_visual_poses_read_back(built):
    parent, asset, _ = built
    _assert_kinematics_match(parent / ASSET_ID / "model.sdf", asset)


def test_joint_pivot_away_from_child_frame_and_gimbal_poses(tmp_path):
    """A pivot that is not the child link's frame gets a relative joint pose; rotations
    at, near and around pitch = +/-90 degrees survive the rpy text exactly enough."""
    rng = np.random.default_rng(7)
    rotations = [(0.4, math.pi / 2, 1.3), (-2.0, -math.pi / 2, 0.5), (1.0, -math.pi / 2 + 1e-9, -3.0),
                 (3.1, math.pi / 2 - 1e-12, 2.9), (0.0, 0.0, math.pi), (math.pi, 0.0, 0.0)]
    rotations += [tuple(rng.uniform(-math.pi, math.pi, 3)) for _ in range(20)]
    links = [ir.Link("root", visuals=(ir.Visual("v", "m", (box_mesh(),)),))]
    joints = []
    for i, rpy in enumerate(rotations):
        link_pose = rpy_matrix(tuple(rng.uniform(-5, 5, 3)), rpy)
        pivot = link_pose @ rpy_matrix((0.1, -0.2, 0.3), (0.5, -0.25, 1.0))
        links.append(ir.Link(f"l{i}", pose=link_pose, visuals=(ir.Visual(f"v{i}", "m", (box_mesh(),), pose=pivot),)))
        joints.append(ir.Joint(f"j{i}", "revolute", "root", f"l{i}", pose=pivot,
                               axis=np.array([0.0, 0.0, 1.0]), lower=-1.0, upper=1.0, effort=1.0, velocity=1.0))
    asset = ir.Asset("gimbal", "test", tuple(links), tuple(joints), materials=(ir.Material("m"),))
    _write_package(tmp_path, asset, lods=())
    _assert_kinematics_match(tmp_path / "gimbal" / "model.sdf", asset)
    result = external.ign_sdf(tmp_path / "gimbal" / "model.sdf", [tmp_path])
    assert result.status in ("passed", "skipped"), result.messages


def test_materials_in_sdf(built):
    parent, asset, _ = built
    model = _parse(parent / ASSET_ID / "model.sdf").getroot().find("model")
    for link, v in asset.visuals():
        mat = asset.material(v.material)
        p = mat.sdf_phong()
        el = model.find(f"link[@name='{link.name}']/visual[@name='{v.name}']/material")
        for tag in ("ambient", "diffuse", "specular", "emissive"):
            assert tuple(float(t) for t in el.findtext(tag).split()) == getattr(p, tag)
        assert float(el.findtext("pbr/metal/metalness")) == mat.metallic
        assert float(el.findtext("pbr/metal/roughness")) == mat.roughness
    oil = model.find("link[@name='gauge']/visual[@name='oil_level']")
    assert oil.findtext("material/emissive") != "0 0 0 1"
    assert float(oil.findtext("transparency")) == pytest.approx(0.4)


def test_static_model_and_visual_overrides(tmp_path):
    asset = articulated_asset()
    static = asset.with_(joints=(), links=(asset.links[0],))
    sdf_writer.write(static, tmp_path / "s")
    assert _parse(tmp_path / "s" / "model.sdf").getroot().findtext("model/static") == "true"

    turned = rpy_matrix((0.0, 0.0, 0.02), (0.0, 0.0, 1.0))
    sdf_writer.write(asset, tmp_path / "v", model_name="test_arm__alarm",
                     visual_overrides={"oil_level": (None, "steel"), "needle": (turned, None)})
    model = _parse(tmp_path / "v" / "model.sdf").getroot().find("model")
    assert model.get("name") == "test_arm__alarm"
    gauge = model.find("link[@name='gauge']")
    steel = asset.material("steel").sdf_phong()
    assert gauge.findtext("visual[@name='oil_level']/material/diffuse") == " ".join(map(names.fmt, steel.diffuse))
    np.testing.assert_allclose(_pose(gauge.find("visual[@name='needle']")), turned, atol=1e-12)
    np.testing.assert_allclose(_pose(gauge.find("visual[@name='oil_level']")), asset.link("gauge").visuals[1].pose,
                               atol=1e-12)
    with pytest.raises(ValueError, match="nope"):
        sdf_writer.write(asset, tmp_path / "x", visual_overrides={"nope": (None, "steel")})


def test_output_is_byte_identical(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    files = _write_package(a, articulated_asset())
    _write_package(b, articulated_asset())
    written = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert written == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert len(written) == len(files) + 2
    for rel in written:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


def test_unknown_material_is_a_user_error(tmp_path):
    asset = articulated_asset()
    broken = asset.with_(materials=tuple(m for m in asset.materials if m.name != "lamp_glass"))
    for writer in (collada_writer.write, sdf_writer.write):
        with pytest.raises(UserError, match="oil_level.*lamp_glass"):
            writer(broken, tmp_path / "x")


def test_fmt_join_spells_every_float_as_fmt_does():
    from pipeline.export.names import fmt, fmt_join

    rng = np.random.default_rng(3)
    values = [0.0, -0.0, 1.0, -10.0, 100.0, 1.05, 10.05, -0.05, 1e-05, 1e16, 1e22, -1e-300, 2.5e-07, float("inf")]
    values += list(rng.normal(size=20_000) * 10.0 ** rng.integers(-8, 9, 20_000)) + [i / 4 for i in range(-40, 40)]
    assert fmt_join(values) == " ".join(fmt(v) for v in values)
    assert fmt_join([-0.0, 3.0, 0.5]) == "0 3 0.5"


def test_a_level_that_repeats_a_finer_mesh_is_formatted_once(tmp_path, monkeypatch):
    """A visual whose LOD2 has LOD1's content (another Mesh object, as read back from
    an .ir file) gets LOD1's bytes; a different mesh its own document."""
    asset = articulated_asset()
    link = asset.links[0]
    visual = link.visuals[0]
    coarse = visual.lods[-1]
    again = ir.Mesh(coarse.vertices.copy(), coarse.faces.copy(), None if coarse.normals is None else coarse.normals.copy(),
                    None if coarse.uvs is None else coarse.uvs.copy())
    visual = replace(visual, lods=(*visual.lods, again))
    asset = asset.with_(links=(replace(link, visuals=(visual, *link.visuals[1:])), *asset.links[1:]))
    calls = []
    real = collada_writer._dae_bytes
    monkeypatch.setattr(collada_writer, "_dae_bytes", lambda name, mesh, mat: calls.append(name) or real(name, mesh, mat))
    collada_writer.write(asset, tmp_path / "pkg")
    levels = len(visual.lods)
    files = [tmp_path / "pkg" / names.mesh_file(link.name, visual.name, k) for k in range(levels)]
    assert calls.count(visual.name) == levels - 1
    assert files[-1].read_bytes() == files[-2].read_bytes() != files[0].read_bytes()
    collada.Collada(str(files[-1]), validate_output=True)
