"""Timing and description helpers shared by every bench section.

Every timing the bench reports is a dict {median_s, min_s, max_s, repeats}: a median
over repeats says what to expect, min and max say how much the shared machine moved
it. Repeat counts adapt to a time budget so one slow stage cannot blow the 20-minute
budget of `make bench` on a 2-core machine.
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
from typing import Callable


def summarize(samples: list[float]) -> dict:
    """{median_s, min_s, max_s, repeats} of a list of durations in seconds."""
    return {"median_s": float(statistics.median(samples)), "min_s": float(min(samples)),
            "max_s": float(max(samples)), "repeats": len(samples)}


def summarize_values(samples: list[float], unit: str) -> dict:
    """Same shape for a non-time quantity (bytes, kB): {median, min, max, repeats, unit}."""
    return {"median": float(statistics.median(samples)), "min": float(min(samples)),
            "max": float(max(samples)), "repeats": len(samples), "unit": unit}


def repeat(fn: Callable[[int], float | None], min_repeats: int, max_repeats: int, budget_s: float) -> list:
    """Call fn(i) at least min_repeats and at most max_repeats times, stopping once the
    calls together took budget_s. fn returns its own measured duration (so setup work
    such as editing a file is not counted) or None to use the wall time of the call.
    Returns the list of durations."""
    out, spent = [], 0.0
    for i in range(max_repeats):
        if i >= min_repeats and spent >= budget_s:
            break
        t0 = time.perf_counter()
        got = fn(i)
        wall = time.perf_counter() - t0
        spent += wall
        out.append(wall if got is None else float(got))
    return out


def timed(fn: Callable[[], object], repeats: int) -> dict:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return summarize(samples)


def _cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_bytes() -> int | None:
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _version(dist: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def machine() -> dict:
    """What the figures were measured on (they mean nothing without it)."""
    libs = ("numpy", "scipy", "trimesh", "pymeshlab", "meshoptimizer", "fast_simplification", "pyproj",
            "usd-core", "bpy", "astral", "matplotlib", "ezdxf")
    return {
        "cpu_model": _cpu_model(),
        "logical_cores": os.cpu_count(),
        "usable_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "memory_bytes": _memory_bytes(),
        "os": platform.platform(),
        "python": sys.version.split()[0],
        "libraries": {name: _version(name) for name in libs},
        "load_average_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
