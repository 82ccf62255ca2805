"""`twin bench`: what every stage costs beside the error it makes (DESIGN.md s.8).

run_bench(sources, out, quick=False) -> Path of OUT/reports/bench.html; the raw figures
are in bench.json beside it (schemas/bench.schema.json).
"""

from .harness import run_bench

__all__ = ["run_bench"]
