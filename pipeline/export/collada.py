"""COLLADA 1.4.1 writer: each visual at every level an SDF model of the package draws
it on its own, the merged visuals of the coarse variants, each collision mesh, and the
whole model the Gazebo world's grouped placements draw.

Each holds one mesh in its own (visual or collision) frame, because the SDF
<visual><pose> places it. Metres, Z up.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np
from lxml import etree

import collada
from collada import asset as dae_asset
from collada import geometry as dae_geometry
from collada import material as dae_material
from collada import scene as dae_scene
from collada import source as dae_source

from pipeline import ir
from pipeline.digest import sha256_json
from pipeline.errors import UserError
from pipeline.export import names
from pipeline.export.textures import texture_file
from pipeline.export.variants import VariantVisual, variant_collisions, variant_visuals
from pipeline.geometry.merge import merge_meshes
from pipeline.geometry.metrics import stored_normals

# pycollada stamps <created>/<modified> with the current time; a fixed date keeps two
# builds of the same inputs byte-identical.
_FIXED_DATE = datetime.datetime(2000, 1, 1, 0, 0, 0)
_TOOL = "substation-twin"
# Elements whose text is a list of floats that pycollada formats itself.
_FLOAT_TAGS = ("color", "float", "matrix")
# The symbol a mesh's <triangles> name and its node binds to the material.
_MATERIAL_SYMBOL = "material0"
# The texture coordinate set a sampler reads, bound to TEXCOORD set 0.
_UV_SET = "UVSET0"


def write(asset: ir.Asset, folder: Path, memo=None) -> list[str]:
    """Write the visuals' levels the package's models draw (`_variants`), the
    merged visuals of each coarse LOD variant (export/variants.py) and every collision
    mesh of `asset` under folder/meshes/.

    A visual's level that every coarse variant merges with others of its material is
    not written: no SDF would name it.
    Returns the package-relative paths written, sorted. A level that repeats a finer
    one's mesh (a part kept at a coarser level, a frozen visual: a large share of a
    site's LOD files) gets the finer level's bytes, not a second formatting.
    `memo` (engine.memo.FileMemo, under the package code's version): documents an
    earlier build wrote, by what they hold; an edit that leaves a mesh as it was
    links its document instead of formatting it again.
    """
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    written = []
    variants = _variants(asset)
    drawn = {v.mesh_file for _, v in variants if not v.merged}
    for link, visual in asset.visuals():
        material = _material(asset, visual)
        made: dict[str, bytes] = {}  # document key -> the visual's document
        for level, mesh in enumerate(visual.lods):
            rel = names.mesh_file(link.name, visual.name, level)
            if rel in drawn:
                _write_document(folder / rel, visual.name, mesh, material, made, memo)
                written.append(rel)
    for level, visual in variants:
        if visual.merged and level > 0:
            _write_document(folder / visual.mesh_file, visual.name, visual.mesh(level),
                            _material(asset, visual.parts[0]), {}, memo)
            written.append(visual.mesh_file)
    for link in asset.links:
        for col in link.collisions:
            rel = names.collision_file(link.name, col.name)
            _write_document(folder / rel, col.name, col.mesh, None, {}, memo)
            written.append(rel)
        merged = [c for c in variant_collisions(link, 1) if len(c.parts) > 1] if asset.lod_count > 1 else []
        for col in merged:
            _write_document(folder / col.mesh_file, col.name, col.mesh(), None, {}, memo)
            written.append(col.mesh_file)
    written += _write_whole(asset, folder, memo)
    return sorted(written)


def _variants(asset: ir.Asset) -> list[tuple[int, VariantVisual]]:
    """(level, variant visual) of every link at every LOD, as the package's SDF models
    draw them (export/variants.py): a visual not merged at a level has its own file
    there; the merged ones at a coarse LOD have theirs."""
    return [(level, v) for level in range(max(1, asset.lod_count)) for link in asset.links
            for v in variant_visuals(asset, link, level)]


def _write_whole(asset: ir.Asset, folder: Path, memo) -> list[str]:
    """The whole model at rest, per coarse LOD (names.whole_mesh_file), and all its collision
    meshes in one (names.WHOLE_COLLISION_FILE), in the model frame. A grouped placement
    of the Gazebo world draws each as one element: sdformat spends about 160 kB of
    memory on every <visual> or <collision> whatever it holds (tools/gzprobe), so a site
    of thousands of placements fits only with one of each a placement."""
    written = []
    # not the finest level of an asset that has coarser ones: the few placements near
    # the inspection points keep each visual with its own SDF material (its PBR terms),
    # and the largest of the files is not written twice
    for level in range(1 if asset.lod_count > 1 else 0, asset.lod_count):
        by_material: dict[str, list] = {}
        for link in asset.links:
            for visual in variant_visuals(asset, link, level):
                by_material.setdefault(visual.material, []).append((link.pose @ visual.pose, visual.mesh(level)))
        groups = [(asset.material(name), merge_meshes(parts))
                  for name, parts in sorted(by_material.items())]
        if groups:
            rel = names.whole_mesh_file(level)
            _write_whole_document(folder / rel, groups, memo)
            written.append(rel)
    if any(j.type in names.MOVABLE_JOINTS for j in asset.joints):
        written += _write_whole_links(asset, folder, memo)
    parts = [(link.pose @ c.pose, c.mesh) for link in asset.links for c in link.collisions]
    if parts:
        _write_document(folder / names.WHOLE_COLLISION_FILE, "whole_collision", merge_meshes(parts), None, {}, memo)
        written.append(names.WHOLE_COLLISION_FILE)
    return written


def _write_whole_links(asset: ir.Asset, folder: Path, memo) -> list[str]:
    """Each link of an articulated asset at each coarse LOD, in the link frame
    (names.whole_link_mesh_file): a grouped placement of it in the Gazebo world draws
    its fixed links and each moving link with one visual apiece (scene.world_joints)."""
    written = []
    for level in range(1 if asset.lod_count > 1 else 0, asset.lod_count):
        for link in asset.links:
            by_material: dict[str, list] = {}
            for visual in variant_visuals(asset, link, level):
                by_material.setdefault(visual.material, []).append((visual.pose, visual.mesh(level)))
            if by_material:
                rel = names.whole_link_mesh_file(link.name, level)
                _write_whole_document(folder / rel, [(asset.material(name), merge_meshes(parts))
                                                     for name, parts in sorted(by_material.items())], memo)
                written.append(rel)
    return written


def _write_whole_document(path: Path, groups: list[tuple[ir.Material, ir.Mesh]], memo) -> None:
    key = sha256_json(["whole", [[m.key(), mesh.digest] for m, mesh in groups]])
    if memo is not None and memo.link(key, path):
        return
    doc = _new_document()
    arrays: dict[str, np.ndarray] = {}
    nodes = []
    for k, (material, mesh) in enumerate(groups):
        ident = f"part{k}_{names.safe_name(material.name)}"
        part_arrays, inputs, sources = _sources(ident, mesh)
        arrays.update(part_arrays)
        geom = dae_geometry.Geometry(doc, f"{ident}-mesh", ident, sources)
        geom.primitives.append(geom.createTriangleSet(_corner_indices(mesh.faces, len(sources)), inputs, _MATERIAL_SYMBOL))
        doc.geometries.append(geom)
        mat = _phong_material(doc, material)
        uv_binding = [(_UV_SET, "TEXCOORD", "0")] if material.base_color_texture is not None else []
        nodes.append(dae_scene.Node(ident, children=[dae_scene.GeometryNode(
            geom, [dae_scene.MaterialNode(_MATERIAL_SYMBOL, mat, inputs=uv_binding)])], name=ident))
    ids = [im.id for im in doc.images]  # materials sharing an image list it once (ids are unique)
    for i in reversed(range(len(ids))):
        if ids[i] in ids[:i]:
            del doc.images[i]
    scene = dae_scene.Scene("Scene", nodes)
    doc.scenes.append(scene)
    doc.scene = scene
    doc.save()
    root = doc.xmlnode.getroot()
    _reformat_floats(root, arrays)
    for el in root.iter("{*}transparent"):
        el.set("opaque", "A_ONE")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True))
    if memo is not None:
        memo.keep(key, path)


def _write_document(path: Path, node_name: str, mesh: ir.Mesh, material: ir.Material | None,
                    made: dict[str, bytes], memo) -> None:
    """path <- the document of one mesh, taken from `made` or `memo` when it was made
    before (keyed by everything _dae_bytes reads)."""
    key = sha256_json([node_name, None if material is None else material.key(), mesh.digest])
    path.parent.mkdir(parents=True, exist_ok=True)
    if memo is not None and memo.link(key, path):
        return
    if key not in made:
        made[key] = _dae_bytes(node_name, mesh, material)
    path.write_bytes(made[key])
    if memo is not None:
        memo.keep(key, path)


def _material(asset: ir.Asset, visual: ir.Visual) -> ir.Material:
    try:
        return asset.material(visual.material)
    except KeyError:
        raise UserError(asset.source or asset.id, visual.name,
                        f"material {visual.material!r} is not among the asset's materials") from None


def _dae_bytes(node_name: str, mesh: ir.Mesh, material: ir.Material | None) -> bytes:
    doc, arrays = _document(node_name, mesh, material)
    doc.save()
    root = doc.xmlnode.getroot()
    _reformat_floats(root, arrays)
    for el in root.iter("{*}transparent"):
        el.set("opaque", "A_ONE")  # pycollada writes the attribute only for RGB_ZERO
    return etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)


def _document(node_name: str, mesh: ir.Mesh, material: ir.Material | None):
    """A pycollada document with one geometry, one material and one node, plus the
    float arrays by id (pycollada rounds them to 7 digits on save; we write them)."""
    doc = _new_document()
    # COLLADA 1.4.1 types every name attribute xs:NCName: a CAD part called "10" would
    # fail the schema, so names take the same safe spelling as ids
    ident = names.safe_name(node_name)
    arrays, inputs, sources = _sources(ident, mesh)
    geom = dae_geometry.Geometry(doc, f"{ident}-mesh", ident, sources)
    triset = geom.createTriangleSet(_corner_indices(mesh.faces, len(sources)), inputs,
                                    None if material is None else _MATERIAL_SYMBOL)
    geom.primitives.append(triset)
    doc.geometries.append(geom)

    bindings = []
    if material is not None:
        mat = _phong_material(doc, material)
        uv_binding = [(_UV_SET, "TEXCOORD", "0")] if material.base_color_texture is not None else []
        bindings.append(dae_scene.MaterialNode(_MATERIAL_SYMBOL, mat, inputs=uv_binding))
    node = dae_scene.Node(ident, children=[dae_scene.GeometryNode(geom, bindings)], name=ident)
    scene = dae_scene.Scene("Scene", [node])
    doc.scenes.append(scene)
    doc.scene = scene
    return doc, arrays


def _new_document():
    doc = collada.Collada()
    doc.assetInfo = dae_asset.Asset(
        created=_FIXED_DATE,
        modified=_FIXED_DATE,
        unitname="meter",
        unitmeter=1,
        upaxis=dae_asset.UP_AXIS.Z_UP,
        contributors=[dae_asset.Contributor(authoring_tool=_TOOL)],
    )
    return doc


def _corner_indices(faces: np.ndarray, streams: int) -> np.ndarray:
    """faces: (n, 3) vertex indices -> (n * 3 * streams,) <p> values: every stream is
    per vertex, so each corner repeats its vertex index once per input offset."""
    faces = np.asarray(faces, dtype=np.int64)
    return np.repeat(faces.reshape(-1, 1), streams, axis=1).reshape(-1)


def _sources(ident: str, mesh: ir.Mesh):
    """Positions, normals (computed when absent) and texcoords, all per vertex, each
    input at an offset of its own.

    One shared offset is valid COLLADA, but Gazebo's loader (gz-common ColladaLoader,
    LoadTriangles) takes the <p> stride from the number of inputs, not from the largest
    offset, and so reads such a file as garbage; NORMAL inside <vertices> is read with
    the stride right, but then two corners at one position share the first one's
    normal. Distinct offsets are read exactly by both it and pycollada."""
    normals = stored_normals(mesh.vertices, mesh.faces, mesh.normals)
    streams = [("VERTEX", f"{ident}-positions", mesh.vertices, ("X", "Y", "Z")),
               ("NORMAL", f"{ident}-normals", normals, ("X", "Y", "Z"))]
    if mesh.uvs is not None:
        streams.append(("TEXCOORD", f"{ident}-texcoords", mesh.uvs, ("S", "T")))
    arrays, sources = {}, []
    inputs = dae_source.InputList()
    for offset, (semantic, sid, data, comps) in enumerate(streams):
        arr = np.array(data, dtype=np.float64).reshape(-1)
        # pycollada spells a source's floats when it is made and again on save; the
        # text is ours (_reformat_floats), so it is handed zeros, which spell fast
        sources.append(dae_source.FloatSource(sid, np.zeros_like(arr), comps))
        arrays[f"{sid}-array"] = arr
        inputs.addInput(offset, semantic, f"#{sid}", set="0" if semantic == "TEXCOORD" else None)
    return arrays, inputs, sources


def _phong_material(doc, material: ir.Material):
    # ir.Material.phong: the classic Phong terms. Opacity is <transparency> under
    # <transparent opaque="A_ONE"> (colour 0 0 0 1): gz-common's LoadTransparent takes
    # 1 - alpha x transparency as the transparency, and ignores both without the
    # `opaque` attribute; the diffuse alpha stays 1 (gz-rendering multiplies the two)
    p = material.phong()
    ident = names.safe_name(material.name)
    params, diffuse = [], p.diffuse
    base = material.base_color_texture
    if base is not None:
        # <diffuse><texture> through a sampler and a surface to the package's image,
        # relative to this file (meshes/ -> ../textures/); a diffuse is a colour or a
        # texture, so the base colour factor is left to the SDF <material>
        image = dae_material.CImage(f"{names.safe_name(base.name)}-image", f"../{texture_file(base)}")
        surface = dae_material.Surface(f"{ident}-surface", image)
        sampler = dae_material.Sampler2D(f"{ident}-sampler", surface)
        doc.images.append(image)
        params, diffuse = [surface, sampler], dae_material.Map(sampler, _UV_SET)
    effect = dae_material.Effect(
        f"{ident}-effect", params, "phong",
        emission=p.emissive, ambient=p.ambient, diffuse=diffuse, specular=p.specular,
        shininess=p.shininess, transparency=material.alpha,
    )
    mat = dae_material.Material(f"{ident}-material", ident, effect)
    doc.effects.append(effect)
    doc.materials.append(mat)
    return mat


def _reformat_floats(root, arrays: dict[str, np.ndarray]) -> None:
    """Write every float through names.fmt: full precision and one spelling."""
    for el in root.iter("{*}float_array"):
        el.text = names.fmt_join(arrays[el.get("id")].tolist())
    for tag in _FLOAT_TAGS:
        for el in root.iter("{*}" + tag):
            el.text = " ".join(names.fmt(float(t)) for t in (el.text or "").split())
    for el in root.iter("{*}unit"):
        el.set("meter", names.fmt(float(el.get("meter"))))
