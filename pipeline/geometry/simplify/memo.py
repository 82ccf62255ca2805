"""What a level's search leaves (`Level`), and how levels are kept between runs in a
memo the caller passes in (`Memo`): under the hash of everything a level depends on,
so a level the memo holds is not searched again."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ...digest import sha256_arrays, sha256_json


class Memo(Protocol):
    """Where results are kept between runs, by key (engine.memo.ArrayMemo): arrays
    in, the same arrays out, or None for a key it does not hold."""

    def get(self, key: str) -> dict[str, np.ndarray] | None: ...

    def put(self, key: str, arrays: dict[str, np.ndarray]) -> None: ...


@dataclass(frozen=True)
class Level:
    """What a level's search leaves for simplify_levels: the faces on the welded
    vertices (j, 3), the measured error and the checks' counts."""

    corners: np.ndarray
    error_m: float
    flipped: int
    non_manifold_added: int


def ceiling_after(levels: list[Level | None], faces: int) -> int:
    """The face count a level after `levels` must beat (search_levels' rule)."""
    for level in reversed(levels):
        if level is not None:
            return len(level.corners)
    return faces


class LevelKeys:
    """Memo keys of a mesh's levels: one hash of the searched mesh (its parts and its
    locked vertices, if any) and the search's settings, then per level its budget and
    its ceiling (known once the finer levels are)."""

    def __init__(self, welded: np.ndarray, welded_faces: np.ndarray, parts: np.ndarray | None, samples: int,
                 iterations: int, budgets, faces: int, locked: np.ndarray | None = None):
        # the parts too: the checks count each part's non-manifold edges apart
        arrays = (welded, welded_faces, parts) if locked is None else (welded, welded_faces, parts, locked)
        self.mesh = sha256_arrays(*arrays)
        self.search = (int(samples), int(iterations))
        self.budgets, self.faces = [float(b) for b in budgets], faces

    def next(self, levels: list[Level | None]) -> str:
        """The key of the level after `levels`."""
        budget = self.budgets[len(levels)]
        return sha256_json([self.mesh, self.search, repr(budget), ceiling_after(levels, self.faces)])


def level_arrays(level: Level | None) -> dict[str, np.ndarray]:
    """A level as the memo keeps it (None: the search found nothing coarser)."""
    if level is None:
        return {"found": np.zeros(1, dtype=np.bool_)}
    return {"found": np.ones(1, dtype=np.bool_), "corners": np.asarray(level.corners, dtype=np.int64),
            "error_m": np.array([level.error_m], dtype=np.float64),
            "counts": np.array([level.flipped, level.non_manifold_added], dtype=np.int64)}


def recall(memo: Memo, keys: LevelKeys, n_welded: int) -> list[Level | None]:
    """The leading levels the memo holds, in order; stops at the first it lacks (a
    damaged entry counts as lacking: it is searched again and replaced)."""
    levels: list[Level | None] = []
    while len(levels) < len(keys.budgets):
        arrays = memo.get(keys.next(levels))
        if arrays is None:
            break
        try:
            if not bool(arrays["found"][0]):
                levels.append(None)
                continue
            corners = arrays["corners"]
            if corners.dtype != np.int64 or corners.ndim != 2 or corners.shape[1] != 3 or not len(corners) \
                    or corners.min() < 0 or corners.max() >= n_welded:
                break
            flipped, added = (int(c) for c in arrays["counts"][:2])
            levels.append(Level(corners, float(arrays["error_m"][0]), flipped, added))
        except (TypeError, KeyError, IndexError, ValueError):
            break
    return levels
