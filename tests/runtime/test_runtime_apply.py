"""Appliers on a tiny hand-made package: USD layer time samples equal the bindings'
mapping of the trace, the layer validates, the animated glb validates, SDF variants."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fixtures_assets import box_arrays, box_mesh
from helpers import SOURCES
from pipeline import ir
from pipeline.export import manifest, names
from pipeline.runtime import graph, nodes, run

TAG = "R-1"
ASSET = "tiny_reactor"


LAMP_ON_BELOW = 90.0  # % tank level; the 20 s run goes 101 -> 81.8, so the lamp switches once


def tiny_asset() -> ir.Asset:
    v, f = box_arrays((0.1, 0.1, 0.1), (0.05, 0.05, 0.05))  # a 10 cm cube on the origin's corner
    column = ir.Mesh(v, f, shape_keys=(ir.ShapeKey("full", v * [1, 1, 5]),))
    rest = np.eye(4)
    rest[:3, 3] = (0.2, -0.5, 1.0)
    visuals = (
        ir.Visual("tank", "steel", (box_mesh((1.0, 1.0, 1.0), (0.5, 0.5, 0.5)),)),
        ir.Visual("pointer", "black", (ir.Mesh(v, f),), pose=rest),
        ir.Visual("column", "oil", (column,)),
        ir.Visual("lamp", "lamp_off", (ir.Mesh(v, f),)),
    )
    mats = (ir.Material("steel"), ir.Material("black", (0.02, 0.02, 0.02, 1.0)), ir.Material("oil", (0.6, 0.4, 0.1, 1.0)),
            ir.Material("lamp_off", (0.3, 0.3, 0.3, 1.0)), ir.Material("lamp_red", (1, 0, 0, 1), emission=(5.0, 0, 0)))
    bindings = (
        ir.StateBinding("oil_level_tank", "rotate", "pointer", (0.0, 100.0), (-2.0, 2.0), axis=(0.0, -1.0, 0.0)),
        ir.StateBinding("oil_level_tank", "material", "lamp", (0.0, 100.0), materials=("lamp_red", "lamp_off"),
                        thresholds=(LAMP_ON_BELOW,)),
        ir.StateBinding("oil_level_b1", "shape", "column", (0.0, 100.0), (0.0, 1.0), shape_key="full"),
    )
    return ir.Asset(ASSET, "reactor", (ir.Link("body", visuals=visuals),), materials=mats, bindings=bindings)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """build/models/<asset>/ (manifest + USD + glb + SDF by the project writers),
    build/scene/site.usda and placements.json as the scene assembly lays them out."""
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux

    from pipeline.export import gltf, sdf, usd

    build = tmp_path_factory.mktemp("build")
    asset = tiny_asset()
    pkg = build / "models" / ASSET
    outputs = usd.write(asset, pkg) + gltf.write(asset, pkg) + sdf.write(asset, pkg)
    manifest.write(manifest.content(asset, source={"sha256": "0"}, outputs={o: "0" for o in outputs}, lod_models=[]), pkg)
    scene = build / "scene"
    scene.mkdir()
    stage = Usd.Stage.CreateNew(str(scene / "site.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    site = UsdGeom.Xform.Define(stage, names.SCENE_ROOT)
    Usd.ModelAPI(site).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(site.GetPrim())
    UsdGeom.Scope.Define(stage, f"{names.SCENE_ROOT}/Placements")
    xf = UsdGeom.Xform.Define(stage, names.scene_placement_path(TAG))
    xf.GetPrim().GetReferences().AddReference(f"../models/{ASSET}/{names.usd_file(ASSET)}")
    xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(10, 20, 0))
    xf.GetPrim().SetInstanceable(True)
    light = UsdLux.DistantLight.Define(stage, f"{names.SCENE_ROOT}/Sun")
    light.CreateIntensityAttr(1000.0)
    UsdGeom.Xformable(light).AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(1, 0, 0, 0))
    stage.GetRootLayer().Save()
    (scene / "placements.json").write_text(json.dumps({"placements": [
        {"tag": TAG, "asset": ASSET, "state": "reactor_A1"}, {"tag": "X", "asset": ASSET, "state": None}]}))
    return build


def scenario_file(tmp_path) -> Path:
    text = (SOURCES / "scenarios" / "oil_leak.toml").read_text()
    text = text.replace('assets = ["shunt_reactor"]', f'assets = ["{ASSET}"]').replace("duration_s = 60.0", "duration_s = 20.0")
    text = text.split("[[edges]]\nfrom = \"bushing_2.level\"")[0]  # the tiny asset binds no oil_level_b2
    f = tmp_path / "oil_leak.toml"
    f.write_text(text)
    return f


@pytest.fixture(scope="module")
def result(built, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    summary = run.run_scenario(scenario_file(out), built, out)
    return built, out, summary


def trace(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "states.jsonl").read_text().splitlines()]


def test_states_jsonl_has_every_output_per_step(result):
    _, out, summary = result
    rows = trace(out)
    assert summary["steps"] == len(rows) == 21
    assert rows[5]["outputs"]["tank.level"] == pytest.approx(95.95)
    assert list(rows[0]["outputs"]) == sorted(rows[0]["outputs"])
    assert {"sun.elevation", "bushing_2.level", "camera.hfov", "clock.t"} <= set(rows[0]["outputs"])


def test_usd_layer_samples_equal_the_binding_mapping(result):
    from pxr import Usd, UsdGeom, UsdLux, UsdShade, UsdSkel

    _, out, summary = result
    rows = trace(out)
    stage = Usd.Stage.Open(str(out / "states.usda"))
    assert stage.GetTimeCodesPerSecond() == 1.0
    placement = names.scene_placement_path(TAG)
    pointer = stage.GetPrimAtPath(f"{placement}/body/pointer")
    op = pointer.GetAttribute("xformOp:orient:twin_oil_level_tank")
    assert op.GetNumTimeSamples() == len(rows)
    rot = ir.StateBinding("oil_level_tank", "rotate", "pointer", (0.0, 100.0), (-2.0, 2.0))
    shape = ir.StateBinding("oil_level_b1", "shape", "column", (0.0, 100.0), (0.0, 1.0))
    anim = UsdSkel.Animation(stage.GetPrimAtPath(f"{placement}/body/column/skel/anim"))
    lamp_state = stage.GetPrimAtPath(placement).GetAttribute("twin:state_oil_level_tank")
    # The lamp's mesh shows its state look, whose inputs follow the selected material.
    lamp_mesh = next(c for c in stage.GetPrimAtPath(f"{placement}/body/lamp").GetChildren() if c.GetTypeName() == "Mesh")
    bound, _ = UsdShade.MaterialBindingAPI(lamp_mesh).ComputeBoundMaterial()
    assert bound.GetPath() == f"{placement}/TwinLooks/lamp"
    look = UsdShade.Shader(stage.GetPrimAtPath(f"{placement}/TwinLooks/lamp/PreviewSurface"))
    assert {bool(row["outputs"]["tank.level"] < LAMP_ON_BELOW) for row in rows} == {True, False}  # both seen
    for k, row in enumerate(rows):
        q = op.Get(k)
        angle = 2 * math.atan2(q.GetImaginary().GetLength(), q.GetReal())
        axis = q.GetImaginary().GetNormalized() if angle > 1e-12 else None
        expected = rot.output(row["outputs"]["tank.level"])
        signed = angle if axis is None or axis[1] < 0 else -angle  # binding axis is -Y
        assert signed == pytest.approx(expected, abs=1e-6)
        assert anim.GetBlendShapeWeightsAttr().Get(k)[0] == pytest.approx(shape.output(row["outputs"]["bushing_1.level"]), abs=1e-6)
        red = row["outputs"]["tank.level"] < LAMP_ON_BELOW
        assert lamp_state.Get(k) == ("s0" if red else "s1")
        assert tuple(look.GetInput("diffuseColor").Get(k)) == pytest.approx((1, 0, 0) if red else (0.3, 0.3, 0.3))
        assert tuple(look.GetInput("emissiveColor").Get(k)) == pytest.approx((5, 0, 0) if red else (0, 0, 0))
    # The composed pointer = rest pose then the rotation about its own axis.
    m = np.array(UsdGeom.Xformable(pointer).GetLocalTransformation(5)).T
    rest = np.eye(4)
    rest[:3, 3] = (0.2, -0.5, 1.0)
    expected = rest @ nodes.delta_matrix("rotate", (0, -1, 0), rot.output(rows[5]["outputs"]["tank.level"]))
    np.testing.assert_allclose(m, expected, atol=1e-9)
    sun = UsdLux.DistantLight(stage.GetPrimAtPath("/Site/Sun"))
    assert sun.GetIntensityAttr().Get(3) == pytest.approx(rows[3]["outputs"]["sun.irradiance"], rel=1e-6)  # float
    world = np.array(UsdGeom.Xformable(sun).ComputeLocalToWorldTransform(3)).T
    e, a = rows[3]["outputs"]["sun.elevation"], rows[3]["outputs"]["sun.azimuth"]
    to_sun = [math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), math.sin(e)]
    assert world[:3, 2] == pytest.approx(to_sun, abs=1e-9)  # +Z towards the sun: light travels -Z
    assert summary["appliers"]["usd"]["not_applied"] == []


def test_usd_layer_passes_usd_validation(result):
    _, out, _ = result
    try:
        from pipeline.validate.external import usd_validation
    except ImportError:
        pytest.skip("pipeline.validate.external not available")
    res = usd_validation(out / "states.usda")
    assert res.status == "passed", res.messages


def test_animated_glb_passes_the_gltf_validator(result):
    from pipeline import glb

    _, out, summary = result
    (path,) = summary["appliers"]["gltf"]["files"]
    doc, _ = glb.read(path)
    (anim,) = doc["animations"]
    assert sorted(c["target"]["path"] for c in anim["channels"]) == ["rotation", "weights"]
    sel = anim["extras"]["KHR_materials_variants_selection"]
    assert len(sel) == 21 and {x["variant"] for x in sel} == {"oil_level_tank:lamp_off", "oil_level_tank:lamp_red"}
    declared = {v["name"] for v in doc["extensions"]["KHR_materials_variants"]["variants"]}
    assert "oil_level_tank:lamp_off" in declared and "oil_level_tank:lamp_red" in declared
    try:
        from pipeline.validate.external import gltf_validator
    except ImportError:
        pytest.skip("pipeline.validate.external not available")
    (res,) = gltf_validator([Path(path)])
    if res.status == "skipped":
        pytest.skip("glTF validator not installed")
    assert res.status == "passed", res.messages


def test_sdf_variants_and_sun_fragments(result):
    from lxml import etree

    _, out, summary = result
    s = summary["appliers"]["sdf"]
    table = [json.loads(x) for x in (out / "sdf" / "variants.jsonl").read_text().splitlines()]
    assert len(table) == 21 and all(TAG in row["placements"] for row in table)
    # Tank level 101 -> 81.8 over 20 s and b1 moves: 10 % steps give a handful of variants.
    assert 2 <= s["variant_count"] <= 8
    first = table[0]["placements"][TAG].removeprefix("model://")
    root = etree.parse(str(out / "sdf" / "models" / first / "model.sdf"))
    assert root.find("model").get("name") == first
    lamp = root.find("model/link/visual[@name='lamp']/material/emissive").text
    assert float(lamp.split()[0]) == 0.0  # the level starts above LAMP_ON_BELOW: lamp off
    last = table[-1]["placements"][TAG].removeprefix("model://")
    root = etree.parse(str(out / "sdf" / "models" / last / "model.sdf"))
    lamp = root.find("model/link/visual[@name='lamp']/material/emissive").text
    assert float(lamp.split()[0]) > 0.0  # and ends below it: lamp red, glowing
    sun = [json.loads(x) for x in (out / "sdf" / "sun.jsonl").read_text().splitlines()]
    assert len(sun) == 21 and sun[0]["direction"][2] < 0
    assert any("shape" in n for n in s["not_applied"])


def test_unbound_render_input_is_a_user_error(built, tmp_path):
    from pipeline.errors import UserError

    f = scenario_file(tmp_path)
    f.write_text(f.read_text().replace("render.reactor_A1.oil_level_b1", "render.reactor_A1.oil_levle_b1"))
    with pytest.raises(UserError, match="reactor_A1.oil_levle_b1"):
        run.run_scenario(f, built, tmp_path / "out")


def test_visual_states_compose_rest_and_rotation(built):
    ob = run.load_observed(built)[0]
    (ptr,) = [v for v in nodes.visual_states({"reactor_A1": {"oil_level_tank": 75.0}}, [ob]) if v.visual == "pointer"]
    c, s = math.cos(1.0), math.sin(1.0)  # output 1 rad about -Y
    np.testing.assert_allclose(ptr.transform[:3, :3], [[c, 0, -s], [0, 1, 0], [s, 0, c]], atol=1e-12)
    np.testing.assert_allclose(ptr.transform[:3, 3], [0.2, -0.5, 1.0])
