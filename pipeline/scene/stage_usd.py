"""The OpenUSD scene: /Site (kind assembly) with one instanceable reference per
placement, the LOD picked by variant selection, the terrain, and a DistantLight sun."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..export.names import SCENE_ROOT, scene_placement_path, usd_file
from .placements import Placed


def _rel(target: Path, start: Path) -> str:
    return "./" + os.path.relpath(target, start).replace(os.sep, "/")


def write(path: Path, *, site_name: str, models: Path, origin_llh, crs: str, placed: list[Placed],
          terrain_model: str, sun: dict) -> None:
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux

    path = Path(path)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    layer.customLayerData = {
        "site": site_name,
        "crs": crs,
        "frame": "ENU topocentric at the geodetic origin (WGS84 ellipsoidal height)",
        "geodetic_origin": {"latitude_deg": float(origin_llh[0]), "longitude_deg": float(origin_llh[1]),
                            "height_m": float(origin_llh[2])},
    }
    site = UsdGeom.Xform.Define(stage, SCENE_ROOT)
    Usd.ModelAPI(site).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(site.GetPrim())
    UsdGeom.Scope.Define(stage, f"{SCENE_ROOT}/Placements")

    terrain = UsdGeom.Xform.Define(stage, f"{SCENE_ROOT}/Terrain")
    terrain.GetPrim().GetReferences().AddReference(_rel(models / terrain_model / usd_file(terrain_model), path.parent))

    for pl in sorted(placed, key=lambda p: p.placement.tag):
        prim_path = scene_placement_path(pl.placement.tag)
        xf = UsdGeom.Xform.Define(stage, prim_path)
        prim = xf.GetPrim()
        asset_id = pl.placement.asset_id
        prim.GetReferences().AddReference(_rel(models / asset_id / usd_file(asset_id), path.parent))
        x, y, z = (float(v) for v in pl.pose[:3, 3])
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(x, y, z))
        xf.AddRotateZOp(UsdGeom.XformOp.PrecisionDouble).Set(float(np.degrees(pl.yaw)))
        vsets = prim.GetVariantSets()
        if "lod" in vsets.GetNames():
            vsets.GetVariantSet("lod").SetVariantSelection(f"lod{pl.lod}")
        prim.SetInstanceable(True)
        prim.SetCustomDataByKey("tag", pl.placement.tag)
        prim.SetCustomDataByKey("asset", asset_id)
        prim.SetCustomDataByKey("level", pl.placement.level)
        if pl.placement.state:
            prim.SetCustomDataByKey("state", pl.placement.state)

    light = UsdLux.DistantLight.Define(stage, f"{SCENE_ROOT}/Sun")
    light.CreateIntensityAttr(float(sun["intensity"]))
    light.CreateAngleAttr(0.53)
    # DistantLight shines along its local -Z: aim -Z at the sunlight's direction.
    el, az = sun["elevation_deg"], sun["azimuth_deg"]
    to_sun = Gf.Vec3d(np.sin(np.radians(az)) * np.cos(np.radians(el)),
                      np.cos(np.radians(az)) * np.cos(np.radians(el)), np.sin(np.radians(el)))
    rot = Gf.Rotation(Gf.Vec3d(0, 0, 1), to_sun)
    xf = UsdGeom.Xformable(light)
    xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(rot.GetQuat()))
    tmp = path.with_name(path.name + ".tmp.usda")
    layer.Export(str(tmp))
    os.replace(tmp, path)
