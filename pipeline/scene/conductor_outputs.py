"""The conductors in every scene format, each span at its chosen LOD:

- USD: a BasisCurves prim per span under /Site/Conductors (linear, a curve per
  subconductor, constant width = the diameter), every LOD a variant of its `lod`
  variant set, points float32 relative to the span's first end (a double translate);
- glTF: a tube mesh per span, the node named by the span id, vertices relative to its
  first end;
- SDF: one static model `conductors` whose visuals are the tubes merged per conductor
  type and LOD (COLLADA beside the world, scene/conductors/), no collision unless
  [wiring] collision = "capsules": then a capsule per polyline segment;
- SDF sag variants: for each of [wiring] sag_variants_c, the same model with every
  span carried to that conductor temperature by the change-of-state equation (same
  segment counts), a model folder of its own (scene/conductor_variants/<name>/, meshes
  by model:// URI as the packages'): what a world includes instead of the as-built
  model when the runtime's conductor temperature is nearest that variant's.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import glb, ir
from ..export.names import fmt, safe_name
from ..geometry.transform import matrix_to_xyz_rpy
from ..geometry.wires import tube
from ..geometry import catenary as cat
from .conductors import Span, SpanLod, prim_names

TUBE_SIDES = 6  # a 30 mm wire: the hexagon's flats are 2 mm inside the circle
MATERIAL = ir.Material("conductor_aluminium", base_color=(0.62, 0.63, 0.64, 1.0), metallic=0.9, roughness=0.45)
FOLDER = "conductors"  # beside the world file
MODEL = "conductors"
VARIANTS = "conductor_variants"  # beside the world file: a model folder per sag variant


def span_mesh(span: Span, lod: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tubes of a span's subconductors, merged: vertices (n, 3) ENU float64, faces
    (m, 3) int32, normals (n, 3)."""
    verts, faces, normals, base = [], [], [], 0
    for path in span.paths(lod):
        v, f, n = tube(path, span.ctype.diameter_m / 2.0, TUBE_SIDES)
        verts.append(v)
        faces.append(f + base)
        normals.append(n)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(normals)


# --- USD ------------------------------------------------------------------------------


def add_usd(site_prim, spans: list[Span]) -> None:
    """/Site/Conductors with a BasisCurves prim per span (Sdf layer API)."""
    from pxr import Gf, Sdf, Vt

    if not spans:
        return
    scope = Sdf.PrimSpec(site_prim, "Conductors", Sdf.SpecifierDef, "Scope")
    names = prim_names(spans)
    T = Sdf.ValueTypeNames
    for s in spans:
        prim = Sdf.PrimSpec(scope, names[s.id], Sdf.SpecifierDef, "BasisCurves")
        Sdf.AttributeSpec(prim, "xformOp:translate", T.Double3).default = Gf.Vec3d(*s.curve.p0.tolist())
        Sdf.AttributeSpec(prim, "xformOpOrder", T.TokenArray, Sdf.VariabilityUniform).default = \
            Vt.TokenArray(["xformOp:translate"])
        Sdf.AttributeSpec(prim, "type", T.Token, Sdf.VariabilityUniform).default = "linear"
        widths = Sdf.AttributeSpec(prim, "widths", T.FloatArray)
        widths.default = Vt.FloatArray([s.ctype.diameter_m])
        widths.SetInfo("interpolation", "constant")
        color = Sdf.AttributeSpec(prim, "primvars:displayColor", T.Color3fArray)
        color.default = Vt.Vec3fArray([Gf.Vec3f(*MATERIAL.base_color[:3])])
        color.SetInfo("interpolation", "constant")
        prim.customData = {"span": s.id, "from": ".".join(s.spec.start), "to": ".".join(s.spec.end),
                           "type": s.ctype.name, "tension_n": round(s.tension_n, 3),
                           "temperature_c": float(s.temperature_c)}
        vset = Sdf.VariantSetSpec(prim, "lod")
        for k in range(len(s.lods)):
            variant = Sdf.VariantSpec(vset, f"lod{k}").primSpec
            paths = [p - s.curve.p0 for p in s.paths(k)]
            pts = np.concatenate(paths).astype(np.float32)
            Sdf.AttributeSpec(variant, "points", T.Point3fArray).default = Vt.Vec3fArray.FromNumpy(pts)
            Sdf.AttributeSpec(variant, "curveVertexCounts", T.IntArray).default = Vt.IntArray([len(p) for p in paths])
            half = s.ctype.diameter_m / 2.0
            lo, hi = pts.min(axis=0) - half, pts.max(axis=0) + half
            Sdf.AttributeSpec(variant, "extent", T.Float3Array).default = Vt.Vec3fArray(
                [Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())])
        prim.variantSetNameList.Prepend("lod")
        prim.variantSelections["lod"] = f"lod{s.lod}"


# --- glTF -----------------------------------------------------------------------------


def add_gltf(sb, spans: list[Span]) -> None:
    """A tube mesh and a node per span on a SceneBuilder (scene_gltf)."""
    if not spans:
        return
    sb.doc["materials"].append({"name": MATERIAL.name, "pbrMetallicRoughness": {
        "baseColorFactor": list(MATERIAL.base_color), "metallicFactor": MATERIAL.metallic,
        "roughnessFactor": MATERIAL.roughness}})
    material = len(sb.doc["materials"]) - 1
    for s in spans:
        v, f, n = span_mesh(s)
        local = glb.points_to_y_up(v - s.curve.p0).astype(np.float32)
        normals = glb.points_to_y_up(n).astype(np.float32)
        prim = {"attributes": {"POSITION": sb.buffer.add_accessor(local, "VEC3", 34962, bounds=True),
                               "NORMAL": sb.buffer.add_accessor(normals, "VEC3", 34962)},
                "indices": sb.buffer.add_accessor(f.reshape(-1).astype(np.uint32), "SCALAR", 34963),
                "material": material, "mode": 4}
        sb.doc["meshes"].append({"name": s.id, "primitives": [prim]})
        sb.add_node({"name": s.id, "mesh": len(sb.doc["meshes"]) - 1,
                     "translation": [float(c) for c in glb.points_to_y_up(s.curve.p0[None])[0]],
                     "extras": {"conductor": s.id, "type": s.ctype.name, "lod": s.lod,
                                "chord_error_m": round(s.lods[s.lod].chord_error_m, 9)}})


# --- SDF ------------------------------------------------------------------------------


def sdf_model(spans: list[Span], scene_folder: Path, capsules: bool = False):
    """The world's `conductors` model (an lxml element), its merged COLLADA meshes
    written to scene_folder/conductors/; None without spans."""
    from lxml import etree

    if not spans:
        return None
    model = etree.Element("model", name=MODEL)
    etree.SubElement(model, "static").text = "true"
    link = etree.SubElement(model, "link", name="spans")
    _merged_visuals(link, spans, Path(scene_folder) / FOLDER, FOLDER)
    if capsules:
        names = prim_names(spans)
        for s in spans:
            pts = s.lods[s.lod].points
            for i, (a, b) in enumerate(zip(pts[:-1], pts[1:])):
                _capsule(link, f"{names[s.id]}__{i}", a, b, s.radius)
    return model


def _merged_visuals(link, spans: list[Span], folder: Path, uri_prefix: str) -> None:
    """A visual per conductor type and LOD on `link`, its tubes merged into one COLLADA
    file in `folder` (referred to as uri_prefix/<name>.dae), posed at its centre."""
    from lxml import etree

    from ..export.collada import _dae_bytes

    groups: dict[str, list[Span]] = defaultdict(list)
    for s in spans:
        groups[f"{s.ctype.name}__lod{s.lod}"].append(s)
    folder.mkdir(parents=True, exist_ok=True)
    for group, members in sorted(groups.items()):
        meshes = [span_mesh(s) for s in members]
        verts = np.concatenate([m[0] for m in meshes])
        centre = np.round((verts.min(axis=0) + verts.max(axis=0)) / 2.0, 3)
        faces, base = [], 0
        for v, f, _ in meshes:
            faces.append(f + base)
            base += len(v)
        mesh = ir.Mesh(verts - centre, np.concatenate(faces), np.concatenate([m[2] for m in meshes]))
        name = safe_name(group)
        (folder / f"{name}.dae").write_bytes(_dae_bytes(name, mesh, MATERIAL))
        visual = etree.SubElement(link, "visual", name=name)
        etree.SubElement(visual, "pose").text = " ".join(fmt(c) for c in (*centre.tolist(), 0, 0, 0))
        geometry = etree.SubElement(etree.SubElement(visual, "geometry"), "mesh")
        etree.SubElement(geometry, "uri").text = f"{uri_prefix}/{name}.dae"
        etree.SubElement(visual, "cast_shadows").text = "true"


def variant_name(temperature_c: float) -> str:
    """The model (and folder) name of the sag variant at a temperature."""
    return safe_name(f"{MODEL}__{temperature_c:g}C".replace("-", "minus"))


def at_temperature(span: Span, temperature_c: float) -> Span:
    """The span carried to `temperature_c`: its tension by the change of state, each
    LOD's polyline with its segment count and its chord error measured again."""
    c, t = span.curve, span.ctype
    if temperature_c == span.temperature_c or c.straight:
        return span
    H = cat.change_of_state(c.p0, c.p1, t.w, t.ea, t.alpha_per_k, span.tension_n, span.temperature_c, temperature_c)
    curve = cat.from_tension(c.p0, c.p1, H, t.w)
    lods = tuple(SpanLod(lod.budget_m, cat.points(curve, lod.segments), cat.chord_error(curve, lod.segments))
                 for lod in span.lods)
    return replace(span, curve=curve, tension_n=H, temperature_c=temperature_c, lods=lods)


def sdf_variants(spans: list[Span], temperatures, scene_folder: Path) -> list[dict]:
    """Write scene/conductor_variants/<name>/ (model.sdf, model.config, meshes/) for
    each temperature; [{temperature_c, model, uri, largest_sag_m}]."""
    from lxml import etree

    from ..export.sdf import SDF_VERSION

    out = []
    for temp in sorted({float(t) for t in temperatures}):
        name = variant_name(temp)
        folder = Path(scene_folder) / VARIANTS / name
        moved = [at_temperature(s, temp) for s in spans]
        root = etree.Element("sdf", version=SDF_VERSION)
        model = etree.SubElement(root, "model", name=MODEL)  # the entity keeps its name when a world swaps it in
        etree.SubElement(model, "static").text = "true"
        link = etree.SubElement(model, "link", name="spans")
        _merged_visuals(link, moved, folder / "meshes", f"model://{name}/meshes")
        (folder / "model.sdf").write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8",
                                                          pretty_print=True))
        config = etree.Element("model")
        etree.SubElement(config, "name").text = name
        etree.SubElement(config, "version").text = "1.0"
        etree.SubElement(config, "sdf", version=SDF_VERSION).text = "model.sdf"
        etree.SubElement(config, "description").text = f"the site's conductors at {temp:g} deg C (substation-twin)"
        (folder / "model.config").write_bytes(etree.tostring(config, xml_declaration=True, encoding="UTF-8",
                                                             pretty_print=True))
        out.append({"temperature_c": temp, "model": name, "uri": f"model://{name}",
                    "largest_sag_m": round(max(cat.sag(s.curve) for s in moved), 6)})
    return out


def _capsule(link, name: str, a: np.ndarray, b: np.ndarray, radius: float) -> None:
    """A capsule collision from a to b (its axis, local Z, turned onto b - a)."""
    from lxml import etree

    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.999999 else np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    m[:3, 3] = (a + b) / 2.0
    xyz, rpy = matrix_to_xyz_rpy(m)
    col = etree.SubElement(link, "collision", name=name)
    etree.SubElement(col, "pose").text = " ".join(fmt(round(float(c), 9)) for c in (*xyz, *rpy))
    cap = etree.SubElement(etree.SubElement(col, "geometry"), "capsule")
    etree.SubElement(cap, "radius").text = fmt(round(radius, 6))
    etree.SubElement(cap, "length").text = fmt(round(length, 6))
