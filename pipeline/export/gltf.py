"""glTF 2.0 binary writer: one `<id>.glb` per package (DESIGN.md s.4), numpy + json +
struct only.

The IR is Z up, glTF is Y up (+Z forward): the change of basis C = pipeline.glb.Z_TO_Y,
(x, y, z) -> (x, z, -y), is applied as the model is written. Vertex data is multiplied
by C and every local transform T becomes C T C^-1, so the composed world transform is
C times the IR's and the root node carries no correction of its own. The GLB bytes
themselves are laid out by pipeline.glb.

Node layout (the runtime targets it by name):

    <id>                    root node, the only node of the scene
      <link>                link nodes following the joint tree; local transform =
        <child link>        pose relative to the parent link; a child link's extras
        <visual>            hold its joint {name, type, parent, axis, axis_ir, ...}
                            visual nodes under their link: one mesh each, TRS transform
    <visual>__lod<i>        lower LODs: nodes outside the scene, listed in the visual
                            node's MSFT_lod ids

Materials are metallic-roughness; states of `material` bindings become
KHR_materials_variants named `<variable>:<material>`; shape keys become morph targets
(POSITION deltas, weights 0, names in mesh.extras.targetNames).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline import glb, ir
from pipeline.errors import UserError
from pipeline.export import names
from pipeline.geometry.metrics import stored_normals
from pipeline.geometry.transform import decompose, quaternion_from_matrix


def write(asset: ir.Asset, folder: Path) -> list[str]:
    """Write `<id>.glb` into `folder` (atomically); return the package-relative paths
    written."""
    rel = names.gltf_file(asset.id)
    glb.write(Path(folder) / rel, *_document(asset))
    return [rel]


class _Doc:
    """The glTF JSON being built and its single binary buffer."""

    def __init__(self):
        self.json: dict = {"asset": {"version": "2.0", "generator": "substation-twin"}}
        self.nodes: list[dict] = []
        self.meshes: list[dict] = []
        self.buffer = glb.Buffer()
        self.extensions: set[str] = set()
        self.images: list[dict] = []
        self.textures: list[dict] = []
        self.texture_index: dict[str, int] = {}  # texture name -> index in textures

    def add_texture(self, texture: ir.Texture) -> int:
        """The texture's index; its image embedded once in the buffer however many
        materials sample it."""
        if texture.name not in self.texture_index:
            view = self.buffer.add_view(texture.data)
            self.images.append({"bufferView": view, "mimeType": texture.mime, "name": texture.name})
            # one sampler for all: trilinear, repeat (glTF's defaults spelled out)
            self.textures.append({"sampler": 0, "source": len(self.images) - 1})
            self.texture_index[texture.name] = len(self.textures) - 1
        return self.texture_index[texture.name]

    def add_node(self, node: dict) -> int:
        self.nodes.append(node)
        return len(self.nodes) - 1

    def add_accessor(self, array: np.ndarray, kind: str, target: int | None, bounds: bool = False) -> int:
        """One tightly packed bufferView + accessor per array."""
        return self.buffer.add_accessor(array, kind, target, bounds)


def _document(asset: ir.Asset) -> tuple[dict, bytes]:
    """The model's glTF document and its binary buffer."""
    doc = _Doc()
    where = asset.source or asset.id
    material_index = {m.name: i for i, m in enumerate(asset.materials)}
    doc.json["materials"] = [_material(doc, m) for m in asset.materials]
    variants = _variants(asset)
    root = doc.add_node({"name": asset.id, "extras": {"asset_id": asset.id, "category": asset.category}})
    _add_links(doc, asset, root, material_index, variants, where)
    doc.json["scene"] = 0
    doc.json["scenes"] = [{"name": asset.id, "nodes": [root]}]
    doc.json["nodes"] = doc.nodes
    if variants:
        doc.json["extensions"] = {"KHR_materials_variants": {"variants": [{"name": n} for n in variants]}}
        doc.extensions.add("KHR_materials_variants")
    for key, items in (("meshes", doc.meshes), ("accessors", doc.buffer.accessors), ("bufferViews", doc.buffer.views),
                       ("images", doc.images), ("textures", doc.textures)):
        if items:
            doc.json[key] = items
    if doc.textures:
        doc.json["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]
    if not doc.json["materials"]:
        del doc.json["materials"]
    blob = bytes(doc.buffer.binary)
    if blob:
        doc.json["buffers"] = [{"byteLength": glb.padded_length(blob)}]
    if doc.extensions:
        doc.json["extensionsUsed"] = sorted(doc.extensions)
    return doc.json, blob


# ---------------------------------------------------------------- transforms

def _set_transform(node: dict, m: np.ndarray) -> None:
    """TRS (animatable by the runtime) of a Z-up local transform, identity parts omitted.
    A matrix with shear cannot be split into TRS: it is written as `matrix`."""
    m = glb.to_y_up(m)
    t, r, s = decompose(m)
    rebuilt = np.eye(4)
    rebuilt[:3, :3] = r @ np.diag(s)
    rebuilt[:3, 3] = t
    if not np.allclose(rebuilt, m, rtol=0.0, atol=1e-12):
        node["matrix"] = [float(c) for c in m.T.reshape(-1)]  # column-major
        return
    if np.any(t != 0.0):
        node["translation"] = [float(c) for c in t]
    q = quaternion_from_matrix(r)
    if np.any(q[1:] != 0.0):
        node["rotation"] = [float(c) for c in glb.to_gltf_rotation(q)]
    if np.any(np.abs(s - 1.0) > 1e-12):  # not the rounding noise of column norms
        node["scale"] = [float(c) for c in s]


# ---------------------------------------------------------------- hierarchy

def _add_links(doc: _Doc, asset: ir.Asset, root: int, material_index, variants, where) -> None:
    links = {link.name: link for link in asset.links}
    children: dict[str, list[ir.Joint]] = {}
    for joint in asset.joints:
        for end in (joint.parent, joint.child):
            if end not in links:
                raise UserError(where, joint.name, f"joint names link {end!r} that does not exist")
        children.setdefault(joint.parent, []).append(joint)
    child_names = {j.child for j in asset.joints}
    visited: set[str] = set()

    def add(link: ir.Link, parent_pose: np.ndarray, joint: ir.Joint | None) -> int:
        if link.name in visited:
            raise UserError(where, link.name, "link is reached twice through the joints (a loop)")
        visited.add(link.name)
        node = {"name": link.name}
        _set_transform(node, np.linalg.inv(parent_pose) @ link.pose)
        if joint is not None:
            node["extras"] = {"joint": _joint_extras(joint, link)}
        index = doc.add_node(node)
        kids = [_add_visual(doc, asset, link, v, material_index, variants) for v in link.visuals]
        kids += [add(links[j.child], link.pose, j) for j in children.get(link.name, [])]
        if kids:
            node["children"] = kids
        return index

    tops = [add(link, np.eye(4), None) for link in asset.links if link.name not in child_names]
    if len(visited) != len(asset.links):
        raise UserError(where, None, "the joints form a loop: some links have no root")
    doc.nodes[root]["children"] = tops


def _joint_extras(joint: ir.Joint, child: ir.Link) -> dict:
    """The joint as the runtime needs it in glTF terms: axis and pivot in the child link
    node's (Y-up) frame, plus the IR axis in the joint frame for exactness."""
    to_child = np.linalg.inv(child.pose) @ joint.pose
    axis = glb.points_to_y_up(to_child[:3, :3] @ joint.axis)
    return {
        "name": joint.name,
        "type": joint.type,
        "parent": joint.parent,
        "axis": [float(c) for c in axis],
        "axis_ir": [float(c) for c in joint.axis],
        "pivot": [float(c) for c in glb.points_to_y_up(to_child[:3, 3])],
        "lower": None if joint.lower is None else float(joint.lower),
        "upper": None if joint.upper is None else float(joint.upper),
        "effort": None if joint.effort is None else float(joint.effort),
        "velocity": None if joint.velocity is None else float(joint.velocity),
    }


def _add_visual(doc: _Doc, asset: ir.Asset, link: ir.Link, visual: ir.Visual, material_index, variants) -> int:
    """The visual node with its LOD-0 mesh; lower LODs as out-of-scene MSFT_lod nodes
    with the same local transform (they stand in for this node)."""
    if visual.material not in material_index:
        raise UserError(asset.source or asset.id, visual.name, f"uses undefined material {visual.material!r}")
    mappings = _mappings(asset, visual, material_index, variants)
    node = {"name": visual.name}
    _set_transform(node, visual.pose)
    mesh = _add_mesh(doc, f"{link.name}/{visual.name}", visual.mesh, material_index[visual.material], mappings)
    if mesh is not None:
        node["mesh"] = mesh
    index = doc.add_node(node)
    lod_nodes = []
    for level, m in enumerate(visual.lods[1:], start=1):
        lod_mesh = _add_mesh(doc, f"{link.name}/{visual.name}/lod{level}", m,
                             material_index[visual.material], mappings)
        if lod_mesh is None:
            continue
        lod_node = {"name": f"{visual.name}__lod{level}", "mesh": lod_mesh}
        _set_transform(lod_node, visual.pose)
        lod_nodes.append(doc.add_node(lod_node))
    if lod_nodes and mesh is not None:
        node["extensions"] = {"MSFT_lod": {"ids": lod_nodes}}
        # Minimum screen coverage of each level, halving per level; the coarsest is
        # never culled (0).
        node["extras"] = {"MSFT_screencoverage": [0.5 ** (i + 1) for i in range(len(lod_nodes))] + [0.0]}
        doc.extensions.add("MSFT_lod")
    return index


# ---------------------------------------------------------------- meshes

def _add_mesh(doc: _Doc, name: str, m: ir.Mesh, material: int, mappings: list[dict]) -> int | None:
    """One mesh with one triangle primitive; None for an empty mesh (glTF accessors
    cannot be empty)."""
    if len(m.faces) == 0 or len(m.vertices) == 0:
        return None
    positions = glb.points_to_y_up(m.vertices).astype(np.float32)
    normals = stored_normals(m.vertices, m.faces, m.normals)
    normals = glb.points_to_y_up(normals)
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    attributes = {
        "POSITION": doc.add_accessor(positions, "VEC3", glb.ARRAY_BUFFER, bounds=True),
        "NORMAL": doc.add_accessor(normals, "VEC3", glb.ARRAY_BUFFER),
    }
    if m.uvs is not None:
        # glTF's texture origin is the top-left corner: v flips.
        uv = np.asarray(m.uvs, dtype=np.float64) * (1.0, -1.0) + (0.0, 1.0)
        attributes["TEXCOORD_0"] = doc.add_accessor(uv.astype(np.float32), "VEC2", glb.ARRAY_BUFFER)
    # 0xFFFF is reserved (primitive restart), so 16-bit indices stop below it.
    index_type = np.uint16 if len(m.vertices) < 0xFFFF else np.uint32
    indices = np.asarray(m.faces, dtype=np.int64).reshape(-1).astype(index_type)
    primitive = {"attributes": attributes, "indices": doc.add_accessor(indices, "SCALAR", glb.ELEMENT_ARRAY_BUFFER),
                 "material": material, "mode": 4}
    mesh: dict = {"name": name, "primitives": [primitive]}
    if m.shape_keys:
        primitive["targets"] = [
            {"POSITION": doc.add_accessor(glb.points_to_y_up(k.vertices - m.vertices).astype(np.float32), "VEC3",
                                          glb.ARRAY_BUFFER, bounds=True)}
            for k in m.shape_keys
        ]
        mesh["weights"] = [0.0] * len(m.shape_keys)
        mesh["extras"] = {"targetNames": [k.name for k in m.shape_keys]}
    if mappings:
        primitive["extensions"] = {"KHR_materials_variants": {"mappings": mappings}}
    doc.meshes.append(mesh)
    return len(doc.meshes) - 1


# ---------------------------------------------------------------- materials

def _material(doc: _Doc, m: ir.Material) -> dict:
    r, g, b, a = (float(np.clip(c, 0.0, 1.0)) for c in m.base_color)
    out: dict = {
        "name": m.name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [r, g, b, a],
            "metallicFactor": float(np.clip(m.metallic, 0.0, 1.0)),
            "roughnessFactor": float(np.clip(m.roughness, 0.0, 1.0)),
        },
    }
    emission = [max(0.0, float(c)) for c in m.emission]
    peak = max(emission)
    if peak > 0.0:
        # emissiveFactor is limited to 1; the strength extension carries the rest.
        if peak > 1.0:
            emission = [c / peak for c in emission]
            out["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": peak}}
            doc.extensions.add("KHR_materials_emissive_strength")
        out["emissiveFactor"] = emission
    if a < 1.0:
        out["alphaMode"] = "BLEND"
    _texture_slots(doc, m, out)
    return out


# IR slot -> where glTF puts it: (parent key or None for the material itself, key)
_SLOTS = {"base_color": ("pbrMetallicRoughness", "baseColorTexture"),
          "metallic_roughness": ("pbrMetallicRoughness", "metallicRoughnessTexture"),
          "normal": (None, "normalTexture"), "occlusion": (None, "occlusionTexture"),
          "emissive": (None, "emissiveTexture")}


def _texture_slots(doc: _Doc, m: ir.Material, out: dict) -> None:
    for slot, texture in m.textures().items():
        parent, key = _SLOTS[slot]
        (out[parent] if parent else out)[key] = {"index": doc.add_texture(texture), "texCoord": 0}
    if "emissive" in m.textures() and "emissiveFactor" not in out:
        out["emissiveFactor"] = [1.0, 1.0, 1.0]  # the map alone: glTF's default factor is black


def _variants(asset: ir.Asset) -> list[str]:
    """KHR_materials_variants names `<variable>:<material>`, one per distinct state look,
    in binding order (sorted by variable, then target)."""
    out: list[str] = []
    for b in _material_bindings(asset):
        for name in b.materials:
            key = f"{b.variable}:{name}"
            if key not in out:
                out.append(key)
    return out


def _material_bindings(asset: ir.Asset) -> list[ir.StateBinding]:
    return sorted((b for b in asset.bindings if b.effect == "material"), key=lambda b: (b.variable, b.target))


def _mappings(asset: ir.Asset, visual: ir.Visual, material_index, variants: list[str]) -> list[dict]:
    """Primitive mappings of one visual: for each material, the variants selecting it."""
    by_material: dict[int, set[int]] = {}
    for b in _material_bindings(asset):
        if b.target != visual.name:
            continue
        for name in b.materials:
            if name not in material_index:
                raise UserError(asset.source or asset.id, visual.name,
                                f"state {b.variable!r} lists unknown material {name!r}")
            by_material.setdefault(material_index[name], set()).add(variants.index(f"{b.variable}:{name}"))
    return [{"material": mat, "variants": sorted(v)} for mat, v in sorted(by_material.items())]
