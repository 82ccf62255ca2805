"""Placement poses read back from each format a build writes (SDF, USD, glTF) and
computed independently from the raw DXF with ezdxf and pyproj alone: the end-to-end
tests of the mini site and of the sample compare the two."""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
import numpy as np
from lxml import etree
from pyproj import CRS, Transformer

SAFE_XML = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)


def independent_poses(sources: Path) -> dict[str, tuple[np.ndarray, float]]:
    """TAG -> (ENU position, ENU yaw in degrees), from the DXF with ezdxf and pyproj
    only: similarity -> UTM -> WGS84 ellipsoidal -> ECEF -> ENU (numpy rotation)."""
    import tomllib

    site = tomllib.loads((sources / "site.toml").read_text())
    e0, n0 = site["plan"]["grid_origin"]
    r = math.radians(site["plan"].get("grid_rotation_deg", 0.0))
    s = site["plan"].get("grid_scale", 1.0)
    elev = {lv["name"]: lv["elevation"] for lv in site["levels"]}
    doc = ezdxf.readfile(sources / site["site"]["floorplan"])
    unit = {4: 0.001, 6: 1.0}[doc.header.get("$INSUNITS", 6)]
    crs = CRS.from_user_input(site["plan"]["crs"])
    to_geo = Transformer.from_crs(crs, CRS.from_epsg(4979), always_xy=True)
    to_ecef = Transformer.from_crs(CRS.from_epsg(4979), CRS.from_epsg(4978), always_xy=True)

    def grid(x, y):
        return e0 + s * (x * math.cos(r) - y * math.sin(r)), n0 + s * (x * math.sin(r) + y * math.cos(r))

    if "origin" in site:  # as given; by default the centre of the platforms, lowest level
        lon0, lat0, h0 = site["origin"]["lon"], site["origin"]["lat"], site["origin"]["height"]
    else:
        platforms = [np.array(p.get_points("xy")) * unit for p in doc.modelspace().query("LWPOLYLINE")]
        pts = np.concatenate(platforms)
        cx, cy = (pts.min(axis=0) + pts.max(axis=0)) / 2
        lon0, lat0, h0 = to_geo.transform(*grid(cx, cy), min(elev.values()))
    o = np.array(to_ecef.transform(lon0, lat0, h0))
    la, lo = math.radians(lat0), math.radians(lon0)
    rot = np.array([[-math.sin(lo), math.cos(lo), 0],
                    [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                    [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])

    def enu(x, y, h):
        lon, lat, hh = to_geo.transform(*grid(x, y), h)
        return rot @ (np.array(to_ecef.transform(lon, lat, hh)) - o)

    out = {}
    for ins in doc.modelspace().query("INSERT"):
        attrs = {a.dxf.tag: a.dxf.text for a in ins.attribs}
        x, y, z = (v * unit for v in ins.dxf.insert)
        h = elev[attrs["LEVEL"]] + z
        p = enu(x, y, h)
        a = math.radians(ins.dxf.rotation)
        q = enu(x + math.cos(a), y + math.sin(a), h)
        out[attrs["TAG"]] = (p, math.degrees(math.atan2(q[1] - p[1], q[0] - p[0])))
    return out


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def sdf_poses(world: Path) -> dict[str, tuple[np.ndarray, float]]:
    root = etree.parse(str(world), SAFE_XML).getroot()
    out = {}
    # a placement is an <include> or, grouped with others of its variant, a <frame>
    for el in [*root.iter("include"), *root.findall("world/model/frame")]:
        name = el.findtext("name") if el.tag == "include" else el.get("name")
        v = [float(t) for t in el.findtext("pose").split()]
        out[name] = (np.array(v[:3]), math.degrees(v[5]))
    return out


def usd_poses(stage_path: Path) -> dict[str, tuple[np.ndarray, float]]:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(stage_path))
    out = {}
    for prim in stage.GetPrimAtPath("/Site/Placements").GetChildren():
        m = np.array(UsdGeom.Xformable(prim).GetLocalTransformation(), dtype=np.float64).T
        out[prim.GetCustomDataByKey("tag")] = (m[:3, 3], math.degrees(math.atan2(m[1, 0], m[0, 0])))
    return out


def gltf_poses(glb: Path) -> dict[str, tuple[np.ndarray, float]]:
    """Instance transforms of each asset's first visual node, back to Z-up ENU. The
    instance matrix is placement pose x the visual's model pose, so compare the root
    visual by removing its model-frame pose, read from the model's own glb."""
    from pipeline import glb as container
    from pipeline.geometry.transform import matrix_from_quaternion

    doc, binary = container.read(glb)
    out, visuals = {}, {}  # asset -> its model's visual node name -> model-frame pose
    for node in doc["nodes"]:
        inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
        if not inst or "tags" not in node.get("extras", {}):
            continue
        asset = node["name"].split("/")[0]
        visual = node["name"].split("/")[2]
        t = _acc(doc, binary, inst["attributes"]["TRANSLATION"])
        q = _acc(doc, binary, inst["attributes"]["ROTATION"])
        if asset not in visuals:
            model_doc, _ = container.read(glb.parent.parent / "models" / asset / f"{asset}.glb")
            visuals[asset] = {model_doc["nodes"][i]["name"]: m for i, m in container.visual_nodes(model_doc)}
        to_model = np.linalg.inv(visuals[asset][visual])
        for tag, ti, qi in zip(node["extras"]["tags"], t, q):
            if tag in out:  # the first visual node that places it has said where
                continue
            inst_m = matrix_from_quaternion(container.from_gltf_rotation(qi))
            inst_m[:3, 3] = ti
            pz = container.to_z_up(inst_m @ to_model)
            out[tag] = (pz[:3, 3], math.degrees(math.atan2(pz[1, 0], pz[0, 0])))
    return out


def _acc(doc, binary, index):
    from pipeline import glb

    return glb.accessor(doc, binary, index).astype(np.float64)
