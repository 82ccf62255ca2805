"""USD and glTF writers: files pass the formats' own validators and read back to the IR.

Readback goes through pxr (composition, UsdPhysics, UsdSkel), through our own parse of
the GLB container, and through Blender's importers (marked `blender`, run in a child
process: bpy ships its own USD libraries, which must not meet pxr in one process).
"""

from __future__ import annotations

import json
import math
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pipeline import ir
from pipeline.errors import UserError
from pipeline.export import gltf, names, usd
from pipeline.validate.external import gltf_validator, usd_validation

from fixtures_assets import articulated_asset, box_mesh, rpy_matrix

pxr = pytest.importorskip("pxr")
from pxr import Gf, Usd, UsdGeom, UsdPhysics, UsdShade, UsdSkel, UsdValidation, Vt  # noqa: E402

Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def static_asset() -> ir.Asset:
    """One link, one visual, one collision, no joints: a static piece of equipment."""
    paint = ir.Material("paint", base_color=(0.2, 0.3, 0.9, 1.0), roughness=0.7, emission=(4.0, 2.0, 0.0))
    link = ir.Link(
        "housing",
        pose=rpy_matrix((0.5, -0.25, 0.0), (0.0, 0.0, 0.3)),
        visuals=(ir.Visual("shell", "paint", (box_mesh((2.0, 1.0, 3.0), (0.0, 0.0, 1.5)),),
                           pose=rpy_matrix((0.1, 0.0, 0.0), (0.0, 0.0, 0.0))),),
        collisions=(ir.Collision("shell_collision", box_mesh((2.0, 1.0, 3.0), (0.0, 0.0, 1.5))),),
    )
    return ir.Asset(id="cabinet-1", category="test", links=(link,), materials=(paint,))


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict:
    """Both assets written once into their package folders."""
    out = {}
    for asset in (articulated_asset(), static_asset()):
        folder = tmp_path_factory.mktemp(asset.id)
        written = usd.write(asset, folder) + gltf.write(asset, folder)
        out[asset.id] = (asset, folder, written)
    return out


def _usd_stage(built, asset_id):
    asset, folder, _ = built[asset_id]
    return asset, Usd.Stage.Open(str(folder / names.usd_file(asset.id)))


# ------------------------------------------------------------------ files and validators

def test_writers_return_package_relative_paths(built):
    for asset, folder, written in built.values():
        assert written == [names.usd_file(asset.id), names.gltf_file(asset.id)]
        assert all((folder / w).is_file() for w in written)
        assert not [p for p in folder.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("asset_id", ["test_arm", "cabinet-1"])
def test_usd_passes_usd_validation(built, asset_id):
    asset, folder, _ = built[asset_id]
    result = usd_validation(folder / names.usd_file(asset_id))
    assert result.status == "passed", result.messages


def test_usd_validates_under_every_variant_selection(built):
    """Validators only see the composed stage: check each lod x state combination."""
    asset, stage = _usd_stage(built, "test_arm")
    root = stage.GetDefaultPrim()
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    sets = root.GetVariantSets()
    assert sorted(sets.GetNames()) == ["lod", "state_alarm"]
    for lod in sets.GetVariantSet("lod").GetVariantNames():
        for state in sets.GetVariantSet("state_alarm").GetVariantNames():
            sets.SetSelection("lod", lod)
            sets.SetSelection("state_alarm", state)
            errors = [e for e in ctx.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]
            assert not errors, (lod, state, [e.GetMessage() for e in errors])


@pytest.mark.parametrize("asset_id", ["test_arm", "cabinet-1"])
def test_glb_passes_khronos_validator(built, asset_id):
    asset, folder, _ = built[asset_id]
    (result,) = gltf_validator([folder / names.gltf_file(asset_id)])
    assert result.status == "passed", result.messages


def test_two_writes_are_byte_identical(tmp_path):
    for asset in (articulated_asset(), static_asset()):
        a, b = tmp_path / "a" / asset.id, tmp_path / "b" / asset.id
        for folder in (a, b):
            usd.write(asset, folder)
            gltf.write(asset, folder)
        for rel in (names.usd_file(asset.id), names.gltf_file(asset.id)):
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


# ------------------------------------------------------------------ USD readback

def test_usd_stage_metadata_and_root(built):
    asset, stage = _usd_stage(built, "cabinet-1")
    root = stage.GetDefaultPrim()
    assert root.GetPath() == "/cabinet_1"
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    model = Usd.ModelAPI(root)
    assert model.GetKind() == "component"
    assert model.GetAssetName() == "cabinet-1"
    assert model.GetAssetIdentifier().path == "./cabinet-1.usdc"


def test_usd_link_and_visual_poses_are_exact(built):
    asset, stage = _usd_stage(built, "test_arm")
    cache = UsdGeom.XformCache()
    for link, visual in asset.visuals():
        link_prim = stage.GetPrimAtPath(names.usd_link_path(asset.id, link.name))
        assert link_prim.GetParent() == stage.GetDefaultPrim()  # flat under the root
        got = np.array(cache.GetLocalToWorldTransform(link_prim)).T
        np.testing.assert_allclose(got, link.pose, rtol=0, atol=1e-15)
        vis_prim = stage.GetPrimAtPath(names.usd_visual_path(asset.id, link.name, visual.name))
        got = np.array(cache.GetLocalToWorldTransform(vis_prim)).T
        np.testing.assert_allclose(got, link.pose @ visual.pose, rtol=0, atol=1e-12)
        mesh = UsdGeom.Mesh(vis_prim.GetChild("mesh"))
        assert mesh.GetSubdivisionSchemeAttr().Get() == "none"
        assert mesh.GetOrientationAttr().Get() == "rightHanded"
        assert mesh.GetDoubleSidedAttr().Get() is False
        np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), visual.mesh.vertices, atol=1e-7)
        normals = np.array(mesh.GetNormalsAttr().Get())
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
        assert UsdGeom.PrimvarsAPI(mesh).HasPrimvar("st") == (visual.mesh.uvs is not None)


def _joint_world(stage, joint_prim, k: int) -> np.ndarray:
    """(4, 4) world frame of a joint seen from body k: body world @ (localPos, localRot)."""
    j = UsdPhysics.Joint(joint_prim)
    body = stage.GetPrimAtPath(getattr(j, f"GetBody{k}Rel")().GetTargets()[0])
    body_world = np.array(UsdGeom.Xformable(body).ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T
    q = getattr(j, f"GetLocalRot{k}Attr")().Get()
    local = np.eye(4)
    local[:3, :3] = np.array(Gf.Matrix3d(Gf.Rotation(Gf.Quatd(q)))).T
    local[:3, 3] = np.array(getattr(j, f"GetLocalPos{k}Attr")().Get(), dtype=np.float64)
    return body_world @ local


def _check_joints(asset: ir.Asset, stage) -> None:
    schema = {"revolute": UsdPhysics.RevoluteJoint, "continuous": UsdPhysics.RevoluteJoint,
              "prismatic": UsdPhysics.PrismaticJoint, "fixed": UsdPhysics.FixedJoint}
    root = names.safe_name(asset.id)
    for joint in asset.joints:
        prim = stage.GetPrimAtPath(f"/{root}/Joints/{names.safe_name(joint.name)}")
        assert prim.IsA(schema[joint.type]), joint.name
        j = UsdPhysics.Joint(prim)
        assert j.GetBody0Rel().GetTargets() == [names.usd_link_path(asset.id, joint.parent)]
        assert j.GetBody1Rel().GetTargets() == [names.usd_link_path(asset.id, joint.child)]
        w0, w1 = _joint_world(stage, prim, 0), _joint_world(stage, prim, 1)
        # float3 / quatf storage: float precision, relative to the pose's size.
        tol = 1e-6 * max(1.0, float(np.abs(joint.pose[:3, 3]).max()))
        np.testing.assert_allclose(w0[:3, 3], joint.pose[:3, 3], rtol=0, atol=tol)
        np.testing.assert_allclose(w1, w0, rtol=0, atol=tol)
        if joint.type != "fixed":
            token_axis = {"X": 0, "Y": 1, "Z": 2}[prim.GetAttribute("physics:axis").Get()]
            world_axis = joint.pose[:3, :3] @ (joint.axis / np.linalg.norm(joint.axis))
            np.testing.assert_allclose(w0[:3, token_axis], world_axis, rtol=0, atol=1e-6)
        assert np.array(prim.GetCustomDataByKey("ir:axis")).tolist() == joint.axis.tolist()  # exact
        lower, upper = prim.GetAttribute("physics:lowerLimit"), prim.GetAttribute("physics:upperLimit")
        if joint.type == "revolute":  # UsdPhysics angles are degrees
            assert math.isclose(lower.Get(), math.degrees(joint.lower), rel_tol=1e-6)
            assert math.isclose(upper.Get(), math.degrees(joint.upper), rel_tol=1e-6)
        elif joint.type == "prismatic":
            assert math.isclose(lower.Get(), joint.lower, rel_tol=1e-6, abs_tol=1e-9)
            assert math.isclose(upper.Get(), joint.upper, rel_tol=1e-6)
        else:
            assert not lower.HasAuthoredValue() and not upper.HasAuthoredValue()
        if joint.lower is not None:
            assert prim.GetCustomDataByKey("ir:lower") == joint.lower  # exact double


def test_usd_joints_read_back_to_ir(built):
    asset, stage = _usd_stage(built, "test_arm")
    _check_joints(asset, stage)
    # The non-principal axis (0, 0.6, 0.8) took a rotated frame and token X.
    prim = stage.GetPrimAtPath("/test_arm/Joints/gauge_joint")
    assert prim.GetAttribute("physics:axis").Get() == "X"


def test_usd_joint_axes_of_every_kind_read_back(tmp_path):
    """A negative principal axis, one next to -X, and continuous/fixed joints."""
    base = articulated_asset()
    arm, gauge, slide = base.joints
    cases = [
        ir.Joint("arm_joint", "continuous", "base", "arm", pose=arm.pose, axis=np.array([-1.0, 1e-9, 0.0])),
        ir.Joint("gauge_joint", "revolute", "arm", "gauge", pose=gauge.pose, axis=np.array([0.0, 0.0, -1.0]),
                 lower=-0.1, upper=0.2),
        ir.Joint("slide_joint", "fixed", "base", "slider", pose=slide.pose),
    ]
    asset = base.with_(joints=tuple(cases))
    usd.write(asset, tmp_path)
    stage = Usd.Stage.Open(str(tmp_path / names.usd_file(asset.id)))
    _check_joints(asset, stage)
    continuous = stage.GetPrimAtPath("/test_arm/Joints/arm_joint")
    assert not continuous.GetAttribute("physics:lowerLimit").HasAuthoredValue()
    assert usd_validation(tmp_path / names.usd_file(asset.id)).status == "passed"


def test_usd_physics_articulated_vs_static(built):
    asset, stage = _usd_stage(built, "test_arm")
    assert stage.GetDefaultPrim().HasAPI(UsdPhysics.ArticulationRootAPI)
    parsed = UsdPhysics.UsdPhysicsLoadStageFromPrimRange(stage, ["/"])
    found = {str(k): sorted(str(p) for p in v[0]) for k, v in parsed.items()}
    assert found["RigidBody"] == sorted(names.usd_link_path(asset.id, link.name) for link in asset.links)
    assert found["Articulation"] == ["/test_arm"]
    for link in asset.links:
        prim = stage.GetPrimAtPath(names.usd_link_path(asset.id, link.name))
        assert UsdPhysics.MassAPI(prim).GetMassAttr().Get() == pytest.approx(link.mass)
        for col in link.collisions:
            cprim = prim.GetChild("collisions").GetChild(col.name)
            assert cprim.HasAPI(UsdPhysics.CollisionAPI) and cprim.HasAPI(UsdPhysics.MeshCollisionAPI)
            assert UsdPhysics.MeshCollisionAPI(cprim).GetApproximationAttr().Get() == "convexHull"
            assert UsdGeom.Imageable(cprim).GetPurposeAttr().Get() == "guide"

    static, sstage = _usd_stage(built, "cabinet-1")
    assert not sstage.GetDefaultPrim().HasAPI(UsdPhysics.ArticulationRootAPI)
    assert not any(p.HasAPI(UsdPhysics.RigidBodyAPI) for p in sstage.Traverse())
    col = sstage.GetPrimAtPath("/cabinet_1/housing/collisions/shell_collision")
    assert col.HasAPI(UsdPhysics.CollisionAPI)


def test_usd_lod_variant_switches_mesh(built):
    asset, stage = _usd_stage(built, "test_arm")
    lod = stage.GetDefaultPrim().GetVariantSet("lod")
    assert lod.GetVariantNames() == ["lod0", "lod1"] and lod.GetVariantSelection() == "lod0"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(names.usd_visual_path(asset.id, "base", "body") + "/mesh"))
    counts = {}
    for name in ("lod0", "lod1"):
        lod.SetVariantSelection(name)
        counts[name] = (len(mesh.GetPointsAttr().Get()), len(mesh.GetFaceVertexIndicesAttr().Get()) // 3)
    body = asset.link("base").visuals[0]
    assert counts == {"lod0": (8, body.lods[0].triangle_count), "lod1": (4, body.lods[1].triangle_count)}


def test_usd_state_variant_switches_material(built):
    asset, stage = _usd_stage(built, "test_arm")
    state = stage.GetDefaultPrim().GetVariantSet("state_alarm")
    assert state.GetVariantNames() == ["s0", "s1"]
    assert state.GetVariantSelection() == "s1"  # the visual's own material, the last state
    prim = stage.GetPrimAtPath(names.usd_visual_path(asset.id, "gauge", "oil_level") + "/mesh")
    bound = {}
    for name in ("s0", "s1"):
        state.SetVariantSelection(name)
        bound[name] = str(UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0].GetPath())
    assert bound == {"s0": "/test_arm/Looks/steel", "s1": "/test_arm/Looks/lamp_glass"}
    # A visual without a state keeps its binding whatever the state.
    needle = stage.GetPrimAtPath(names.usd_visual_path(asset.id, "gauge", "needle") + "/mesh")
    assert str(UsdShade.MaterialBindingAPI(needle).ComputeBoundMaterial()[0].GetPath()) == "/test_arm/Looks/steel"


def test_usd_materials_are_preview_surfaces(built):
    asset, stage = _usd_stage(built, "test_arm")
    for m in asset.materials:
        shader = UsdShade.Shader(stage.GetPrimAtPath(f"/test_arm/Looks/{m.name}/PreviewSurface"))
        assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
        assert tuple(shader.GetInput("diffuseColor").Get()) == pytest.approx(m.base_color[:3])
        assert shader.GetInput("opacity").Get() == pytest.approx(m.alpha)
        assert shader.GetInput("metallic").Get() == pytest.approx(m.metallic)
        assert shader.GetInput("roughness").Get() == pytest.approx(m.roughness)
        assert tuple(shader.GetInput("emissiveColor").Get()) == pytest.approx(m.emission)


def test_usd_shape_key_is_a_blend_shape_that_deforms(built):
    """UsdSkel computes the shape key's positions at weight 1 from the authored data."""
    asset, stage = _usd_stage(built, "test_arm")
    visual = next(v for _, v in asset.visuals() if v.name == "oil_level")
    path = names.usd_visual_path(asset.id, "gauge", "oil_level")
    skel_root = UsdSkel.Root(stage.GetPrimAtPath(path))
    assert skel_root
    cache = UsdSkel.Cache()
    cache.Populate(skel_root, Usd.PrimDefaultPredicate)
    (binding,) = cache.ComputeSkelBindings(skel_root, Usd.PrimDefaultPredicate)
    anim = cache.GetSkelQuery(binding.GetSkeleton()).GetAnimQuery()
    assert list(anim.GetBlendShapeOrder()) == ["full"]
    assert list(anim.ComputeBlendShapeWeights()) == [0.0]
    (target,) = binding.GetSkinningTargets()
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(target.GetPrim()))
    weights, shapes, subs = query.ComputeSubShapeWeights(Vt.FloatArray([1.0]))
    points = Vt.Vec3fArray(UsdGeom.Mesh(target.GetPrim()).GetPointsAttr().Get())
    assert query.ComputeDeformedPoints(weights, shapes, subs, query.ComputeBlendShapePointIndices(),
                                       query.ComputeSubShapePointOffsets(), points)
    np.testing.assert_allclose(np.array(points), visual.mesh.shape_keys[0].vertices, atol=1e-6)


def test_usd_bad_input_is_a_user_error(tmp_path):
    asset = static_asset()
    link = asset.links[0]
    wrong = ir.Visual("shell", "missing", link.visuals[0].lods)
    bad = asset.with_(links=(ir.Link(link.name, link.pose, (wrong,), link.collisions),))
    with pytest.raises(UserError, match="missing"):
        usd.write(bad, tmp_path)
    with pytest.raises(UserError, match="missing"):
        gltf.write(bad, tmp_path)
    clash = asset.with_(links=(ir.Link("Looks", link.pose, link.visuals),))
    with pytest.raises(UserError, match="Looks"):
        usd.write(clash, tmp_path)
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ glTF readback

def read_glb(path: Path) -> tuple[dict, bytes]:
    """(JSON, BIN chunk) of a GLB, checking the container's framing."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    doc = json.loads(data[20:20 + json_len])
    rest = data[20 + json_len:]
    if not rest:
        return doc, b""
    bin_len, bin_type = struct.unpack_from("<II", rest, 0)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0 and bin_len == doc["buffers"][0]["byteLength"]
    return doc, rest[8:8 + bin_len]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc["type"]]
    start = view["byteOffset"] + acc.get("byteOffset", 0)
    return np.frombuffer(blob, dtype=dtype, count=acc["count"] * width, offset=start).reshape(acc["count"], width)


def node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"]).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    m = np.eye(4)
    m[:3, :3] = r @ np.diag(node.get("scale", [1.0, 1.0, 1.0]))
    m[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return m


def world_matrices(doc: dict) -> dict[int, np.ndarray]:
    out = {}

    def walk(i, parent):
        out[i] = parent @ node_matrix(doc["nodes"][i])
        for c in doc["nodes"][i].get("children", []):
            walk(c, out[i])

    for root in doc["scenes"][doc["scene"]]["nodes"]:
        walk(root, np.eye(4))
    return out


def _glb(built, asset_id):
    asset, folder, _ = built[asset_id]
    return (asset, *read_glb(folder / names.gltf_file(asset_id)))


def _node(doc, name):
    (i,) = [i for i, n in enumerate(doc["nodes"]) if n.get("name") == name]
    return i


def test_glb_hierarchy_follows_the_joint_tree(built):
    asset, doc, _ = _glb(built, "test_arm")
    (root,) = doc["scenes"][doc["scene"]]["nodes"]
    assert doc["nodes"][root]["name"] == "test_arm"

    def child_names(name):
        return sorted(doc["nodes"][c]["name"] for c in doc["nodes"][_node(doc, name)].get("children", []))

    assert child_names("test_arm") == ["base"]
    assert child_names("base") == ["arm", "body", "slider"]
    assert child_names("arm") == ["arm_shell", "gauge"]
    assert child_names("gauge") == ["needle", "oil_level"]
    assert child_names("slider") == ["slider_block"]
    extras = doc["nodes"][_node(doc, "gauge")]["extras"]["joint"]
    assert extras["name"] == "gauge_joint" and extras["type"] == "revolute" and extras["parent"] == "arm"
    assert extras["axis_ir"] == [0.0, 0.6, 0.8]
    np.testing.assert_allclose(extras["axis"], [0.0, 0.8, -0.6], atol=1e-12)  # (x, z, -y)
    assert (extras["lower"], extras["upper"]) == (-math.pi, math.pi)
    assert "extras" not in doc["nodes"][_node(doc, "base")]


def test_glb_world_transforms_are_y_up_ir(built):
    """Every visual's world matrix is C @ IR model-frame pose @ C^T, and a known vertex
    lands at (x, z, -y) of its IR model-frame position."""
    for asset_id in ("test_arm", "cabinet-1"):
        asset, doc, blob = _glb(built, asset_id)
        world = world_matrices(doc)
        c4 = np.eye(4)
        c4[:3, :3] = Z_TO_Y
        for link, visual in asset.visuals():
            (i,) = [i for i in world if doc["nodes"][i]["name"] == visual.name]
            ir_pose = link.pose @ visual.pose
            np.testing.assert_allclose(world[i], c4 @ ir_pose @ c4.T, atol=1e-12)
            prim = doc["meshes"][doc["nodes"][i]["mesh"]]["primitives"][0]
            pos = accessor(doc, blob, prim["attributes"]["POSITION"]).astype(np.float64)
            v_ir = (ir_pose @ np.append(visual.mesh.vertices[0], 1.0))[:3]
            v_gltf = (world[i] @ np.append(pos[0], 1.0))[:3]
            np.testing.assert_allclose(v_gltf, [v_ir[0], v_ir[2], -v_ir[1]], atol=1e-6)
            acc = doc["accessors"][prim["attributes"]["POSITION"]]
            assert acc["min"] == pos.min(axis=0).tolist() and acc["max"] == pos.max(axis=0).tolist()


def test_glb_msft_lod_nodes(built):
    asset, doc, _ = _glb(built, "test_arm")
    assert "MSFT_lod" in doc["extensionsUsed"] and "MSFT_lod" not in doc.get("extensionsRequired", [])
    in_scene = set(world_matrices(doc))
    as_child = {c for n in doc["nodes"] for c in n.get("children", [])}
    for link, visual in asset.visuals():
        node = doc["nodes"][_node(doc, visual.name)]
        if len(visual.lods) == 1:
            assert "extensions" not in node
            continue
        ids = node["extensions"]["MSFT_lod"]["ids"]
        assert len(ids) == len(visual.lods) - 1
        assert len(node["extras"]["MSFT_screencoverage"]) == len(visual.lods)
        for level, i in enumerate(ids, start=1):
            assert i not in in_scene and i not in as_child
            lod_mesh = doc["meshes"][doc["nodes"][i]["mesh"]]
            count = doc["accessors"][lod_mesh["primitives"][0]["indices"]]["count"]
            assert count == 3 * visual.lods[level].triangle_count


def test_glb_morph_targets(built):
    asset, doc, blob = _glb(built, "test_arm")
    node = doc["nodes"][_node(doc, "oil_level")]
    mesh = doc["meshes"][node["mesh"]]
    (target,) = mesh["primitives"][0]["targets"]
    assert mesh["extras"]["targetNames"] == ["full"] and mesh["weights"] == [0.0]
    visual = asset.link("gauge").visuals[1]
    delta = accessor(doc, blob, target["POSITION"])
    expected = (visual.mesh.shape_keys[0].vertices - visual.mesh.vertices) @ Z_TO_Y.T
    np.testing.assert_allclose(delta, expected, atol=1e-6)
    others = [m for m in doc["meshes"] if m is not mesh]
    assert all("targets" not in p for m in others for p in m["primitives"])


def test_glb_material_variants(built):
    asset, doc, _ = _glb(built, "test_arm")
    variants = [v["name"] for v in doc["extensions"]["KHR_materials_variants"]["variants"]]
    assert variants == ["alarm:steel", "alarm:lamp_glass"]
    materials = [m["name"] for m in doc["materials"]]
    prim = doc["meshes"][doc["nodes"][_node(doc, "oil_level")]["mesh"]]["primitives"][0]
    assert materials[prim["material"]] == "lamp_glass"
    mappings = prim["extensions"]["KHR_materials_variants"]["mappings"]
    chosen = {variants[v]: materials[m["material"]] for m in mappings for v in m["variants"]}
    assert chosen == {"alarm:steel": "steel", "alarm:lamp_glass": "lamp_glass"}
    needle = doc["meshes"][doc["nodes"][_node(doc, "needle")]["mesh"]]["primitives"][0]
    assert "extensions" not in needle


def test_glb_materials(built):
    _, doc, _ = _glb(built, "test_arm")
    mats = {m["name"]: m for m in doc["materials"]}
    glass = mats["lamp_glass"]
    assert glass["alphaMode"] == "BLEND"
    assert glass["pbrMetallicRoughness"]["baseColorFactor"] == [0.9, 0.2, 0.1, 0.6]
    assert glass["emissiveFactor"] == [1.0, 0.3, 0.05] and "extensions" not in glass
    assert "alphaMode" not in mats["steel"] and mats["steel"]["pbrMetallicRoughness"]["metallicFactor"] == 0.9
    _, doc, _ = _glb(built, "cabinet-1")
    (paint,) = doc["materials"]
    assert paint["emissiveFactor"] == [1.0, 0.5, 0.0]
    assert paint["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] == 4.0
    assert "KHR_materials_emissive_strength" in doc["extensionsUsed"]


# ------------------------------------------------------------------ Blender

_BLENDER_SCRIPT = textwrap.dedent("""
    import json, sys
    import bpy

    def objects():
        return {o.name: {"type": o.type, "parent": o.parent.name if o.parent else None,
                         "world": [list(r) for r in o.matrix_world],
                         "keys": [k.name for k in o.data.shape_keys.key_blocks]
                                 if o.type == "MESH" and o.data.shape_keys else []}
                for o in bpy.data.objects}

    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert "FINISHED" in bpy.ops.import_scene.gltf(filepath=sys.argv[1])
    gltf = objects()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert "FINISHED" in bpy.ops.wm.usd_import(filepath=sys.argv[2])
    usd = objects()
    print("RESULT " + json.dumps({"gltf": gltf, "usd": usd}))
""")


@pytest.mark.blender
def test_blender_reimports_glb_and_usdc(built):
    pytest.importorskip("bpy")
    asset, folder, _ = built["test_arm"]
    out = subprocess.run([sys.executable, "-c", _BLENDER_SCRIPT, str(folder / names.gltf_file(asset.id)),
                          str(folder / names.usd_file(asset.id))], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    (line,) = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    found = json.loads(line[len("RESULT "):])
    g, u = found["gltf"], found["usd"]
    # glTF: Blender converts back to Z up, so world matrices are the IR's again.
    for link in asset.links:
        assert link.name in g, link.name
        np.testing.assert_allclose(np.array(g[link.name]["world"]), link.pose, atol=1e-5)
    for joint in asset.joints:
        assert g[joint.child]["parent"] == joint.parent
    for link, visual in asset.visuals():
        assert g[visual.name]["parent"] == link.name
        np.testing.assert_allclose(np.array(g[visual.name]["world"]), link.pose @ visual.pose, atol=1e-5)
    assert g["oil_level"]["keys"] == ["Basis", "full"]
    # USD: one object per link prim, directly under the asset root, at the link pose.
    for link in asset.links:
        assert u[link.name]["parent"] == "test_arm"
        np.testing.assert_allclose(np.array(u[link.name]["world"]), link.pose, atol=1e-5)
    assert any(o["keys"] == ["Basis", "full"] for o in u.values())
