"""Error-bounded mesh simplification.

A LOD level has a budget in metres; it gets the coarsest mesh this package can find
whose MEASURED two-sided Hausdorff distance to the authored mesh (metrics.hausdorff)
is within the budget, that flips no face and adds no non-manifold edge. Each level is
simplified from the authored mesh, never from the previous level, so errors do not
accumulate. Vertices are simplified relative to their bounding-box centre
(meshoptimizer works in float32: 10^7 m coordinates would otherwise lose everything
below a metre).

Modules, each using only those before it:
  backends  the raw simplifiers (meshoptimizer, with a ctypes call for vertex locks;
            pymeshlab; fast_simplification)
  judge     a candidate measured against the original: error, flips, added edges
  search    the level search (rounds of simplify, measure, lock) and its side-by-side
            form (`Parallelism`, `Board`)
  memo      what a level's search leaves and its keys in a caller's memo
  pieces    splitting a large mesh into pieces and joining their levels
  levels    simplify_levels: all of the above for one mesh

It knows `ir`, numpy, scipy and the rest of `geometry`: how parts run side by side (`Parallelism`) and
the memo (`Memo`) come from the caller.
"""

from .backends import METHODS, simplify_to_count
from .judge import MEASURE_SAMPLES, Judge, Simplified, flipped_face_count
from .levels import simplify, simplify_checked, simplify_levels
from .memo import Memo
from .search import ITERATIONS, Parallelism

__all__ = ["ITERATIONS", "MEASURE_SAMPLES", "METHODS", "Judge", "Memo", "Parallelism", "Simplified", "flipped_face_count",
           "simplify", "simplify_checked", "simplify_levels", "simplify_to_count"]
