"""The level search: the coarsest simplification of one mesh that the judge passes,
per budget, each level no finer than the one before.

meshoptimizer is error-driven: its error target is scaled and vertices around misses
are locked, round after round (`search_meshopt`). The count-driven simplifiers bisect
on the triangle count (`search_count`). A mesh's levels are searched one after the
other, or side by side when the caller gives the search cores (`Parallelism`), each level
learning its ceiling from a shared board (`Board`) as the finer levels finish.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, TypeVar

import numpy as np

from .backends import fast, meshopt, pymeshlab
from .judge import Judge, Simplified

# A result keeping this share of the faces is no simplification: stop searching.
NO_GAIN = 0.95
# Points measured further than this share of the budget get their vertices locked.
LOCK_SHARE = 0.8
# More misses than this share of the measured points: lower the target, lock nothing.
WIDESPREAD = 0.02
# simplify+measure rounds per level at most, and the widest lock around one miss
ITERATIONS = 10
LOCK_NEIGHBOURS = 64

T = TypeVar("T")


def in_order(parts: list[Callable[[], T]]) -> list[T]:
    """[part() for part in parts], here, one after the other."""
    return [part() for part in parts]


@dataclass(frozen=True)
class Parallelism:
    """How the caller lets a search run its independent parts: `cores`, how many
    cores it may keep busy (1: one part after the other); `spread(parts)`, which
    returns [part() for part in parts] run as the caller sees fit (fork_join.spread forks
    a process per part). Parts share a `Board` by memory, so `spread` runs them
    forked or in threads, never in spawned processes. The results do not depend on it."""

    cores: int = 1
    spread: Callable[[list[Callable[[], T]]], list[T]] = in_order


def search_meshopt(judge: Judge, budget: float, iterations: int,
                   ceiling: Callable[[], int | None] = lambda: None,
                   locked: np.ndarray | None = None) -> tuple[Simplified | None, list[int]]:
    """Coarsest meshoptimizer result whose measurement is within budget (None if no
    round finds one), and the face count of every round's simplification.

    meshoptimizer's error is an area-weighted MEAN of squared distances to the planes
    around a vertex, so a vertex may slide off a narrow face (a bevel, a fin's rim, a
    shed's edge) at a cost the wide faces beside it average away: the measured
    Hausdorff distance runs far above the target there, and only there. So: simplify
    at the budget, measure, lock the original vertices around every point that
    misses (too far either way, a flipped face, a new non-manifold edge) and simplify
    again; each round keeps the reduction everywhere else. Every level starts with no
    lock: a finer level's trouble spots, locked for a coarser budget too, would keep
    far more faces than the coarser budget needs.

    `ceiling()`: the finer level's face count, None while it is not known. A round
    that does not beat it ends the search with nothing (later rounds only lock more or
    lower the target). The result is the same as searching without it and applying
    `under_ceiling` after, so a search side by side with the finer level's can learn
    it midway (`Board`) and stop as early as it would have one after the other.
    `locked: (n,) bool`: vertices locked from the first round (a piece's border)."""
    n = len(judge.faces)
    lock = np.zeros(len(judge.vertices), dtype=bool) if locked is None else locked.copy()
    s = budget
    rounds: list[int] = []
    widespread = np.zeros((0, 3))  # misses left unlocked while a lower target was tried
    for round_ in range(iterations):
        v, f = meshopt(judge.vertices, judge.faces, 0, s, lock)
        rounds.append(len(f))
        top = ceiling()
        if top is not None and len(f) >= top:
            return None, rounds
        if len(f) >= NO_GAIN * n:
            if len(widespread) == 0:
                break  # the mesh is as simple as this error allows: nothing to gain
            # a lower target gained nothing either (a wire mesh in one plane: its
            # quadrics see no error, so it goes all or nothing): lock the misses instead
            lock[judge.near_vertices(widespread, 4)] = True
            widespread, s = np.zeros((0, 3)), budget
            continue
        measured = judge.measure(v, f, np.arange(len(v)), budget, threshold=LOCK_SHARE * budget)
        r, where = measured.result, measured.misses
        if r.valid and r.error_m <= budget:
            # the first pass is the coarsest: later rounds only lock more vertices or
            # lower the target, and both keep more faces
            return r, rounds
        if not np.isfinite(r.error_m):  # everything collapsed away
            s /= 4.0
            continue
        if len(where) > WIDESPREAD * len(judge.queries):
            # misses everywhere (a smooth surface): the target itself is too coarse;
            # lock only around what went badly wrong (a small part collapsed away).
            # When that too is everywhere (the whole mesh collapsed), a lock would
            # freeze most of the mesh at full detail: the lower target alone
            s /= 2.0
            widespread = where
            where = where[measured.how_far > 2.0 * budget]
            if len(where) == 0 or len(where) > WIDESPREAD * len(judge.queries):
                continue
        new = lock_around(judge, lock, where, round_)
        if len(new) == 0 or lock[new].all():
            break
        lock[new] = True
    return None, rounds


def lock_around(judge: Judge, lock: np.ndarray, where: np.ndarray, round_: int) -> np.ndarray:
    """The original vertices to lock around the misses `where: (p, 3)`. Around a miss
    whose nearest vertex a lock already holds, a neighbourhood doubling each round (4,
    8, 16, ... up to LOCK_NEIGHBOURS); around one where nothing is locked yet, one
    doubling every third round. Widening around every miss by the round would freeze
    fresh misses' whole neighbourhoods; the same 4 in every round would leave slow
    searches out of rounds before they converge."""
    if len(where) == 0:
        return np.zeros(0, dtype=np.int64)
    again = lock[judge.nearest_vertex(where)]
    return np.union1d(judge.near_vertices(where[~again], min(4 << (round_ // 3), LOCK_NEIGHBOURS)),
                      judge.near_vertices(where[again], min(4 << round_, LOCK_NEIGHBOURS)))


def beats(found: int | None, top: int, ceiling: int) -> bool:
    """Whether a search that found `found` faces (None: nothing), its largest round
    having `top`, gives a level under `ceiling`: the one rule of `search_levels`
    and the board (a round at or over the ceiling would have ended the search)."""
    return found is not None and top < ceiling and found < ceiling


def under_ceiling(best: Simplified | None, rounds: list[int], ceiling: int) -> Simplified | None:
    """A search's result as `ceiling` would have cut it short (see search_meshopt)."""
    found = None if best is None else len(best.faces)
    return best if beats(found, max(rounds, default=0), ceiling) else None


def search_levels(judge: Judge, budgets, iterations: int, faces: int, locked: np.ndarray | None = None,
                  workers: Parallelism = Parallelism()) -> list[Simplified | None]:
    """Each budget's search result (ascending budgets; None: no coarser mesh than the
    finer level's, whose face count is the ceiling). Alone, the levels are searched
    one after the other, each stopping at its ceiling; with more than one core of
    `workers`, side by side, each learning its ceiling from the board as soon as the
    finer levels are done, and the ceilings applied again after. The results are the
    same. `locked`: see search_meshopt."""
    searched = [i for i, b in enumerate(budgets) if b > 0]
    outcomes: dict[int, tuple[Simplified | None, list[int]]] = {i: (None, []) for i, b in enumerate(budgets) if b <= 0}
    if len(searched) > 1 and workers.cores > 1:
        board = Board(len(budgets), faces)
        for i, outcome in outcomes.items():
            board.publish(i, *outcome)  # no budget, no search: it passes its ceiling on

        def search(i: int):
            outcome = search_meshopt(judge, budgets[i], iterations, lambda: board.ceiling(i), locked)
            board.publish(i, *outcome)
            return outcome

        # every level a part of its own, more parts than cores: a level that waits on
        # nothing keeps a core busy, where the coarser levels would queue behind each
        # other one after the other in one part; a coarser level that cannot beat a
        # finer one still learns so at the finer one's end
        outcomes.update(zip(searched, workers.spread([lambda i=i: search(i) for i in searched])))
    out, ceiling = [], faces
    for i, budget in enumerate(budgets):
        outcome = outcomes[i] if i in outcomes else search_meshopt(judge, budget, iterations, lambda: ceiling, locked)
        best = under_ceiling(*outcome, ceiling)
        if best is not None:
            ceiling = len(best.faces)
        out.append(best)
    return out


class Board:
    """The levels' search outcomes as they finish, in memory shared with the forked
    processes searching the others. One int64 per level, UNFINISHED until published,
    then (largest round's face count << 32) | (result's face count + 1, 0 for none):
    one aligned word, so a reader never sees half an outcome."""

    UNFINISHED = -1

    def __init__(self, levels: int, faces: int):
        import mmap

        self.faces = faces
        self._memory = mmap.mmap(-1, 8 * levels)  # anonymous and shared: forks see one board
        self.table = np.frombuffer(self._memory, dtype=np.int64)
        self.table[:] = self.UNFINISHED

    def publish(self, level: int, best: Simplified | None, rounds: list[int]) -> None:
        found = 0 if best is None else len(best.faces) + 1
        self.table[level] = (max(rounds, default=0) << 32) | found

    def ceiling(self, level: int) -> int | None:
        """Level `level`'s ceiling as `search_levels` will apply it, None while a finer
        searched level is unfinished."""
        ceiling = self.faces
        for word in self.table[:level].tolist():
            if word == self.UNFINISHED:
                return None
            top, found = word >> 32, (word & 0xFFFFFFFF) - 1
            if beats(found if found >= 0 else None, top, ceiling):
                ceiling = found
        return ceiling


def search_count(judge: Judge, budget: float, iterations: int, method: str) -> Simplified | None:
    """Smallest triangle count (bisected in log space) whose result measures within budget."""
    run = pymeshlab if method == "pymeshlab" else fast
    best, lo, hi = None, 4, len(judge.faces)  # lo: too coarse (or unknown); hi: acceptable
    target = max(4, len(judge.faces) // 10)
    for _ in range(iterations):
        v, f = run(judge.vertices, judge.faces, target)
        r = judge(v, f, None, budget)
        if r.valid and r.error_m <= budget:
            if best is None or len(r.faces) < len(best.faces):
                best = r
            hi = target
        else:
            lo = target
        if hi <= lo * 1.15:
            break
        target = int(round(math.sqrt(lo * hi)))
    return best
