"""The Gazebo world: SDF 1.9 with spherical coordinates, a sun, the terrain and one
<include> per placement (never one mesh)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree

from ..export.names import fmt, lod_model_name
from .placements import Placed


def _text(parent, tag: str, text) -> etree._Element:
    el = etree.SubElement(parent, tag)
    el.text = str(text)
    return el


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector the sunlight travels along, in ENU (azimuth clockwise from north)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    to_sun = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    return -to_sun


def write(path: Path, *, site_name: str, origin_llh, placed: list[Placed], terrain_model: str,
          sun: dict) -> None:
    sdf = etree.Element("sdf", version="1.9")
    world = etree.SubElement(sdf, "world", name=site_name)
    sph = etree.SubElement(world, "spherical_coordinates")
    _text(sph, "surface_model", "EARTH_WGS84")
    _text(sph, "world_frame_orientation", "ENU")
    _text(sph, "latitude_deg", fmt(origin_llh[0]))
    _text(sph, "longitude_deg", fmt(origin_llh[1]))
    _text(sph, "elevation", fmt(origin_llh[2]))
    _text(sph, "heading_deg", "0")

    light = etree.SubElement(world, "light", type="directional", name="sun")
    _text(light, "cast_shadows", "true")
    _text(light, "pose", "0 0 100 0 0 0")
    _text(light, "diffuse", "1 0.96 0.9 1")
    _text(light, "specular", "0.3 0.3 0.3 1")
    _text(light, "intensity", fmt(round(sun["intensity"], 6)))
    d = sun_direction(sun["elevation_deg"], sun["azimuth_deg"])
    _text(light, "direction", " ".join(fmt(round(v, 12)) for v in d))

    inc = etree.SubElement(world, "include")
    _text(inc, "uri", f"model://{terrain_model}")
    _text(inc, "name", "terrain")
    _text(inc, "pose", "0 0 0 0 0 0")
    _text(inc, "static", "true")

    for pl in sorted(placed, key=lambda p: p.placement.tag):
        inc = etree.SubElement(world, "include")
        _text(inc, "uri", f"model://{lod_model_name(pl.placement.asset_id, pl.lod)}")
        _text(inc, "name", pl.placement.tag)
        x, y, z = pl.pose[:3, 3]
        _text(inc, "pose", " ".join(fmt(v) for v in (x, y, z, 0.0, 0.0, pl.yaw)))
        _text(inc, "static", "true")
    data = etree.tostring(sdf, pretty_print=True, xml_declaration=True, encoding="UTF-8")
    Path(path).write_bytes(data)
