"""OpenUSD writer: one component asset `<id>.usdc` per package (DESIGN.md s.4).

Layout (the runtime addresses it through `names.usd_link_path` / `usd_visual_path`):

    /<id>                        Xform, Kind component, defaultPrim, assetInfo
        variantSet lod           lod0..lodN: mesh data of every visual at that level
        variantSet state_<var>   s0..sK: material binding of one visual per state
        PhysicsArticulationRootAPI (only when the asset has joints)
    /<id>/Looks/<material>       UsdPreviewSurface materials
    /<id>/<link>                 Xform = link pose in the model frame (flat, no nesting)
                                 RigidBodyAPI + MassAPI when the asset has joints
    /<id>/<link>/<visual>        Xform (SkelRoot when it has shape keys) = visual pose
    /<id>/<link>/<visual>/mesh   Mesh; BlendShapes as its children
    /<id>/<link>/<visual>/skel   Skeleton (no joints) + skel/anim SkelAnimation whose
                                 blendShapeWeights the runtime time-samples
    /<id>/<link>/collisions/<c>  Mesh, purpose guide, CollisionAPI, convex hull
    /<id>/Joints/<joint>         UsdPhysics joints between link prims

Poses are authored as double matrices (xformOp:transform), so they read back exactly.
UsdPhysics stores joint frames as float3 / quatf and limits as float in degrees; the
exact IR values also go into each joint's customData.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from pipeline import ir
from pipeline.errors import UserError
from pipeline.files import atomic_path
from pipeline.export import names
from pipeline.export.textures import texture_file
from pipeline.geometry.metrics import stored_normals
from pipeline.geometry.transform import compose, quaternion_from_matrix

_LOOKS = "Looks"
_JOINTS = "Joints"
_COLLISIONS = "collisions"
_MESH = "mesh"
_SKELETON = "skel"


def write(asset: ir.Asset, folder: Path) -> list[str]:
    """Write `<id>.usdc` into `folder`; return the package-relative paths written.
    A failed write leaves no half-written stage (files.atomic_path)."""
    pxr = _import_pxr()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _check_names(asset)
    stage = pxr.Usd.Stage.CreateInMemory()
    _author(pxr, stage, asset)
    rel = names.usd_file(asset.id)
    with atomic_path(folder / rel) as tmp:  # its temporary name keeps .usdc: the crate writer's format
        if not stage.GetRootLayer().Export(str(tmp)):
            raise UserError(str(folder / rel), asset.id, "USD export failed")
    return [rel]


def _import_pxr() -> SimpleNamespace:
    """The pxr modules this writer uses, imported when it runs (DESIGN.md s.9)."""
    try:
        from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade, UsdSkel, Vt
    except ImportError as exc:
        raise RuntimeError("the USD writer needs usd-core: pip install usd-core") from exc
    return SimpleNamespace(Gf=Gf, Kind=Kind, Sdf=Sdf, Usd=Usd, UsdGeom=UsdGeom, UsdPhysics=UsdPhysics,
                           UsdShade=UsdShade, UsdSkel=UsdSkel, Vt=Vt)


def _check_names(asset: ir.Asset) -> None:
    """Prim names come from IR names through `safe_name`; two IR names that map to the
    same prim, or a name that takes a reserved slot, would silently merge prims."""
    where = asset.source or asset.id
    _unique(where, [link.name for link in asset.links], "link", reserved=(_LOOKS, _JOINTS))
    for link in asset.links:
        _unique(where, [v.name for v in link.visuals], f"visual of link {link.name!r}", reserved=(_COLLISIONS,))
        _unique(where, [c.name for c in link.collisions], f"collision of link {link.name!r}")
        for v in link.visuals:
            _unique(where, [k.name for k in v.mesh.shape_keys], f"shape key of visual {v.name!r}")
    _unique(where, [m.name for m in asset.materials], "material")
    _unique(where, [j.name for j in asset.joints], "joint")
    defined = {m.name for m in asset.materials}
    for link, v in asset.visuals():
        if v.material not in defined:
            raise UserError(where, v.name, f"visual of link {link.name!r} uses undefined material {v.material!r}")


def _unique(where: str, ir_names: list[str], what: str, reserved: tuple[str, ...] = ()) -> None:
    seen = {r: "a reserved prim" for r in reserved}
    for name in ir_names:
        key = names.safe_name(name)
        if key in seen:
            raise UserError(where, name, f"{what}: prim name {key!r} is already taken by {seen[key]}")
        seen[key] = repr(name)


def _author(p, stage, asset: ir.Asset) -> None:
    p.UsdGeom.SetStageUpAxis(stage, p.UsdGeom.Tokens.z)
    p.UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root_path = p.Sdf.Path("/" + names.safe_name(asset.id))
    root = p.UsdGeom.Xform.Define(stage, root_path).GetPrim()
    stage.SetDefaultPrim(root)
    model = p.Usd.ModelAPI(root)
    model.SetKind(p.Kind.Tokens.component)
    model.SetAssetName(asset.id)
    model.SetAssetIdentifier(p.Sdf.AssetPath("./" + names.usd_file(asset.id)))
    if asset.description:
        root.SetDocumentation(asset.description)

    looks = _author_materials(p, stage, root_path, asset)
    for link in asset.links:
        _author_link(p, stage, root_path, link, articulated=bool(asset.joints))
    _author_lod_variants(p, stage, root, asset)
    _author_plain_bindings(p, stage, root, asset, looks)
    _author_state_variants(p, stage, root, asset, looks)
    if asset.joints:
        p.UsdPhysics.ArticulationRootAPI.Apply(root)
        _author_joints(p, stage, root_path, asset)


def _set_matrix(p, xformable, m: np.ndarray) -> None:
    """One double-precision xformOp:transform; USD matrices act on row vectors, so the
    IR's column-vector matrix is transposed."""
    op = xformable.AddTransformOp(p.UsdGeom.XformOp.PrecisionDouble)
    op.Set(p.Gf.Matrix4d(np.asarray(m, dtype=np.float64).T.tolist()))


# ---------------------------------------------------------------- materials

def _author_materials(p, stage, root_path, asset: ir.Asset) -> dict[str, object]:
    """UsdPreviewSurface per IR material; returns name -> UsdShade.Material."""
    scope = root_path.AppendChild(_LOOKS)
    p.UsdGeom.Scope.Define(stage, scope)
    out = {}
    for m in sorted(asset.materials, key=lambda m: m.name):
        path = scope.AppendChild(names.safe_name(m.name))
        mat = p.UsdShade.Material.Define(stage, path)
        shader = p.UsdShade.Shader.Define(stage, path.AppendChild("PreviewSurface"))
        shader.CreateIdAttr("UsdPreviewSurface")
        r, g, b, a = (float(c) for c in m.base_color)
        vec3 = p.Sdf.ValueTypeNames.Color3f
        flt = p.Sdf.ValueTypeNames.Float
        shader.CreateInput("diffuseColor", vec3).Set(p.Gf.Vec3f(r, g, b))
        shader.CreateInput("metallic", flt).Set(float(m.metallic))
        shader.CreateInput("roughness", flt).Set(float(m.roughness))
        shader.CreateInput("emissiveColor", vec3).Set(p.Gf.Vec3f(*(float(c) for c in m.emission)))
        shader.CreateInput("opacity", flt).Set(a)
        _author_textures(p, stage, path, shader, m)
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        mat.GetPrim().SetCustomDataByKey("ir:name", m.name)
        out[m.name] = mat
    return out


# IR slot -> (UsdPreviewSurface input, the texture output it reads, colour space)
_TEXTURE_INPUTS = {"base_color": ("diffuseColor", "rgb", "sRGB"), "emissive": ("emissiveColor", "rgb", "sRGB"),
                   "normal": ("normal", "rgb", "raw"), "occlusion": ("occlusion", "r", "raw")}


def _author_textures(p, stage, path, surface, m: ir.Material) -> None:
    """A UsdUVTexture per image map of `m`, reading the mesh's `st` primvar and the
    package's image (./textures/..., beside this layer). The factors multiply the image
    through the texture's `scale`, as glTF's factors do; glTF's packed
    metallic-roughness image feeds roughness from G and metallic from B."""
    textures = m.textures()
    if not textures:
        return
    reader = p.UsdShade.Shader.Define(stage, path.AppendChild("stReader"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", p.Sdf.ValueTypeNames.String).Set("st")
    st = reader.CreateOutput("result", p.Sdf.ValueTypeNames.Float2)
    flt3, flt = p.Sdf.ValueTypeNames.Float3, p.Sdf.ValueTypeNames.Float
    r, g, b, a = (float(c) for c in m.base_color)
    factors = {"base_color": (r, g, b, a), "emissive": (*(float(c) for c in m.emission), 1.0),
               "normal": (2.0, 2.0, 2.0, 1.0), "occlusion": (1.0, 1.0, 1.0, 1.0),
               "metallic_roughness": (1.0, float(m.roughness), float(m.metallic), 1.0)}
    for slot, texture in textures.items():
        node = p.UsdShade.Shader.Define(stage, path.AppendChild(f"{slot}_texture"))
        node.CreateIdAttr("UsdUVTexture")
        node.CreateInput("file", p.Sdf.ValueTypeNames.Asset).Set(f"./{texture_file(texture)}")
        node.CreateInput("st", p.Sdf.ValueTypeNames.Float2).ConnectToSource(st)
        for wrap in ("wrapS", "wrapT"):
            node.CreateInput(wrap, p.Sdf.ValueTypeNames.Token).Set("repeat")
        node.CreateInput("scale", p.Sdf.ValueTypeNames.Float4).Set(p.Gf.Vec4f(*factors[slot]))
        if slot == "normal":
            node.CreateInput("bias", p.Sdf.ValueTypeNames.Float4).Set(p.Gf.Vec4f(-1.0, -1.0, -1.0, 0.0))
        if slot == "metallic_roughness":
            node.CreateInput("sourceColorSpace", p.Sdf.ValueTypeNames.Token).Set("raw")
            surface.CreateInput("roughness", flt).ConnectToSource(node.CreateOutput("g", flt))
            surface.CreateInput("metallic", flt).ConnectToSource(node.CreateOutput("b", flt))
            continue
        target, output, space = _TEXTURE_INPUTS[slot]
        node.CreateInput("sourceColorSpace", p.Sdf.ValueTypeNames.Token).Set(space)
        kind = flt3 if output == "rgb" else flt
        value_type = p.Sdf.ValueTypeNames.Color3f if target in ("diffuseColor", "emissiveColor") else (
            p.Sdf.ValueTypeNames.Normal3f if target == "normal" else flt)
        surface.CreateInput(target, value_type).ConnectToSource(node.CreateOutput(output, kind))


def _bind(p, mesh_prim, material) -> None:
    api = p.UsdShade.MaterialBindingAPI.Apply(mesh_prim)
    api.Bind(material)


# ---------------------------------------------------------------- links, visuals

def _author_link(p, stage, root_path, link: ir.Link, articulated: bool) -> None:
    path = root_path.AppendChild(names.safe_name(link.name))
    xf = p.UsdGeom.Xform.Define(stage, path)
    _set_matrix(p, xf, link.pose)
    prim = xf.GetPrim()
    if articulated:
        p.UsdPhysics.RigidBodyAPI.Apply(prim)
        p.UsdPhysics.MassAPI.Apply(prim).CreateMassAttr(float(link.mass))
    for visual in link.visuals:
        _author_visual(p, stage, path, visual)
    if link.collisions:
        cpath = path.AppendChild(_COLLISIONS)
        p.UsdGeom.Scope.Define(stage, cpath)
        for col in link.collisions:
            _author_collision(p, stage, cpath.AppendChild(names.safe_name(col.name)), col)


def _author_visual(p, stage, link_path, visual: ir.Visual) -> None:
    """The visual's Xform and the mesh prim's LOD-independent attributes; the point data
    lives in the `lod` variants (a local opinion would win over every variant)."""
    path = link_path.AppendChild(names.safe_name(visual.name))
    keys = visual.mesh.shape_keys
    xf = p.UsdSkel.Root.Define(stage, path) if keys else p.UsdGeom.Xform.Define(stage, path)
    _set_matrix(p, xf, visual.pose)
    mesh = p.UsdGeom.Mesh.Define(stage, path.AppendChild(_MESH))
    mesh.CreateSubdivisionSchemeAttr(p.UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(p.UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(False)
    mesh.GetPrim().SetCustomDataByKey("ir:name", visual.name)
    if keys:
        _author_shape_keys(p, stage, path, mesh, visual.mesh)


def _author_mesh_data(p, mesh, m: ir.Mesh) -> None:
    """Points, topology, normals, UVs and extent of one IR mesh onto a UsdGeom.Mesh."""
    pts = np.asarray(m.vertices, dtype=np.float32)
    mesh.CreatePointsAttr(p.Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(p.Vt.IntArray.FromNumpy(np.full(len(m.faces), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(p.Vt.IntArray.FromNumpy(np.ascontiguousarray(m.faces.reshape(-1), dtype=np.int32)))
    normals = stored_normals(m.vertices, m.faces, m.normals)
    mesh.CreateNormalsAttr(p.Vt.Vec3fArray.FromNumpy(np.asarray(normals, dtype=np.float32)))
    mesh.SetNormalsInterpolation(p.UsdGeom.Tokens.vertex)
    if m.uvs is not None:
        st = p.UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "st", p.Sdf.ValueTypeNames.TexCoord2fArray, p.UsdGeom.Tokens.vertex)
        st.Set(p.Vt.Vec2fArray.FromNumpy(np.asarray(m.uvs, dtype=np.float32)))
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3), np.zeros(3))
    mesh.CreateExtentAttr(p.Vt.Vec3fArray([p.Gf.Vec3f(*map(float, lo)), p.Gf.Vec3f(*map(float, hi))]))


def _author_shape_keys(p, stage, visual_path, mesh, m: ir.Mesh) -> None:
    """Shape keys as UsdSkel blend shapes: a joint-less Skeleton whose animation carries
    the weights (0 by default), so the runtime time-samples `blendShapeWeights`."""
    key_names = [names.safe_name(k.name) for k in m.shape_keys]
    targets = []
    for key, key_name in zip(m.shape_keys, key_names):
        bs = p.UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(key_name))
        offsets = np.asarray(key.vertices - m.vertices, dtype=np.float32)
        bs.CreateOffsetsAttr(p.Vt.Vec3fArray.FromNumpy(offsets))
        bs.GetPrim().SetCustomDataByKey("ir:name", key.name)
        targets.append(bs.GetPath())
    skel_path = visual_path.AppendChild(_SKELETON)
    skel = p.UsdSkel.Skeleton.Define(stage, skel_path)
    skel.CreateJointsAttr([])
    anim = p.UsdSkel.Animation.Define(stage, skel_path.AppendChild("anim"))
    anim.CreateBlendShapesAttr(key_names)
    anim.CreateBlendShapeWeightsAttr(p.Vt.FloatArray([0.0] * len(key_names)))
    p.UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    binding = p.UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel_path])
    binding.CreateBlendShapesAttr(key_names)
    binding.CreateBlendShapeTargetsRel().SetTargets(targets)


def _author_collision(p, stage, path, col: ir.Collision) -> None:
    mesh = p.UsdGeom.Mesh.Define(stage, path)
    _set_matrix(p, mesh, col.pose)
    mesh.CreatePurposeAttr(p.UsdGeom.Tokens.guide)
    mesh.CreateSubdivisionSchemeAttr(p.UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(p.UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(False)
    _author_mesh_data(p, mesh, col.mesh)
    prim = mesh.GetPrim()
    p.UsdPhysics.CollisionAPI.Apply(prim)
    p.UsdPhysics.MeshCollisionAPI.Apply(prim).CreateApproximationAttr(p.UsdPhysics.Tokens.convexHull)


# ---------------------------------------------------------------- variants

def _visual_mesh_path(root_path, link: ir.Link, visual: ir.Visual):
    return root_path.AppendChild(names.safe_name(link.name)).AppendChild(
        names.safe_name(visual.name)).AppendChild(_MESH)


def _author_lod_variants(p, stage, root, asset: ir.Asset) -> None:
    """Variant set `lod` on the root: lodI authors every visual's mesh at level I (the
    coarsest it has when it has fewer levels). Default lod0."""
    vset = root.GetVariantSets().AddVariantSet("lod")
    levels = max(1, asset.lod_count)
    for level in range(levels):
        vset.AddVariant(f"lod{level}")
    for level in range(levels):
        vset.SetVariantSelection(f"lod{level}")
        with vset.GetVariantEditContext():
            for link, visual in asset.visuals():
                mesh = p.UsdGeom.Mesh(stage.GetPrimAtPath(_visual_mesh_path(root.GetPath(), link, visual)))
                # Blend-shape offsets fit only the authored topology: keep it at every level.
                data = visual.mesh if visual.mesh.shape_keys else visual.lod(level)
                _author_mesh_data(p, mesh, data)
    vset.SetVariantSelection("lod0")


def _state_bindings(asset: ir.Asset) -> list[ir.StateBinding]:
    """`material` bindings that list materials, in a fixed order (variable, target)."""
    chosen = (b for b in asset.bindings if b.effect == "material" and b.materials)
    return sorted(chosen, key=lambda b: (b.variable, b.target))


def _material_targets(asset: ir.Asset) -> set[str]:
    return {b.target for b in _state_bindings(asset)}


def _author_plain_bindings(p, stage, root, asset: ir.Asset, looks: dict) -> None:
    """Bind every visual without a material state to its material, outside variants.
    Visuals driven by a material state get their binding only inside the state variants:
    a local binding would be stronger than any variant's."""
    driven = _material_targets(asset)
    for link, visual in asset.visuals():
        if visual.name in driven:
            continue
        _bind(p, stage.GetPrimAtPath(_visual_mesh_path(root.GetPath(), link, visual)), looks[visual.material])


def _author_state_variants(p, stage, root, asset: ir.Asset, looks: dict) -> None:
    """Per `material` binding: variant set `state_<variable>`, variants s0..sK binding the
    target's mesh to materials[i]. Default: the visual's own material when it is one of
    the states (so every format shows the same default look), else the last state."""
    where = asset.source or asset.id
    by_name = {v.name: (link, v) for link, v in asset.visuals()}
    for binding in _state_bindings(asset):
        if binding.target not in by_name:
            raise UserError(where, binding.target, f"state {binding.variable!r} targets a visual that does not exist")
        for name in binding.materials:
            if name not in looks:
                raise UserError(where, binding.target, f"state {binding.variable!r} lists unknown material {name!r}")
        link, visual = by_name[binding.target]
        mesh_path = _visual_mesh_path(root.GetPath(), link, visual)
        vset = root.GetVariantSets().AddVariantSet(f"state_{names.safe_name(binding.variable)}")
        for i in range(len(binding.materials)):
            vset.AddVariant(f"s{i}")
        for i, name in enumerate(binding.materials):
            vset.SetVariantSelection(f"s{i}")
            with vset.GetVariantEditContext():
                _bind(p, stage.GetPrimAtPath(mesh_path), looks[name])
        mats = list(binding.materials)
        default = mats.index(visual.material) if visual.material in mats else len(mats) - 1
        vset.SetVariantSelection(f"s{default}")


# ---------------------------------------------------------------- joints

_PRINCIPAL = {(1.0, 0.0, 0.0): "X", (0.0, 1.0, 0.0): "Y", (0.0, 0.0, 1.0): "Z"}


def _axis_frame(axis: np.ndarray) -> tuple[np.ndarray, str]:
    """(4, 4) rotation R and axis token so that R's token axis is the IR axis.

    A positive principal axis keeps R = I; any other axis (negative principal ones
    included) gets the shortest rotation taking +X onto it and token "X".
    """
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    token = _PRINCIPAL.get(tuple(float(c) for c in a))
    r = np.eye(4)
    if token is not None:
        return r, token
    # Rodrigues from u = +X or -X, whichever is nearer to a (so 1 + c >= 1 stays well
    # conditioned); starting from -X prepends a half turn about Z, which takes X to -X.
    flip = a[0] < 0.0
    u = np.array([-1.0 if flip else 1.0, 0.0, 0.0])
    v, c = np.cross(u, a), float(np.dot(u, a))
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    r[:3, :3] = np.eye(3) + vx + vx @ vx / (1.0 + c)
    if flip:
        r[:3, :3] = r[:3, :3] @ np.diag([-1.0, -1.0, 1.0])
    return r, "X"


def _author_joints(p, stage, root_path, asset: ir.Asset) -> None:
    where = asset.source or asset.id
    scope = root_path.AppendChild(_JOINTS)
    p.UsdGeom.Scope.Define(stage, scope)
    links = {link.name: link for link in asset.links}
    for joint in asset.joints:
        for end in (joint.parent, joint.child):
            if end not in links:
                raise UserError(where, joint.name, f"joint names link {end!r} that does not exist")
        if joint.type != "fixed" and not np.linalg.norm(joint.axis) > 1e-9:
            raise UserError(where, joint.name, "joint axis has (near) zero length")
        _author_joint(p, stage, scope.AppendChild(names.safe_name(joint.name)), root_path, joint,
                      links[joint.parent], links[joint.child])


def _author_joint(p, stage, path, root_path, joint: ir.Joint, parent: ir.Link, child: ir.Link) -> None:
    kinds = {"revolute": p.UsdPhysics.RevoluteJoint, "continuous": p.UsdPhysics.RevoluteJoint,
             "prismatic": p.UsdPhysics.PrismaticJoint, "fixed": p.UsdPhysics.FixedJoint}
    j = kinds[joint.type].Define(stage, path)
    j.CreateBody0Rel().SetTargets([root_path.AppendChild(names.safe_name(parent.name))])
    j.CreateBody1Rel().SetTargets([root_path.AppendChild(names.safe_name(child.name))])
    rot, token = (np.eye(4), "X") if joint.type == "fixed" else _axis_frame(joint.axis)
    # The pivot frame (rotated so its token axis is the IR axis) in each body's frame.
    for k, body in ((0, parent), (1, child)):
        local = compose(np.linalg.inv(body.pose), joint.pose, rot)
        getattr(j, f"CreateLocalPos{k}Attr")(p.Gf.Vec3f(*(float(c) for c in local[:3, 3])))
        w, x, y, z = quaternion_from_matrix(local)
        getattr(j, f"CreateLocalRot{k}Attr")(p.Gf.Quatf(float(w), float(x), float(y), float(z)))
    if joint.type != "fixed":
        j.CreateAxisAttr(token)
    if joint.type in ("revolute", "prismatic") and joint.lower is not None and joint.upper is not None:
        scale = 180.0 / math.pi if joint.type == "revolute" else 1.0  # UsdPhysics angles are degrees
        j.CreateLowerLimitAttr(float(joint.lower) * scale)
        j.CreateUpperLimitAttr(float(joint.upper) * scale)
    prim = j.GetPrim()
    prim.SetCustomDataByKey("ir:name", joint.name)
    prim.SetCustomDataByKey("ir:type", joint.type)
    prim.SetCustomDataByKey("ir:axis", p.Gf.Vec3d(*(float(c) for c in joint.axis)))
    for key in ("lower", "upper", "effort", "velocity"):
        value = getattr(joint, key)
        if value is not None:
            prim.SetCustomDataByKey(f"ir:{key}", float(value))
