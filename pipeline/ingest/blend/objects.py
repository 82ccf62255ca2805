"""What the reader reads off one Blender object: its custom properties as checked
plain values and its world transform, with errors that name the object."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...errors import UserError
from .arrays import split_rigid


def prop(ob, key: str):
    """A custom property as plain Python (lists for arrays), or None."""
    if key not in ob.keys():
        return None
    value = ob[key]
    if hasattr(value, "to_list"):
        return value.to_list()
    if hasattr(value, "to_dict"):
        return value.to_dict()
    return value


def prop_number(path: Path, ob, key: str) -> float | None:
    value = prop(ob, key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserError(path, ob.name, f"{key} = {value!r}: expected a finite number")
    return float(value)


def prop_numbers(path: Path, ob, key: str, n: int, default=None) -> tuple[float, ...]:
    value = prop(ob, key)
    if value is None:
        if default is None:
            raise UserError(path, ob.name, f"missing {key}")
        return tuple(default)
    ok = isinstance(value, (list, tuple)) and len(value) == n
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise UserError(path, ob.name, f"{key} = {value!r}: expected {n} finite numbers")
    return tuple(float(v) for v in value)


def prop_strings(path: Path, ob, key: str) -> tuple[str, ...]:
    value = prop(ob, key)
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise UserError(path, ob.name, f"{key} = {value!r}: expected a list of material names")
    return tuple(value)


def prop_bool(path: Path, ob, key: str) -> bool:
    value = prop(ob, key)
    if value is None:
        return False
    if isinstance(value, (bool, int)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise UserError(path, ob.name, f"{key} = {value!r}: expected true or false")


def world_matrix(path: Path, ob, depsgraph) -> np.ndarray:
    """The object's evaluated world matrix, (4, 4) float64."""
    m = np.array(ob.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise UserError(path, ob.name, "transform has NaN or infinite values")
    return m


def split_world(path: Path, ob, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """split_rigid of the object's world matrix; zero scale is the object's error."""
    try:
        return split_rigid(world)
    except ValueError:
        raise UserError(path, ob.name, "has zero scale") from None
