"""Read one .blend asset (DESIGN.md s.2) into an `ir.Asset`.

The file is untrusted: it is opened with Python auto-execution off, so text blocks
registered to run on load are skipped. Blender still evaluates the depsgraph while
loading; with auto-execution off it only runs a scripted driver whose bytecode passes
its whitelist (math names only): an expression calling `open` is refused, not run.
The reader then mutes every Python-expression driver before it evaluates anything, so
such properties keep their stored values and nothing depends on that whitelist;
Blender's simple-expression drivers (no Python at all) still work. Muted drivers are
listed in the asset's metadata (`notes`).

What becomes what:
- the asset is the objects of the view layer (hidden ones included, excluded
  collections not); geometry objects (mesh, curve, surface, text) are evaluated
  through the viewport
  depsgraph (modifiers applied, as the modeller sees them and as the sample's digest
  hashes them) and triangulated with `loop_triangles`;
- an object with `collision = true` is an `ir.Collision`, any other an `ir.Visual`
  named after the object; an object whose triangles use several materials becomes one
  visual per material, named `<object>__<material>`;
- links: `base` holds everything not below a joint Empty; a joint Empty `<e>` (custom
  property `joint`) is the joint `<e>` and starts the link `<e>_link`, whose frame is
  the Empty's world transform without scale; an object belongs to the link of its
  nearest joint-Empty ancestor;
- a visual's pose is rigid (rotation + translation of its object, relative to its link);
  the rest of the object's matrix (scale, shear, mirror) is baked into the vertices,
  and a mirrored object gets its winding reversed so faces stay outward;
- normals are left None (writers compute smooth ones); UVs come from the active UV
  layer, vertices being split where corners disagree;
- shape keys: each key is the shape with that key alone at full weight (reference +
  key - its own reference). The rest mesh is the mix the file shows (each key at its
  saved value), so every writer shows what the modeller saw; except on an object a
  `shape` binding drives (in the file or asset.toml): there the binding sets the
  weights, the saved values were a preview, and the rest mesh is the reference key.
  The notes say which values made a rest mesh and which were left to a binding.

What the IR does not carry is said, one warning each in the metadata (`warning.<what>`,
validate.checks SRC001), never dropped silently:
- armatures: every armature is put in its rest pose before anything is evaluated, so
  meshes it deforms or carries (bone parents) are read at rest, never at the frame of
  an action the file was saved in;
- animation: actions are not carried; objects are read as the file shows them at its
  current frame (armatures at rest);
- a file saved by a newer Blender than the one reading it (data may be lost).

Units: the scene's unit scale (metres per Blender unit; unitless scenes are metres),
unless asset.toml says `units`; `scale` multiplies after; `up_axis` turns the model
(Blender is Z up).

bpy is imported only inside the functions that need it, so this module imports
without Blender. Everything else here is plain numpy on arrays.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .. import ir
from ..errors import UserError
from .textures import blend_image

BASE_LINK = "base"
DEFAULT_MATERIAL = "default"
JOINT_TYPES = ("revolute", "prismatic", "continuous", "fixed")
EFFECTS = ("rotate", "translate", "scale", "shape", "material")
GEOMETRY_TYPES = ("MESH", "CURVE", "SURFACE", "FONT")
_VARIABLE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
# A direction shorter than this is no direction (joint or binding axis).
MIN_AXIS_LENGTH = 1e-9
# Smallest share of the asset's mass a link gets, relative to the heaviest link: a link
# without volume (an intermediate pan link, a flat sign) still needs a positive mass.
MIN_MASS_SHARE = 0.01


def read_blend(cfg) -> ir.Asset:
    """The asset of an asset.toml (`config.AssetConfig`) whose source is a .blend."""
    return read_blend_path(
        cfg.source,
        cfg.id,
        cfg.category,
        mass_kg=cfg.mass_kg,
        bindings=cfg.bindings,
        description=cfg.description,
        config_path=cfg.path,
        units=cfg.units,
        up_axis=cfg.up_axis,
        scale=cfg.scale,
    )


def read_blend_path(
    path,
    asset_id: str,
    category: str,
    *,
    mass_kg: float = 100.0,
    bindings=(),
    description: str = "",
    config_path=None,
    units: str | None = None,
    up_axis: str | None = None,
    scale: float = 1.0,
) -> ir.Asset:
    """Read the .blend at `path`. `bindings` are asset.toml binding tables (dicts),
    merged with the ones authored in the file; their errors name `config_path`.
    `units`, `up_axis`, `scale`: asset.toml's (ingest.units)."""
    from .units import resolve, transform_asset

    path = Path(path)
    _open(path)
    scene = _Scene(driven=_driven_objects(bindings))
    scene.warnings.update(_newer_file_warning(path))
    muted = _mute_python_drivers()
    scene.warnings.update(_rest_armatures())
    scene.warnings.update(_animation_warning())
    _read_scene(path, scene)
    scene.notes.extend(f"{m}: Python driver not evaluated" for m in muted)
    asset_bindings = _merge_bindings(scene, bindings, Path(config_path) if config_path else path)
    links = _assign_mass(scene.links, mass_kg)
    frame = resolve(SimpleNamespace(units=units, up_axis=up_axis, scale=scale), _unit_metres(), None)
    asset = ir.Asset(
        id=asset_id,
        category=category,
        links=links,
        joints=tuple(scene.joints),
        materials=tuple(scene.materials[name] for name in sorted(scene.materials)),
        bindings=asset_bindings,
        description=description,
        source=str(path),
        metadata=_metadata(scene) + frame.metadata(),
    )
    return transform_asset(asset, frame)


# --- opening the file -----------------------------------------------------------


@contextlib.contextmanager
def _quiet_stdout():
    """Blender's C logger prints 'Read blend: ...' on file descriptor 1 for every open;
    builds print progress there. Errors still arrive as exceptions."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _open(path: Path) -> None:
    """Load `path` as Blender's main file without running anything stored in it.

    Every open replaces the whole main database, so nothing leaks between files."""
    if not path.is_file():
        raise UserError(path, None, "file not found")
    import bpy

    # Both switches: the preference governs later reloads, `use_scripts=False` this
    # load; with them off Blender neither runs registered text blocks nor evaluates
    # Python-expression drivers.
    bpy.context.preferences.filepaths.use_scripts_auto_execute = False
    try:
        with _quiet_stdout():
            bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False, use_scripts=False)
    except RuntimeError as e:
        reason = str(e).strip().splitlines()[0] if str(e).strip() else "unreadable"
        reason = reason.removeprefix("Error: ")
        saved = header_version(path)
        if saved is not None and saved > tuple(bpy.app.version[:2]):
            reason += (f" (saved by Blender {saved[0]}.{saved[1]}, newer than the Blender "
                       f"{bpy.app.version_string} reading it)")
        raise UserError(path, None, f"not a readable .blend file (truncated or corrupt?): {reason}") from None


_HEADER = re.compile(rb"^BLENDER(?:[-_][vV](\d)(\d\d)|\d\d-\d\d[vV](\d\d)(\d\d))")


def header_version(path: Path) -> tuple[int, int] | None:
    """(major, minor) Blender version in an uncompressed .blend's header, e.g.
    BLENDER-v279 (2.79) or BLENDER17-01v0500 (5.0); None when compressed or not one."""
    with open(path, "rb") as fh:
        head = fh.read(17)
    m = _HEADER.match(head)
    if m is None:
        return None
    major, minor = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    return int(major), int(minor)


def _newer_file_warning(path: Path) -> dict[str, str]:
    """A warning when the file was saved by a newer Blender than the one reading it
    (its file version beyond bpy's): Blender reads it, but may drop what it does not know."""
    import bpy

    saved, reader = tuple(bpy.data.version), tuple(bpy.app.version_file)
    if saved <= reader:
        return {}
    return {"blender_version": f"saved by Blender {saved[0]}.{saved[1]} (file version {'.'.join(map(str, saved))}), "
                               f"newer than the Blender {bpy.app.version_string} reading it: data it does not know is "
                               "lost (save it from this version, or update bpy)"}


def _unit_metres() -> float | None:
    """Metres per Blender unit of the scene, None for a unitless scene."""
    import bpy

    units = bpy.context.scene.unit_settings
    # a single-precision property: its 7 digits, so 0.001 stays 0.001
    return None if units.system == "NONE" else float(f"{units.scale_length:.7g}")


def _listed(names: list[str], most: int = 5) -> str:
    names = sorted(names)
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def _rest_armatures() -> dict[str, str]:
    """Every armature in its rest pose (before any evaluation reads a mesh); one
    warning naming them and, where the file showed one, the pose it was saved in."""
    import bpy

    armatures = [ob for ob in bpy.data.objects if ob.type == "ARMATURE"]
    if not armatures:
        return {}
    posed = []
    for ob in armatures:
        action = ob.animation_data.action if ob.animation_data else None
        moved = ob.pose is not None and any(not np.allclose(np.array(pb.matrix_basis), np.eye(4)) for pb in ob.pose.bones)
        if ob.data.pose_position == "POSE" and (action is not None or moved):
            posed.append(f"{ob.name} showed {'action ' + repr(action.name) if action else 'a pose'}")
    for arm in bpy.data.armatures:
        arm.pose_position = "REST"
    bpy.context.evaluated_depsgraph_get().update()
    names = [f"{ob.name} ({len(ob.data.bones)} bones)" for ob in armatures]
    saved = f"; the file was saved posed ({'; '.join(sorted(posed))} at frame {bpy.context.scene.frame_current})" \
        if posed else ""
    return {"armature": f"armatures are not carried: {_listed(names)}; the meshes they deform or carry are read "
                        f"in the rest pose{saved}"}


def _animation_warning() -> dict[str, str]:
    """One warning for the actions of the file, which the IR does not carry."""
    import bpy

    actions = [a.name for a in bpy.data.actions]
    if not actions:
        return {}
    return {"animation": f"{len(actions)} actions are not carried ({_listed(actions)}): objects are read as the "
                         f"file shows them at frame {bpy.context.scene.frame_current}, armatures at rest"}


# ID collections whose blocks can carry drivers (animation_data).
_ANIMATABLE = (
    "objects", "meshes", "shape_keys", "materials", "node_groups", "scenes", "curves",
    "lights", "cameras", "worlds", "textures", "armatures", "lattices", "metaballs",
)


def _mute_python_drivers() -> list[str]:
    """Mute every scripted driver that is not a simple expression; returns them as
    `<id name>.<data path>[<index>]`, sorted."""
    import bpy

    owners = []
    for attr in _ANIMATABLE:
        for block in getattr(bpy.data, attr, ()):
            owners.append(block)
            tree = getattr(block, "node_tree", None)
            if tree is not None:
                owners.append(tree)
    muted = []
    for block in owners:
        ad = getattr(block, "animation_data", None)
        if ad is None:
            continue
        for fc in ad.drivers:
            if fc.driver.type == "SCRIPTED" and not fc.driver.is_simple_expression and not fc.mute:
                fc.mute = True
                muted.append(f"{block.name}.{fc.data_path}[{fc.array_index}]")
    if muted:
        bpy.context.evaluated_depsgraph_get().update()
    return sorted(muted)


# --- pure pose arithmetic (no bpy) ------------------------------------------------


def split_rigid(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split an affine (4, 4) float64 matrix M into a rigid pose P and a linear rest S
    with M = P @ [S 0; 0 1].

    P's rotation is the orthogonal polar factor of M's 3x3 part, negated when that is a
    reflection (a 3x3 negation flips the determinant), so P is always a proper rotation
    and S carries scale, shear and any mirroring (det S < 0). For an unscaled object P
    is its matrix and S the identity. Returns (P (4, 4), S (3, 3)); raises ValueError
    for a singular (zero-scale) matrix."""
    m = np.asarray(matrix, dtype=np.float64)
    a = m[:3, :3]
    u, sigma, vt = np.linalg.svd(a)
    if not np.all(np.isfinite(sigma)) or sigma[-1] <= 1e-12 * max(sigma[0], 1e-300):
        raise ValueError("zero scale")
    q = u @ vt
    if np.linalg.det(q) < 0.0:
        q = -q
    s = q.T @ a
    p = np.eye(4)
    p[:3, :3] = q
    p[:3, 3] = m[:3, 3]
    return p, s


def rigid_inverse(p: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) pose."""
    inv = np.eye(4)
    inv[:3, :3] = p[:3, :3].T
    inv[:3, 3] = -p[:3, :3].T @ p[:3, 3]
    return inv


def build_mesh(
    co: np.ndarray,
    tris: np.ndarray,
    corner_uvs: np.ndarray | None,
    rest: np.ndarray,
    keys: tuple[tuple[str, np.ndarray], ...] = (),
) -> ir.Mesh:
    """An `ir.Mesh` from Blender-style arrays.

    co: (n, 3) float64 object-local vertices; tris: (m, 3) vertex indices;
    corner_uvs: (m, 3, 2) UV per triangle corner, or None; rest: (3, 3) linear part
    baked into the vertices (mirroring reverses the winding); keys: (name, (n, 3)
    absolute local positions). Unreferenced vertices are dropped; a vertex whose
    corners carry different UVs is split, so uvs are per vertex."""
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if corner_uvs is None:
        source, inverse = np.unique(tris.ravel(), return_inverse=True)
        uvs = None
    else:
        corners = np.column_stack([tris.ravel().astype(np.float64), corner_uvs.reshape(-1, 2)])
        rows, inverse = np.unique(corners, axis=0, return_inverse=True)
        source = rows[:, 0].astype(np.int64)
        uvs = rows[:, 1:]
    faces = inverse.reshape(-1, 3)
    if np.linalg.det(rest) < 0.0:
        faces = faces[:, ::-1]
    vertices = co[source] @ rest.T
    shape_keys = tuple(ir.ShapeKey(name, k[source] @ rest.T) for name, k in keys)
    return ir.Mesh(vertices=vertices, faces=faces, uvs=uvs, shape_keys=shape_keys)


# --- the scene ---------------------------------------------------------------------


@dataclass
class _Part:
    """One visual or collision before links are assembled."""

    link: str
    obj: str
    item: ir.Visual | ir.Collision
    rest: np.ndarray  # the object's linear rest S, to map authored axes


@dataclass
class _Scene:
    links: list[ir.Link] = field(default_factory=list)
    joints: list[ir.Joint] = field(default_factory=list)
    materials: dict[str, ir.Material] = field(default_factory=dict)
    parts: list[_Part] = field(default_factory=list)
    bindings: list[ir.StateBinding] = field(default_factory=list)
    # object name -> names of its visuals (one per material), for binding targets
    visuals_of: dict[str, tuple[str, ...]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    warnings: dict[str, str] = field(default_factory=dict)  # what is not carried -> the message
    # objects and visuals whose shape-key weights asset.toml's bindings drive (_driven)
    driven: frozenset[str] = frozenset()

    def drives(self, ob) -> bool:
        """Whether a shape binding sets the object's shape-key weights."""
        if _prop(ob, "state_effect") == "shape":
            return True
        return any(t == ob.name or t.startswith(f"{ob.name}__") for t in self.driven)


def _driven_objects(tables) -> frozenset[str]:
    """Targets (object or visual names) of asset.toml's shape bindings."""
    return frozenset(str(t["target"]) for t in tables if t.get("effect") == "shape")


def _read_scene(path: Path, scene: _Scene) -> None:
    import bpy

    objects = _asset_objects(bpy)
    if not any(ob.type in GEOMETRY_TYPES for ob in objects):
        raise UserError(path, None, "the scene holds no mesh objects")
    depsgraph = bpy.context.evaluated_depsgraph_get()

    for ob in objects:
        if "joint" in ob.keys() and ob.type != "EMPTY":
            raise UserError(path, ob.name, f"has a `joint` property but is a {ob.type.lower()}, not an Empty")
    empties = [ob for ob in objects if ob.type == "EMPTY" and "joint" in ob.keys()]
    link_pose = {BASE_LINK: ir.pose()}
    parent_of_link: dict[str, str] = {}
    for empty in empties:
        joint = _joint(path, empty, depsgraph)
        scene.joints.append(joint)
        link_pose[joint.child] = joint.pose
        parent_of_link[joint.child] = joint.parent

    for ob in objects:
        if ob.type not in GEOMETRY_TYPES:
            if "state" in ob.keys():
                raise UserError(path, ob.name, "state binding on an object without geometry (bind the mesh itself)")
            continue
        link = _link_of(ob)
        _read_object(path, ob, depsgraph, link, link_pose[link], scene, bpy)

    _check_names(path, scene)
    scene.links = _assemble_links(path, scene, link_pose, parent_of_link)
    for material_name in _referenced_materials(scene):
        if material_name not in scene.materials:
            scene.materials[material_name] = _material(bpy, path, material_name, scene.warnings)


def _asset_objects(bpy) -> list:
    """The objects of the view layer, sorted by name. Objects only hidden in the
    viewport (a collision box a modeller hid, a disabled collection) are part of the
    asset: they are un-hidden here so the depsgraph evaluates their modifiers too.
    Objects outside the view layer (an excluded collection, an unlinked object) are
    not part of it."""
    for collection in bpy.data.collections:
        collection.hide_viewport = False
    objects = sorted(bpy.context.view_layer.objects, key=lambda o: o.name)
    for ob in objects:
        ob.hide_viewport = False
    return objects


def _link_of(ob) -> str:
    """The link of a non-joint object, or of a joint Empty's parent side."""
    p = ob.parent
    while p is not None:
        if p.type == "EMPTY" and "joint" in p.keys():
            return f"{p.name}_link"
        p = p.parent
    return BASE_LINK


def _world(path: Path, ob, depsgraph) -> np.ndarray:
    m = np.array(ob.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise UserError(path, ob.name, "transform has NaN or infinite values")
    return m


def _split(path: Path, ob, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    try:
        return split_rigid(world)
    except ValueError:
        raise UserError(path, ob.name, "has zero scale") from None


# --- joints --------------------------------------------------------------------------


def _joint(path: Path, empty, depsgraph) -> ir.Joint:
    kind = _prop(empty, "joint")
    if kind not in JOINT_TYPES:
        raise UserError(path, empty.name, f"joint = {kind!r}: expected one of {', '.join(JOINT_TYPES)}")
    world = _world(path, empty, depsgraph)
    pose, _ = _split(path, empty, world)
    local_axis = np.array(_floats(path, empty, "joint_axis", 3, default=(0.0, 0.0, 1.0)))
    if np.linalg.norm(local_axis) < MIN_AXIS_LENGTH:
        raise UserError(path, empty.name, f"joint_axis {tuple(local_axis)} has (near) zero length")
    # Through the Empty's full matrix (a scaled Empty shows its axis that way), then
    # into the unscaled pivot frame.
    axis = pose[:3, :3].T @ (world[:3, :3] @ local_axis)
    length = np.linalg.norm(axis)
    if length < MIN_AXIS_LENGTH:
        raise UserError(path, empty.name, "joint_axis has (near) zero length after the Empty's scale")
    lower = _float(path, empty, "joint_lower")
    upper = _float(path, empty, "joint_upper")
    if kind in ("continuous", "fixed"):
        lower = upper = None
    elif lower is not None and upper is not None and lower > upper:
        raise UserError(path, empty.name, f"joint_lower {lower} is above joint_upper {upper}")
    for key in ("joint_effort", "joint_velocity"):
        value = _float(path, empty, key)
        if value is not None and value < 0:
            raise UserError(path, empty.name, f"{key} {value} is negative")
    return ir.Joint(
        name=empty.name,
        type=kind,
        parent=_link_of(empty),
        child=f"{empty.name}_link",
        pose=pose,
        axis=axis / length,
        lower=lower,
        upper=upper,
        effort=_float(path, empty, "joint_effort"),
        velocity=_float(path, empty, "joint_velocity"),
    )


# --- geometry ------------------------------------------------------------------------


def _truthy(path: Path, ob, key: str) -> bool:
    value = _prop(ob, key)
    if value is None:
        return False
    if isinstance(value, (bool, int)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise UserError(path, ob.name, f"{key} = {value!r}: expected true or false")


def _read_object(path: Path, ob, depsgraph, link: str, link_pose: np.ndarray, scene: _Scene, bpy) -> None:
    world = _world(path, ob, depsgraph)
    rigid, rest = _split(path, ob, world)
    pose = rigid_inverse(link_pose) @ rigid
    is_collision = _truthy(path, ob, "collision")

    arrays = _evaluated_arrays(path, ob, depsgraph, scene)
    co, tris, loops, mat_index, uv, keys = arrays
    if len(tris) == 0:
        raise UserError(path, ob.name, "mesh has no faces (empty mesh object)")
    if not np.all(np.isfinite(co)):
        raise UserError(path, ob.name, "mesh has NaN or infinite vertex coordinates")
    for name, k in keys:
        if not np.all(np.isfinite(k)):
            raise UserError(path, ob.name, f"shape key {name!r} has NaN or infinite coordinates")
    corner_uvs = None if uv is None else uv[loops]

    if is_collision:
        if "state" in ob.keys():
            raise UserError(path, ob.name, "a collision mesh cannot carry a state binding")
        mesh = build_mesh(co, tris, None, rest)
        scene.parts.append(_Part(link, ob.name, ir.Collision(ob.name, mesh, pose), rest))
        return

    slots = [s.material.name if s.material is not None else DEFAULT_MATERIAL for s in ob.material_slots]
    if not slots:
        slots = [DEFAULT_MATERIAL]
    # Blender clamps out-of-range material indices to the last slot.
    names = np.array(slots, dtype=object)[np.clip(mat_index, 0, len(slots) - 1)]
    used = sorted(set(names.tolist()))
    visual_names = []
    for material_name in used:
        sel = names == material_name
        mesh = build_mesh(co, tris[sel], None if corner_uvs is None else corner_uvs[sel], rest, keys)
        name = ob.name if len(used) == 1 else f"{ob.name}__{material_name}"
        visual_names.append(name)
        scene.parts.append(_Part(link, ob.name, ir.Visual(name, material_name, (mesh,), pose), rest))
        if material_name not in scene.materials:
            scene.materials[material_name] = _material(bpy, path, material_name, scene.warnings)
    scene.visuals_of[ob.name] = tuple(visual_names)
    if "state" in ob.keys():
        scene.bindings.extend(_authored_bindings(path, ob, visual_names, rest, keys, bpy))


def _evaluated_arrays(path: Path, ob, depsgraph, scene: _Scene):
    """(co (n,3) f64, tris (m,3), loops (m,3), material index (m,), per-loop uv (L,2) or
    None, shape keys ((name, (n,3)), ...)) of the object's evaluated geometry."""
    key_blocks = None
    if ob.type == "MESH" and ob.data.shape_keys is not None and len(ob.data.shape_keys.key_blocks) > 1:
        key_blocks = ob.data.shape_keys.key_blocks
    if key_blocks is None:
        return (*_mesh_arrays(ob.evaluated_get(depsgraph)), ())
    return _shape_key_arrays(path, ob, depsgraph, key_blocks, scene)


def _mesh_arrays(ob_eval, mesh=None):
    """Arrays of `mesh`, or of the evaluated object's to_mesh() (freed afterwards)."""
    owned = mesh is None
    me = ob_eval.to_mesh() if owned else mesh
    try:
        n = len(me.vertices)
        co = np.empty(n * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        lt = me.loop_triangles
        m = len(lt)
        tris = np.empty(m * 3, dtype=np.int32)
        lt.foreach_get("vertices", tris)
        loops = np.empty(m * 3, dtype=np.int32)
        lt.foreach_get("loops", loops)
        mat_index = np.empty(m, dtype=np.int32)
        lt.foreach_get("material_index", mat_index)
        uv = None
        if me.uv_layers.active is not None and len(me.loops):
            uv = np.empty(len(me.loops) * 2, dtype=np.float32)
            me.uv_layers.active.data.foreach_get("uv", uv)
            uv = uv.reshape(-1, 2).astype(np.float64)
    finally:
        if owned:
            ob_eval.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64), tris.reshape(-1, 3), loops.reshape(-1, 3), mat_index, uv


def _enabled_modifiers(ob) -> list:
    return [m for m in ob.modifiers if m.show_viewport]


def _shape_key_arrays(path: Path, ob, depsgraph, key_blocks, scene: _Scene):
    """The saved mix as the base arrays, plus each key but the reference alone at full
    weight (module docstring).

    Without modifiers: both from the key blocks (_shape_key_arrays_raw). With
    modifiers: the object evaluated as saved, and each key evaluated alone through the
    stack (show_only_shape_key); if the stack changes the vertex count between them (it
    merges or welds by distance), the modifiers are left out for this object and a
    warning says so."""
    names = [kb.name for kb in key_blocks]
    mixed = not scene.drives(ob)
    _note_key_values(ob, key_blocks, scene, mixed)
    if not _enabled_modifiers(ob):
        return _shape_key_arrays_raw(ob, key_blocks, names, mixed)

    base = _mesh_arrays(ob.evaluated_get(depsgraph)) if mixed else None
    ob.show_only_shape_key = True
    evaluated = []
    for i in range(0 if base is None else 1, len(key_blocks)):
        ob.active_shape_key_index = i
        depsgraph.update()
        evaluated.append(_mesh_arrays(ob.evaluated_get(depsgraph)))
    ob.show_only_shape_key = False
    ob.active_shape_key_index = 0
    depsgraph.update()
    if base is None:
        base = evaluated.pop(0)
    if all(len(e[0]) == len(base[0]) for e in evaluated):
        return (*base, tuple((name, e[0]) for name, e in zip(names[1:], evaluated)))
    lost = scene.warnings.get("shape_keys", "shape keys read without the modifiers of: ")
    scene.warnings["shape_keys"] = lost + ("" if lost.endswith(": ") else ", ") + \
        f"{ob.name} (its modifiers change the vertex count between keys)"
    return _shape_key_arrays_raw(ob, key_blocks, names, mixed)


def _note_key_values(ob, key_blocks, scene: _Scene, mixed: bool) -> None:
    """The saved values, and whether they make the object's rest mesh, in the notes."""
    values = [f"{kb.name}={kb.value:g}" for kb in list(key_blocks)[1:] if kb.value != 0.0 and not kb.mute]
    if values:
        what = "make its rest mesh" if mixed else "left to its shape binding (the rest mesh is the reference key)"
        scene.notes.append(f"{ob.name}: shape key values {', '.join(values)} {what}")


def _shape_key_arrays_raw(ob, key_blocks, names, mixed: bool = True):
    """Mesh data arrays with the mix of the keys' saved values as positions (a key's
    offset is from its reference key, scaled by its vertex group; the reference key
    alone unless `mixed`), and each key alone: reference + key - its own reference."""
    co, tris, loops, mat_index, uv = _mesh_arrays(None, ob.data)
    positions = {}
    for kb in key_blocks:
        buf = np.empty(len(co) * 3, dtype=np.float32)
        kb.data.foreach_get("co", buf)
        positions[kb.name] = buf.reshape(-1, 3).astype(np.float64)
    reference = positions[key_blocks[0].name]
    mix = reference.copy()
    alone = []
    for kb in list(key_blocks)[1:]:
        offset = positions[kb.name] - positions[kb.relative_key.name]
        alone.append((kb.name, reference + offset))
        if mixed and kb.value != 0.0 and not kb.mute:
            mix += kb.value * _group_weights(ob, kb.vertex_group, len(co))[:, None] * offset
    return mix, tris, loops, mat_index, uv, tuple(alone)


def _group_weights(ob, group: str, n: int) -> np.ndarray:
    """(n,) weights of vertex group `group` (ones when the key names none)."""
    if not group or group not in ob.vertex_groups:
        return np.ones(n)
    index = ob.vertex_groups[group].index
    weights = np.zeros(n)
    for v in ob.data.vertices:
        for g in v.groups:
            if g.group == index:
                weights[v.index] = g.weight
    return weights


# --- materials -------------------------------------------------------------------------


def _material(bpy, path: Path, name: str, warnings: dict | None = None) -> ir.Material:
    """Principled BSDF inputs of material `name`: their unlinked values, and the image
    of an Image Texture node linked to Base Color, Normal (through a Normal Map node) or
    Emission Color, whose factor is then white as in Blender; a material without one
    falls back to its viewport colour, metallic and roughness. An image that cannot be
    had (external, outside the .blend's folder or missing) is a warning."""
    if name == DEFAULT_MATERIAL and name not in bpy.data.materials:
        return ir.Material(DEFAULT_MATERIAL)
    mat = bpy.data.materials.get(name)
    if mat is None:
        raise UserError(path, name, "material not found in the file")
    bsdf = _principled(mat)
    if bsdf is None:
        r, g, b, a = (float(c) for c in mat.diffuse_color)
        return ir.Material(name, (r, g, b, a), float(mat.metallic), float(mat.roughness))
    inputs = bsdf.inputs
    r, g, b = (float(c) for c in inputs["Base Color"].default_value[:3])
    alpha = float(inputs["Alpha"].default_value)
    strength = float(inputs["Emission Strength"].default_value)
    emission = tuple(float(c) * strength for c in inputs["Emission Color"].default_value[:3])
    values = (r, g, b, alpha, float(inputs["Metallic"].default_value), float(inputs["Roughness"].default_value), *emission)
    if not all(math.isfinite(v) for v in values):
        raise UserError(path, name, "material has NaN or infinite values")
    textures, missing = _textures(path, name, inputs)
    if missing and warnings is not None:
        warnings["textures"] = ", ".join(filter(None, [warnings.get("textures"), *missing]))
    if "base_color" in textures:
        r, g, b = 1.0, 1.0, 1.0
    if "emissive" in textures:
        emission = (strength, strength, strength)
    return ir.Material(
        name,
        base_color=(r, g, b, alpha),
        metallic=float(inputs["Metallic"].default_value),
        roughness=float(inputs["Roughness"].default_value),
        emission=emission,
        **{f"{slot}_texture": t for slot, t in textures.items()},
    )


_TEXTURE_SOCKETS = {"base_color": "Base Color", "normal": "Normal", "emissive": "Emission Color"}


def _textures(path: Path, name: str, inputs) -> tuple[dict[str, ir.Texture], list[str]]:
    """slot -> texture of the Principled inputs' linked images, and what could not be read."""
    found, missing = {}, []
    for slot, socket in _TEXTURE_SOCKETS.items():
        image = _linked_image(inputs[socket]) if socket in inputs else None
        if image is None:
            continue
        texture = blend_image(image, path, f"{_safe_stem(name)}_{slot}")
        if texture is None:
            missing.append(f"{name}.{socket} image {image.name!r} (not packed, not inside the .blend's folder)")
        else:
            found[slot] = texture
    return found, missing


def _linked_image(socket):
    """The image of an Image Texture node feeding `socket`, directly or through a Normal
    Map node; None for anything else (a procedural texture is not carried)."""
    for link in socket.links:
        node = link.from_node
        if node.type == "NORMAL_MAP" and "Color" in node.inputs:
            return _linked_image(node.inputs["Color"])
        if node.type == "TEX_IMAGE" and node.image is not None:
            return node.image
    return None


def _safe_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "material"


def _principled(mat):
    """The Principled BSDF feeding the material output, else the first one."""
    if mat.node_tree is None:
        return None
    nodes = [n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"]
    for node in nodes:
        if any(link.to_node.type == "OUTPUT_MATERIAL" for out in node.outputs for link in out.links):
            return node
    return nodes[0] if nodes else None


def _referenced_materials(scene: _Scene) -> list[str]:
    return sorted({m for b in scene.bindings for m in b.materials})


# --- state bindings ------------------------------------------------------------------


def _authored_bindings(path: Path, ob, visual_names, rest: np.ndarray, keys, bpy) -> list[ir.StateBinding]:
    """The object's `state*` properties, one binding per visual of the object."""
    variable = _prop(ob, "state")
    if not isinstance(variable, str) or not _VARIABLE.match(variable):
        raise UserError(path, ob.name, f"state = {variable!r}: expected a variable name")
    effect = _prop(ob, "state_effect")
    if effect not in EFFECTS:
        raise UserError(path, ob.name, f"state_effect = {effect!r}: expected one of {', '.join(EFFECTS)}")
    if "state_domain" not in ob.keys():
        raise UserError(path, ob.name, "state binding without state_domain")
    domain = _floats(path, ob, "state_domain", 2)
    out_range = _floats(path, ob, "state_range", 2, default=(0.0, 1.0))
    axis = _binding_axis(path, ob, effect, rest)
    shape_key = None
    if effect == "shape":
        shape_key = _shape_key_name(path, ob.name, [k for k, _ in keys], _prop(ob, "state_shape_key"))
    materials, thresholds = (), ()
    if effect == "material":
        materials = _strings(path, ob, "state_materials")
        thresholds = _floats(path, ob, "state_thresholds", len(materials) - 1)
        _check_material_choice(path, ob.name, materials, thresholds)
        for m in materials:
            if m not in bpy.data.materials:
                raise UserError(path, ob.name, f"state_materials names {m!r}, which is not a material of the file")
    return [
        ir.StateBinding(variable, effect, name, domain, out_range, axis, shape_key, materials, thresholds)
        for name in visual_names
    ]


def _binding_axis(path: Path, ob, effect: str, rest: np.ndarray) -> tuple[float, float, float]:
    """`state_axis` (object-local, default Z) expressed in the visual's frame, whose
    vertices are `rest @ local`. A rotation axis is a pseudo-vector: it turns with the
    mirror (det) so the motion looks the same."""
    local = np.array(_floats(path, ob, "state_axis", 3, default=(0.0, 0.0, 1.0)))
    if np.linalg.norm(local) < MIN_AXIS_LENGTH:
        raise UserError(path, ob.name, "state_axis has (near) zero length")
    axis = rest @ local
    if effect == "rotate" and np.linalg.det(rest) < 0.0:
        axis = -axis
    axis = axis / np.linalg.norm(axis)
    if np.allclose(axis, np.round(axis), atol=1e-12):
        axis = np.round(axis) + 0.0  # keep authored unit axes exact (and no -0)
    return tuple(float(a) for a in axis)


def _shape_key_name(file, obj: str, keys: list[str], wanted) -> str:
    if not keys:
        raise UserError(file, obj, "shape binding on a mesh without shape keys")
    if wanted is not None:
        if wanted not in keys:
            raise UserError(file, obj, f"shape key {wanted!r} not found (keys: {', '.join(keys)})")
        return wanted
    if len(keys) > 1:
        raise UserError(file, obj, f"several shape keys ({', '.join(keys)}): name one with state_shape_key")
    return keys[0]


def _check_material_choice(file, obj: str, materials, thresholds) -> None:
    if len(materials) < 2:
        raise UserError(file, obj, "a material binding needs at least two materials")
    if len(thresholds) != len(materials) - 1:
        raise UserError(file, obj, f"{len(materials)} materials need {len(materials) - 1} thresholds")
    if list(thresholds) != sorted(thresholds):
        raise UserError(file, obj, "material thresholds must ascend")


def _merge_bindings(scene: _Scene, tables, config_path: Path) -> tuple[ir.StateBinding, ...]:
    """Authored bindings plus asset.toml ones. A table's target is a visual name or an
    object name (then every visual of that object); its axis is in the visual frame."""
    result = list(scene.bindings)
    visuals = {p.item.name: p for p in scene.parts if isinstance(p.item, ir.Visual)}
    for i, t in enumerate(tables):
        where = f"bindings[{i}]"
        target = t["target"]
        names = scene.visuals_of.get(target) or ((target,) if target in visuals else None)
        if names is None:
            raise UserError(config_path, f"{where}.target", f"no visual or object named {target!r} in the source")
        materials = tuple(t.get("materials", ()))
        thresholds = tuple(float(x) for x in t.get("thresholds", ()))
        if t["effect"] == "material":
            _check_material_choice(config_path, where, materials, thresholds)
            for m in materials:
                if m not in scene.materials:
                    scene.materials[m] = _material_or_error(config_path, where, m)
        axis = np.array(t.get("axis", (0.0, 0.0, 1.0)), dtype=np.float64)
        if np.linalg.norm(axis) < MIN_AXIS_LENGTH:
            raise UserError(config_path, f"{where}.axis", "axis has (near) zero length")
        axis = axis / np.linalg.norm(axis)
        for name in names:
            shape_key = None
            if t["effect"] == "shape":
                keys = [k.name for k in visuals[name].item.mesh.shape_keys]
                shape_key = _shape_key_name(config_path, where, keys, t.get("shape_key"))
            result.append(
                ir.StateBinding(
                    variable=t["variable"],
                    effect=t["effect"],
                    target=name,
                    domain=tuple(float(x) for x in t["domain"]),
                    range=tuple(float(x) for x in t.get("range", (0.0, 1.0))),
                    axis=tuple(float(a) for a in axis),
                    shape_key=shape_key,
                    materials=materials,
                    thresholds=thresholds,
                )
            )
    seen = set()
    for b in result:
        key = (b.target, b.variable, b.effect)
        if key in seen:
            raise UserError(config_path, b.target, f"binding of {b.variable!r} ({b.effect}) given twice (file and asset.toml?)")
        seen.add(key)
    return tuple(sorted(result, key=lambda b: (b.target, b.variable, b.effect)))


def _material_or_error(config_path: Path, where: str, name: str) -> ir.Material:
    import bpy

    if name not in bpy.data.materials:
        raise UserError(config_path, f"{where}.materials", f"material {name!r} is not in the source file")
    return _material(bpy, config_path, name)


# --- links and mass ----------------------------------------------------------------------


def _check_names(path: Path, scene: _Scene) -> None:
    seen: dict[str, str] = {}
    for part in scene.parts:
        name = part.item.name
        if name in seen:
            raise UserError(path, part.obj, f"visual name {name!r} clashes with object {seen[name]!r}")
        seen[name] = part.obj


def _assemble_links(path: Path, scene: _Scene, link_pose, parent_of_link) -> list[ir.Link]:
    """Links parent-first (base, then breadth-first, siblings by name)."""
    visuals: dict[str, list] = {name: [] for name in link_pose}
    collisions: dict[str, list] = {name: [] for name in link_pose}
    for part in scene.parts:
        (visuals if isinstance(part.item, ir.Visual) else collisions)[part.link].append(part.item)
    for part in scene.parts:
        if isinstance(part.item, ir.Collision) and not visuals[part.link]:
            raise UserError(path, part.obj, f"collision mesh of link {part.link!r}, which has no visual geometry")
    order = [BASE_LINK]
    for name in order:
        order.extend(sorted(c for c, p in parent_of_link.items() if p == name))
    return [ir.Link(name, link_pose[name], tuple(visuals[name]), tuple(collisions[name])) for name in order]


def _assign_mass(links: list[ir.Link], mass_kg: float) -> tuple[ir.Link, ...]:
    """Split `mass_kg` over links in proportion to the summed bounding-box volumes of
    their LOD0 visuals (each box in its visual's frame): cheap, needs no closed meshes,
    and good enough for a kinematic twin. Every link gets at least MIN_MASS_SHARE of
    the heaviest link's share."""
    weights = []
    for link in links:
        w = 0.0
        for v in link.visuals:
            lo, hi = v.mesh.bounds()
            w += float(np.prod(hi - lo))
        weights.append(w)
    top = max(weights, default=0.0)
    if top <= 0.0:
        weights = [1.0] * len(links)
    else:
        weights = [max(w, MIN_MASS_SHARE * top) for w in weights]
    total = sum(weights)
    return tuple(ir.Link(l.name, l.pose, l.visuals, l.collisions, mass_kg * w / total) for l, w in zip(links, weights))


def _metadata(scene: _Scene) -> tuple[tuple[str, str], ...]:
    """Deterministic and free of Blender's version: only what the reader decided."""
    meta = [("source_format", "blend")]
    if scene.notes:
        meta.append(("notes", "; ".join(sorted(scene.notes))))
    meta.extend((f"warning.{k}", scene.warnings[k]) for k in sorted(scene.warnings))
    return tuple(meta)


# --- custom properties ----------------------------------------------------------------------


def _prop(ob, key: str):
    """A custom property as plain Python (lists for arrays), or None."""
    if key not in ob.keys():
        return None
    value = ob[key]
    if hasattr(value, "to_list"):
        return value.to_list()
    if hasattr(value, "to_dict"):
        return value.to_dict()
    return value


def _float(path: Path, ob, key: str) -> float | None:
    value = _prop(ob, key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserError(path, ob.name, f"{key} = {value!r}: expected a finite number")
    return float(value)


def _floats(path: Path, ob, key: str, n: int, default=None) -> tuple[float, ...]:
    value = _prop(ob, key)
    if value is None:
        if default is None:
            raise UserError(path, ob.name, f"missing {key}")
        return tuple(default)
    ok = isinstance(value, (list, tuple)) and len(value) == n
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise UserError(path, ob.name, f"{key} = {value!r}: expected {n} finite numbers")
    return tuple(float(v) for v in value)


def _strings(path: Path, ob, key: str) -> tuple[str, ...]:
    value = _prop(ob, key)
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise UserError(path, ob.name, f"{key} = {value!r}: expected a list of material names")
    return tuple(value)
