"""Read one .blend asset (DESIGN.md s.2) into an `ir.Asset`.

The file is untrusted: `safe_open` opens it with nothing stored in it run, and
mutes its Python-expression drivers before anything is evaluated.

What becomes what:
- the asset is the objects of the view layer (hidden ones included, excluded
  collections not); geometry objects (mesh, curve, surface, text) are evaluated
  through the viewport depsgraph (modifiers applied, as the modeller sees them and as
  the sample's digest hashes them) and triangulated with `loop_triangles` (`walk`,
  `evaluate`);
- an object with `collision = true` is an `ir.Collision`, any other an `ir.Visual`
  named after the object; an object whose triangles use several materials becomes one
  visual per material, named `<object>__<material>` (`walk`, `materials`);
- links: `base` holds everything not below a joint Empty; a joint Empty `<e>` (custom
  property `joint`) is the joint `<e>` and starts the link `<e>_link`, whose frame is
  the Empty's world transform without scale; an object belongs to the link of its
  nearest joint-Empty ancestor (`links`);
- a visual's pose is rigid (rotation + translation of its object, relative to its link);
  the rest of the object's matrix (scale, shear, mirror) is baked into the vertices,
  and a mirrored object gets its winding reversed so faces stay outward (`arrays`);
- normals are left None (writers compute smooth ones); UVs come from the active UV
  layer, vertices being split where corners disagree;
- shape keys: each key is the shape with that key alone at full weight (reference +
  key - its own reference). The rest mesh is the mix the file shows (each key at its
  saved value), so every writer shows what the modeller saw; except on an object a
  `shape` binding drives (in the file or asset.toml): there the binding sets the
  weights, the saved values are a preview, and the rest mesh is the reference key.
  The notes say which values make a rest mesh and which are left to a binding
  (`evaluate`);
- state bindings come from an object's `state*` properties and asset.toml's
  `[[bindings]]` (`bindings`);
- an Empty named `terminal.<name>` is a conductor terminal at its world location, in
  the model frame like everything else (`walk`); asset.toml `[[terminals]]` adds to
  them, and a name in both is an error (builder.package_task).

What the IR does not carry is said, one warning each in the metadata (`warning.<what>`,
validate.checks SRC001), never dropped silently (`not_carried`):
- armatures: every armature is put in its rest pose before anything is evaluated, so
  meshes it deforms or carries (bone parents) are read at rest, never at the frame of
  an action the file was saved in;
- animation: actions are not carried; objects are read as the file shows them at its
  current frame (armatures at rest);
- a file saved by a newer Blender than the one reading it (data may be lost).

Units: the scene's unit scale (metres per Blender unit; unitless scenes are metres),
unless asset.toml says `units`; `scale` multiplies after; `up_axis` turns the model
(Blender is Z up).

bpy is imported only inside the functions that need it, so the package imports
without Blender. Everything else is plain numpy on arrays.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from ... import ir
from .arrays import build_mesh, rigid_inverse, split_rigid
from .bindings import merge_bindings
from .links import assign_mass
from .not_carried import animation_warning, newer_file_warning, rest_armatures
from .safe_open import header_version, mute_python_drivers, open_untrusted, untrusted_code_warning
from .scene import Scene, driven_objects, scene_metadata
from .walk import read_scene, unit_metres

__all__ = ["read_blend", "read_blend_path", "build_mesh", "split_rigid", "rigid_inverse", "header_version"]


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
    from ..units import resolve, transform_asset

    path = Path(path)
    open_untrusted(path)
    scene = Scene(driven=driven_objects(bindings))
    scene.warnings.update(newer_file_warning())
    muted = mute_python_drivers()
    scene.warnings.update(untrusted_code_warning(path, muted))
    scene.warnings.update(rest_armatures())
    scene.warnings.update(animation_warning())
    read_scene(path, scene)
    scene.notes.extend(f"{m}: Python driver not evaluated" for m in muted)
    asset_bindings = merge_bindings(scene, bindings, Path(config_path) if config_path else path)
    links = assign_mass(scene.links, mass_kg)
    frame = resolve(SimpleNamespace(units=units, up_axis=up_axis, scale=scale), unit_metres(), None)
    asset = ir.Asset(
        id=asset_id,
        category=category,
        links=links,
        joints=tuple(scene.joints),
        materials=tuple(scene.materials[name] for name in sorted(scene.materials)),
        bindings=asset_bindings,
        description=description,
        source=str(path),
        metadata=scene_metadata(scene) + frame.metadata(),
        terminals=sorted(scene.terminals.items()),
    )
    return transform_asset(asset, frame)
