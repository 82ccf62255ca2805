"""`twin bench`: every benchmark, each guarded, into OUT/reports/bench.json and bench.html.

Sections run in an order where later ones reuse earlier results: the build section
leaves a complete build of the sample (peers and the LOD section read its packages).
A section that raises (a missing bench function, a missing tool, a failed build)
becomes {"ok": false, "error": ...} and the rest still run. Scratch work happens in a
temporary folder (TWIN_BENCH_KEEP=1 keeps it); only OUT/reports/ is written.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

from ..errors import UserError
from . import report, summary
from .context import Context
from .stats import machine


def _sections(results: dict):
    from . import blender_peer, builds, conductors, dataset, gazebo, gltf_transform, live, live_io, sections, viewer

    return [
        ("build", builds.build_section),
        ("scale", builds.scale_section),
        ("gazebo", gazebo.gazebo_section),
        ("viewer", viewer.viewer_section),
        ("lod", sections.lod_section),
        ("georef", sections.georef_section),
        ("conductors", conductors.conductor_section),
        ("runtime", sections.runtime_section),
        ("sun", lambda ctx: sections.sun_section(ctx, results.get("runtime", {}).get("data"))),
        ("render", sections.render_section),
        ("dataset", dataset.dataset_section),
        ("live", lambda ctx: live.live_section(ctx, results.get("dataset", {}).get("data"))),
        ("live_io", live_io.live_io_section),
        ("blender", blender_peer.blender_section),
        ("blender_reexport", blender_peer.reexport_section),
        ("gltf_transform", gltf_transform.gltf_transform_section),
    ]


def _say(msg: str) -> None:
    print(f"bench: {msg}", file=sys.stderr, flush=True)


def run_bench(sources: Path, out: Path, quick: bool = False, only: list[str] | None = None) -> Path:
    """Run the benchmarks on `sources`; returns the path of bench.html (bench.json beside it).
    `only`: names of the sections to run (default all)."""
    unknown = sorted(set(only or ()) - {name for name, _ in _sections({})})
    if unknown:
        raise UserError(str(sources), None, f"no bench section {', '.join(unknown)} (the sections: "
                        f"{', '.join(name for name, _ in _sections({}))})")
    sources, out = Path(sources).resolve(), Path(out)
    reports = out / "reports"
    reports.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="twin-bench-"))
    ctx = Context(sources=sources, out=out, work=work, quick=quick)
    results: dict = {}
    t_all = time.perf_counter()
    doc = {"schema": report.SCHEMA_ID, "quick": quick, "sources": str(sources), "machine": machine(),
           "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    try:
        for name, fn in _sections(results):
            if only and name not in only:
                continue
            _say(f"{name} ...")
            t0 = time.perf_counter()
            try:
                results[name] = {"ok": True, "data": fn(ctx)}
            except Exception as e:  # guarded: record and go on
                results[name] = {"ok": False, "error": f"{type(e).__name__}: {e}"[:2000],
                                 "trace": traceback.format_exc()[-3000:]}
            results[name]["seconds"] = time.perf_counter() - t0
            _say(f"{name} {'done' if results[name]['ok'] else 'FAILED: ' + results[name]['error'][:200]}"
                 f" in {results[name]['seconds']:.1f} s")
    finally:
        if not os.environ.get("TWIN_BENCH_KEEP"):
            shutil.rmtree(work, ignore_errors=True)
        else:
            _say(f"scratch kept in {work}")
    doc["sections"] = results
    doc["summary"] = summary.rows(results)
    doc["targets"] = [t for name in ("build", "scale") if results.get(name, {}).get("ok")
                      for t in results[name]["data"].get("targets", [])]
    doc["total_s"] = time.perf_counter() - t_all
    doc["machine"]["load_average_at_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    doc = report.clean(doc)
    report.write_json(doc, reports / "bench.json")
    report.write_html(doc, reports / "bench.html")
    return reports / "bench.html"
