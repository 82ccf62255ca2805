"""USD applier: build/runs/<scenario>/states.usda, a layer over the scene stage.

The layer sublayers build/scene/<site>.usda and authors, at time code k (t = k step_s,
timeCodesPerSecond = 1 / step_s):

- per bound visual (scene_placement_path(TAG)/<link>/<visual>): one extra xformOp
  appended after the rest pose the model authors, so local = rest @ delta:
  `xformOp:orient:twin_<variable>` (quatd, rotation about the binding axis),
  `xformOp:translate:twin_<variable>` or `xformOp:transform:twin_<variable>` (scale
  along the axis);
- shape bindings: `blendShapeWeights` of the visual's SkelAnimation (<visual>/skel/anim,
  the USD writer's layout), in the animation's blendShapes order;
- material bindings: USD cannot time-sample a relationship or a variant selection, so
  the visual is bound to its own state look, `<placement>/TwinLooks/<visual>` (a
  UsdPreviewSurface whose diffuse, emissive, metallic, roughness and opacity are
  time-sampled from the manifest's PBR values of the material each step selects), which
  any USD player shows as it plays. The model's variant `state_<variable>` is selected
  for the first step, and the selection is time-sampled as the token attribute
  `twin:state_<variable>` on the placement prim (for a player that swaps variants);
- the sun DistantLight /Site/Sun: `xformOp:orient` (+Z towards the sun, as the scene
  writer aims it) and `inputs:intensity` = irradiance (W/m2) x sun_intensity_scale.

Stateful placements are made non-instanceable here: opinions below an instance are
ignored, and each driven placement needs its own pointer.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..export import names
from ..files import atomic_path
from ..geometry.transform import quaternion_from_axis_angle
from .nodes import delta_matrix

SUN_PATH = f"{names.SCENE_ROOT}/Sun"


def _quat(Gf, axis, angle: float):
    """Gf.Quatd (real part first, as the pipeline's (w, x, y, z)) of a rotation by
    `angle` rad about `axis`."""
    w, x, y, z = (float(c) for c in quaternion_from_axis_angle(axis, angle))
    return Gf.Quatd(w, Gf.Vec3d(x, y, z))


LOOK_INPUTS = (("diffuseColor", "Color3f"), ("emissiveColor", "Color3f"), ("metallic", "Float"),
               ("roughness", "Float"), ("opacity", "Float"))


def state_materials(frame, stage, materials: dict, looks: dict):
    """(visual prim path, manifest material record) of every visual whose material a
    state selects in this frame; binds a new state look to a visual seen first."""
    from pxr import UsdShade

    for vs in frame:
        record = materials.get(vs.tag, {}).get(vs.material) if vs.material else None
        if record is None:
            continue
        placement = names.scene_placement_path(vs.tag)
        path = f"{placement}/{names.safe_name(vs.link)}/{names.safe_name(vs.visual)}"
        if path not in looks:
            visual = stage.GetPrimAtPath(path)
            if not visual:
                continue
            look = UsdShade.Material.Define(stage, f"{placement}/TwinLooks/{names.safe_name(vs.visual)}")
            shader = UsdShade.Shader.Define(stage, look.GetPath().AppendChild("PreviewSurface"))
            shader.CreateIdAttr("UsdPreviewSurface")
            look.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            meshes = [c for c in visual.GetChildren() if c.GetTypeName() == "Mesh"] or [visual]
            for mesh in meshes:  # a binding on the mesh itself: stronger than the model's
                UsdShade.MaterialBindingAPI.Apply(mesh).Bind(look)
            looks[path] = shader
        yield path, record


def _set_look(shader, record: dict, k: int) -> None:
    from pxr import Gf, Sdf

    r, g, b, a = (float(c) for c in record["base_color"])
    values = {"diffuseColor": Gf.Vec3f(r, g, b), "emissiveColor": Gf.Vec3f(*(float(c) for c in record["emission"])),
              "metallic": float(record["metallic"]), "roughness": float(record["roughness"]), "opacity": a}
    for name, type_name in LOOK_INPUTS:
        shader.CreateInput(name, getattr(Sdf.ValueTypeNames, type_name)).Set(values[name], k)


def write(run, scene_usda: Path, out_path: Path) -> dict:
    """Author the layer; returns a summary (samples written, things not applied)."""
    out_path = Path(out_path)
    # Authored in a file beside the target, so the relative sublayer path resolves.
    with atomic_path(out_path) as tmp:
        return _author(run, Path(scene_usda), out_path, tmp)


def _author(run, scene_usda: Path, out_path: Path, tmp: Path) -> dict:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdSkel, Vt
    layer = Sdf.Layer.CreateNew(str(tmp))
    layer.subLayerPaths.append(os.path.relpath(Path(scene_usda).resolve(), out_path.parent.resolve()).replace(os.sep, "/"))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    step = run.scenario.step_s
    stage.SetTimeCodesPerSecond(1.0 / step)
    stage.SetFramesPerSecond(1.0 / step)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(len(run.times) - 1)
    site = stage.GetPrimAtPath(names.SCENE_ROOT)
    if site:
        stage.SetDefaultPrim(site)
    layer.customLayerData = {"scenario": run.scenario.name, "seed": run.scenario.seed, "step_s": step}

    skipped: list[str] = []
    samples = 0
    ops: dict[tuple, object] = {}
    materials = {o.tag: {m["name"]: m for m in o.manifest.get("materials", [])} for o in run.observed}
    looks: dict[str, object] = {}  # visual prim path -> the PreviewSurface of its state look
    for tag in sorted({o.tag for o in run.observed}):
        prim = stage.GetPrimAtPath(names.scene_placement_path(tag))
        if prim:
            prim.SetInstanceable(False)
    for k, frame in enumerate(run.frames):
        for vs in frame:
            placement = names.scene_placement_path(vs.tag)
            path = f"{placement}/{names.safe_name(vs.link)}/{names.safe_name(vs.visual)}"
            prim = stage.GetPrimAtPath(path)
            if not prim:
                key = ("missing", path)
                if key not in ops:
                    ops[key] = None
                    skipped.append(f"{path}: no such prim in the scene")
                continue
            for bo in vs.outputs:
                rec = bo.binding
                var = names.safe_name(rec["variable"])
                effect = rec["effect"]
                key = (path, var, effect)
                if effect in ("rotate", "translate", "scale"):
                    if key not in ops:
                        kind = {"rotate": UsdGeom.XformOp.TypeOrient, "translate": UsdGeom.XformOp.TypeTranslate,
                                "scale": UsdGeom.XformOp.TypeTransform}[effect]
                        ops[key] = UsdGeom.Xformable(prim).AddXformOp(kind, UsdGeom.XformOp.PrecisionDouble, f"twin_{var}")
                    op, y, axis = ops[key], float(bo.output), rec.get("axis") or (0.0, 0.0, 1.0)
                    if effect == "rotate":
                        op.Set(_quat(Gf, axis, y), k)
                    elif effect == "translate":
                        a = np.asarray(axis, float) / (np.linalg.norm(axis) or 1.0)
                        op.Set(Gf.Vec3d(*(a * y)), k)
                    else:
                        op.Set(Gf.Matrix4d(delta_matrix("scale", axis, y).T.tolist()), k)
                    samples += 1
                elif effect == "shape":
                    if key not in ops:
                        anim = UsdSkel.Animation(stage.GetPrimAtPath(f"{path}/skel/anim"))
                        ops[key] = anim if anim else None
                        if not anim:
                            skipped.append(f"{path}: shape binding {rec['variable']} but no SkelAnimation at {path}/skel/anim")
                    anim = ops[key]
                    if anim:
                        order = list(anim.GetBlendShapesAttr().Get() or [])
                        weights = [0.0] * len(order)
                        for key_name, w in vs.shape_weights.items():
                            if names.safe_name(key_name) in order:
                                weights[order.index(names.safe_name(key_name))] = w
                        anim.GetBlendShapeWeightsAttr().Set(Vt.FloatArray(weights), k)
                        samples += 1
                elif effect == "material":
                    placement_prim = stage.GetPrimAtPath(placement)
                    vset_name = f"state_{var}"
                    if key not in ops:
                        ops[key] = placement_prim.CreateAttribute(f"twin:state_{var}", Sdf.ValueTypeNames.Token,
                                                                  custom=True, variability=Sdf.VariabilityVarying)
                        vsets = placement_prim.GetVariantSets()
                        if vset_name in vsets.GetNames():
                            vsets.GetVariantSet(vset_name).SetVariantSelection(f"s{int(bo.output)}")
                        else:
                            skipped.append(f"{placement}: no variant set {vset_name} (material binding not selectable)")
                    ops[key].Set(f"s{int(bo.output)}", k)
                    samples += 1
        for path, material in state_materials(frame, stage, materials, looks):
            _set_look(looks[path], material, k)
            samples += 1
    sun_samples = 0
    if run.sun is not None:
        light = UsdLux.DistantLight(stage.GetPrimAtPath(SUN_PATH))
        if not light:
            skipped.append(f"{SUN_PATH}: no DistantLight in the scene")
        else:
            xf = UsdGeom.Xformable(light)
            orient = next((op for op in xf.GetOrderedXformOps() if op.GetOpType() == UsdGeom.XformOp.TypeOrient), None)
            if orient is None:
                orient = xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble)
            intensity = light.GetIntensityAttr() or light.CreateIntensityAttr()
            for k, (elev, az, irr) in enumerate(run.sun):
                to_sun = Gf.Vec3d(math.sin(az) * math.cos(elev), math.cos(az) * math.cos(elev), math.sin(elev))
                q = Gf.Quatd(Gf.Rotation(Gf.Vec3d(0, 0, 1), to_sun).GetQuat())
                orient.Set(q if orient.GetPrecision() == UsdGeom.XformOp.PrecisionDouble else Gf.Quatf(q), k)
                intensity.Set(float(irr) * run.sun_intensity_scale, k)
                sun_samples += 1
    layer.Save()
    return {"file": str(out_path), "visual_samples": samples, "sun_samples": sun_samples, "not_applied": skipped}
