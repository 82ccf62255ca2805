"""State bindings: an object's `state*` properties and asset.toml's `[[bindings]]`
tables, checked and merged into `ir.StateBinding`s."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ... import ir
from ...errors import UserError
from .arrays import MIN_AXIS_LENGTH
from .materials import material_or_error
from .objects import prop, prop_numbers, prop_strings
from .scene import Scene

EFFECTS = ("rotate", "translate", "scale", "shape", "material")
_VARIABLE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def authored_bindings(path: Path, ob, visual_names, rest: np.ndarray, keys, bpy) -> list[ir.StateBinding]:
    """The object's `state*` properties, one binding per visual of the object."""
    variable = prop(ob, "state")
    if not isinstance(variable, str) or not _VARIABLE.match(variable):
        raise UserError(path, ob.name, f"state = {variable!r}: expected a variable name")
    effect = prop(ob, "state_effect")
    if effect not in EFFECTS:
        raise UserError(path, ob.name, f"state_effect = {effect!r}: expected one of {', '.join(EFFECTS)}")
    if "state_domain" not in ob.keys():
        raise UserError(path, ob.name, "state binding without state_domain")
    domain = prop_numbers(path, ob, "state_domain", 2)
    out_range = prop_numbers(path, ob, "state_range", 2, default=(0.0, 1.0))
    axis = _binding_axis(path, ob, effect, rest)
    shape_key = None
    if effect == "shape":
        shape_key = _shape_key_name(path, ob.name, [k for k, _ in keys], prop(ob, "state_shape_key"))
    materials, thresholds = (), ()
    if effect == "material":
        materials = prop_strings(path, ob, "state_materials")
        thresholds = prop_numbers(path, ob, "state_thresholds", len(materials) - 1)
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
    local = np.array(prop_numbers(path, ob, "state_axis", 3, default=(0.0, 0.0, 1.0)))
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


def merge_bindings(scene: Scene, tables, config_path: Path) -> tuple[ir.StateBinding, ...]:
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
                    scene.materials[m] = material_or_error(config_path, where, m)
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
