"""The simplifiers side by side at matched triangle counts: each run in a child
process (`python -m pipeline.bench.simplifiers METHOD IN OUT TARGET`), so a
simplifier that crashes kills only its child, measured with the LOD search's judge."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .. import ir
from ..geometry import clean as _clean
from ..geometry.simplify import MEASURE_SAMPLES, METHODS, Judge, simplify_to_count
from .meshes import insulator_mesh, noisy_sphere, sliver_mesh


def _isolated(method: str, v: np.ndarray, f: np.ndarray, target: int, timeout: float) -> dict:
    """Run one simplification in a child process (a crash kills only the child)."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, v=v, f=f)
        cmd = [sys.executable, "-m", "pipeline.bench.simplifiers", method, str(src), str(dst), str(target)]
        try:
            proc = subprocess.run(cmd, capture_output=True, timeout=timeout, text=True)
        except subprocess.TimeoutExpired:
            return {"crashed": True, "why": f"timeout after {timeout} s"}
        if proc.returncode != 0 or not dst.exists():
            return {"crashed": True, "why": f"exit {proc.returncode}: {proc.stderr.strip()[-200:]}"}
        out = np.load(dst)
        return {"crashed": False, "v": out["v"], "f": out["f"], "seconds": float(out["seconds"])}


def bench_simplifiers(meshes: dict | None = None, ratios=(0.1, 0.02), methods=METHODS, timeout: float = 300.0) -> dict:
    """Each simplifier on each mesh at matched triangle counts (ratios of the input).

    meshes: {name: (vertices (n, 3), faces (m, 3))}; default: insulator (200k faces),
    noisy sphere (82k), slivers. Every run is in a child process. Returns
    {"runs": [{mesh, method, ratio, triangles, seconds, triangles_per_s, error_m,
    flipped, non_manifold_added, crashed}], "summary": {...per method vs pymeshlab}}.
    """
    if meshes is None:
        meshes = {"insulator": insulator_mesh(), "noisy_sphere": noisy_sphere(), "slivers": sliver_mesh()}
    runs = []
    for name, (v0, f0) in meshes.items():
        m = _clean.clean_mesh(ir.Mesh(v0, f0))
        v, f = m.vertices, np.asarray(m.faces, dtype=np.int64)
        local, _ = _clean.centred(v)
        judge = Judge(local, f, MEASURE_SAMPLES)
        for ratio in ratios:
            target = max(4, int(len(f) * ratio))
            for method in methods:
                r = _isolated(method, v, f, target, timeout)
                row = {"mesh": name, "method": method, "ratio": ratio, "input_triangles": int(len(f)),
                       "target_triangles": target, "crashed": r["crashed"]}
                if r["crashed"]:
                    row["why"] = r["why"]
                else:
                    sv, sf = r["v"] - _clean.centred(v)[1], r["f"]
                    s = judge(sv, sf, None, 0.0)
                    row.update(triangles=int(len(sf)), seconds=r["seconds"],
                               triangles_per_s=float(len(f) / max(r["seconds"], 1e-9)), error_m=s.error_m,
                               flipped=s.flipped, non_manifold_added=s.non_manifold_added)
                runs.append(row)
    return {"runs": runs, "summary": _summary(runs)}


def _summary(runs: list[dict]) -> dict:
    """Per method: median error ratio and speed-up against pymeshlab at matched counts."""
    ref = {(r["mesh"], r["ratio"]): r for r in runs if r["method"] == "pymeshlab" and not r["crashed"]}
    out = {}
    for method in sorted({r["method"] for r in runs}):
        err, speed, crashes = [], [], 0
        for r in runs:
            if r["method"] != method:
                continue
            crashes += r["crashed"]
            p = ref.get((r["mesh"], r["ratio"]))
            if r["crashed"] or p is None:
                continue
            err.append(r["error_m"] / max(p["error_m"], 1e-12))
            speed.append(p["seconds"] / max(r["seconds"], 1e-9))
        out[method] = {"median_error_vs_pymeshlab": float(np.median(err)) if err else None,
                       "median_speedup_vs_pymeshlab": float(np.median(speed)) if speed else None,
                       "crashes": int(crashes)}
    return out


def _child(method: str, src: str, dst: str, target: str) -> None:
    data = np.load(src)
    t0 = time.perf_counter()
    v, f = simplify_to_count(data["v"], data["f"], int(target), method)
    seconds = time.perf_counter() - t0
    np.savez(dst, v=v, f=f, seconds=seconds)


if __name__ == "__main__":
    if len(sys.argv) == 5:
        _child(*sys.argv[1:])
    else:
        print(json.dumps(bench_simplifiers(), indent=1, default=float))
