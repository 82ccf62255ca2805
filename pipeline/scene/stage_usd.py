"""The OpenUSD scene: /Site (kind assembly) with one reference per placement
(instanceable unless the model is articulated), the LOD picked by variant selection,
the terrain, and a DistantLight sun.

Authored with the Sdf layer API, not through a stage: nothing is composed while
writing (hundreds of references would be opened for nothing), and references are
written relative to the scene file's final place, build/scene/.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..export.names import safe_name, usd_file
from ..files import atomic_path
from .placements import Placed

MODELS_FROM_SCENE = "../models"  # build/scene/ -> build/models/


def _reference(model: str) -> str:
    return f"{MODELS_FROM_SCENE}/{model}/{usd_file(model)}"


def _attr(prim, name: str, type_name, value, uniform: bool = False):
    from pxr import Sdf

    variability = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    spec = Sdf.AttributeSpec(prim, name, type_name, variability)
    spec.default = value
    return spec


def sun_orientation(elevation_deg: float, azimuth_deg: float):
    """Quaternion turning a DistantLight's -Z (its shining direction) onto the
    sunlight's direction in ENU (azimuth clockwise from north)."""
    from pxr import Gf

    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    to_sun = Gf.Vec3d(np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el))
    return Gf.Quatd(Gf.Rotation(Gf.Vec3d(0, 0, 1), to_sun).GetQuat())


def write(path: Path, *, site_name: str, models: Path, origin_llh, crs: str, placed: list[Placed],
          terrain_model: str, sun: dict, articulated: frozenset[str] = frozenset(), extra=None) -> None:
    """`extra(site_prim)`: authors more prims under /Site (the conductors).
    `articulated`: asset ids with joints. Their placements are not instanceable:
    physics refuses RigidBodyAPI on instance proxies, and each one's joints move on
    their own (a switch open here, closed there)."""
    from pxr import Gf, Sdf, Vt

    path = Path(path)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    layer.pseudoRoot.SetInfo("upAxis", "Z")
    layer.defaultPrim = "Site"
    layer.customLayerData = {
        "site": site_name,
        "crs": crs,
        "frame": "ENU topocentric at the geodetic origin (WGS84 ellipsoidal height)",
        "geodetic_origin": {"latitude_deg": float(origin_llh[0]), "longitude_deg": float(origin_llh[1]),
                            "height_m": float(origin_llh[2])},
    }
    site = Sdf.PrimSpec(layer, "Site", Sdf.SpecifierDef, "Xform")
    site.SetInfo("kind", "assembly")
    scope = Sdf.PrimSpec(site, "Placements", Sdf.SpecifierDef, "Scope")

    terrain = Sdf.PrimSpec(site, "Terrain", Sdf.SpecifierDef, "Xform")
    terrain.referenceList.Prepend(Sdf.Reference(_reference(terrain_model)))

    # a prim spec and three attribute specs a placement, tens of thousands on a large
    # plan: the loop keeps to what Sdf needs, the numbers converted for all at once
    op_order = Vt.TokenArray(["xformOp:translate", "xformOp:rotateZ"])
    scaled_order = Vt.TokenArray(["xformOp:translate", "xformOp:rotateZ", "xformOp:scale"])  # insert_scale = "apply"
    double3, double, tokens = Sdf.ValueTypeNames.Double3, Sdf.ValueTypeNames.Double, Sdf.ValueTypeNames.TokenArray
    varying, uniform = Sdf.VariabilityVarying, Sdf.VariabilityUniform
    placed = sorted(placed, key=lambda p: p.placement.tag)
    positions = np.array([pl.pose[:3, 3] for pl in placed], dtype=np.float64).reshape(-1, 3).tolist()
    yaws_deg = np.degrees([pl.yaw for pl in placed]).tolist()
    for pl, position, yaw_deg in zip(placed, positions, yaws_deg):
        p = pl.placement
        prim = Sdf.PrimSpec(scope, safe_name(p.tag), Sdf.SpecifierDef, "Xform")
        prim.referenceList.Prepend(Sdf.Reference(_reference(p.asset_id)))
        prim.variantSelections["lod"] = f"lod{pl.lod}"
        prim.instanceable = p.asset_id not in articulated
        Sdf.AttributeSpec(prim, "xformOp:translate", double3, varying).default = Gf.Vec3d(*position)
        Sdf.AttributeSpec(prim, "xformOp:rotateZ", double, varying).default = yaw_deg
        if p.scale != 1.0:
            Sdf.AttributeSpec(prim, "xformOp:scale", double3, varying).default = Gf.Vec3d(p.scale, p.scale, p.scale)
        Sdf.AttributeSpec(prim, "xformOpOrder", tokens, uniform).default = scaled_order if p.scale != 1.0 else op_order
        data = {"tag": p.tag, "asset": p.asset_id, "level": p.level}
        if p.state:
            data["state"] = p.state
        prim.customData = data

    light = Sdf.PrimSpec(site, "Sun", Sdf.SpecifierDef, "DistantLight")
    _attr(light, "inputs:intensity", Sdf.ValueTypeNames.Float, float(sun["intensity"]))
    _attr(light, "inputs:angle", Sdf.ValueTypeNames.Float, 0.53)
    _attr(light, "xformOp:orient", Sdf.ValueTypeNames.Quatd, sun_orientation(sun["elevation_deg"], sun["azimuth_deg"]))
    _attr(light, "xformOpOrder", Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(["xformOp:orient"]), uniform=True)

    if extra is not None:
        extra(site)
    with atomic_path(path) as tmp:  # its temporary name keeps .usda: Export's format
        layer.Export(str(tmp))
