"""STEP to triangles through cascadio (OpenCASCADE), in a child process, guarded.

OpenCASCADE crashes (SIGSEGV) instead of raising when an allocation is refused, so
it never runs in the build's own process: a child runs it under the same memory
limit (RLIMIT_AS is inherited) and its death becomes an error naming the asset.

cascadio's `tol_linear` is in millimetres whatever the file's unit (OpenCASCADE
converts every length context to its own millimetres on reading, then writes metres),
so a tolerance in metres goes in times 1000.

Before tessellating at the asked tolerance the child makes a coarse pass (tolerance
relative to each edge's size, so it costs the same in any unit) and estimates from it
the triangles the asked one makes. Per B-rep face (cascadio's face indices):
- the coarse pass's deflection is REL_TOL times the face's size, and the deflection
  under which the angular tolerance stops ruling is R (1 - cos(ANG/2)), R the face's
  radius of curvature (1 / the median dihedral angle per centroid distance of its
  curved edges); below the smaller of the two, triangles grow as the tolerance
  shrinks;
- faces whose normals lie on a plane or a cone (planes, cylinders, cones, extrusions)
  grow as 1/sqrt(tolerance) (only their curved direction is divided), the others
  (spheres, tori, free-form) as 1/tolerance.
The laws are upper ones (the angular floor and ruled directions only slow growth),
so the estimate errs above the count and a refusal is never a close call.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.edges import edge_keys

ANG_TOL_RAD = 0.5
REL_TOL = 0.05
# a face whose normals' spread off their best plane is under this share of the spread
# in it is ruled (a B-spline cylinder's normals leave their plane a little)
RULED_SPREAD = 0.05
MIN_CURVED_RAD = 1e-6


@dataclass(frozen=True)
class Face:
    """One B-rep face of the coarse pass: triangles (times its instances), the
    deflection in metres below which it grows, and how ("sqrt" or "linear")."""

    triangles: int
    onset_m: float
    law: str


def _edge_pairs(tris: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """(a, b): triangles sharing an edge, one pair per interior edge."""
    owner = np.repeat(np.arange(len(tris)), 3)
    key = edge_keys(tris, n_vertices)
    order = np.argsort(key, kind="stable")
    same = np.nonzero(key[order][1:] == key[order][:-1])[0]
    return owner[order[same]], owner[order[same + 1]]


def face_growth(vertices: np.ndarray, tris: np.ndarray, instances: int) -> Face:
    """vertices: (n, 3) float64 metres; tris: (m, 3) int64 of one face."""
    corners = vertices[tris]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(normals, axis=1)
    ok = area > 0
    size = float(np.ptp(corners.reshape(-1, 3), axis=0).max()) if len(tris) else 0.0
    coarse = REL_TOL * size
    if ok.sum() < 3:
        return Face(len(tris) * instances, coarse, "sqrt")
    n = normals[ok] / area[ok, None]
    w = area[ok] / area[ok].sum()
    spread = np.linalg.svd((n - w @ n) * np.sqrt(w)[:, None], compute_uv=False)
    law = "sqrt" if spread[2] <= RULED_SPREAD * spread[1] + 1e-12 else "linear"
    a, b = _edge_pairs(tris[ok], len(vertices))
    onset = coarse
    if len(a):
        angle = np.arccos(np.clip(np.einsum("ij,ij->i", n[a], n[b]), -1.0, 1.0))
        centres = corners[ok].mean(axis=1)
        gap = np.linalg.norm(centres[a] - centres[b], axis=1)
        curved = (gap > 0) & (angle > MIN_CURVED_RAD)
        if curved.any():
            radius = 1.0 / float(np.median(angle[curved] / gap[curved]))
            onset = min(coarse, radius * (1.0 - np.cos(ANG_TOL_RAD / 2)))
    return Face(len(tris) * instances, onset, law)


def coarse_faces(glb: Path) -> list[Face]:
    """Every B-rep face of cascadio's coarse GLB (written with include_brep)."""
    from .gltf_file import read

    g = read(glb)
    uses: dict[int, int] = {}
    for node in g.header.get("nodes", []):
        if "mesh" in node:
            uses[node["mesh"]] = uses.get(node["mesh"], 0) + 1
    faces = []
    for index, mesh in enumerate(g.header.get("meshes", [])):
        for prim in mesh.get("primitives", []):
            vertices = g.accessor(prim["attributes"]["POSITION"])
            tris = g.accessor(prim["indices"]).reshape(-1, 3)
            brep = prim.get("extensions", {}).get("TM_brep_faces")
            ids = g.accessor(brep["faceIndices"]).ravel() if brep else np.zeros(len(tris), dtype=np.int64)
            for face in np.unique(ids):
                faces.append(face_growth(vertices, tris[ids == face], uses.get(index, 1)))
    return faces


def estimate(faces: list[Face], tolerance_m: float) -> float:
    """Triangles a tessellation at `tolerance_m` makes, from the coarse faces."""
    total = 0.0
    for f in faces:
        ratio = max(1.0, f.onset_m / tolerance_m)
        total += f.triangles * (np.sqrt(ratio) if f.law == "sqrt" else ratio)
    return total


def fitting_tolerance(faces: list[Face], max_triangles: int) -> float | None:
    """The finest tolerance (m) estimated to stay within `max_triangles`, or None
    when none does (the coarse faces alone are too many)."""
    if estimate(faces, float("inf")) > max_triangles:
        return None
    lo, hi = 1e-12, max((f.onset_m for f in faces), default=1.0) + 1e-12
    for _ in range(200):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if estimate(faces, mid) > max_triangles else (lo, mid)
        if hi / lo < 1.001:
            break
    return float(hi)


# --- the child ------------------------------------------------------------------------


def _child(job: dict) -> dict:
    import cascadio

    work = Path(job["work"])
    coarse = work / "coarse.glb"
    status = cascadio.step_to_glb(job["source"], str(coarse), tol_linear=REL_TOL, tol_angular=ANG_TOL_RAD,
                                  tol_relative=True, include_brep=True)
    if status != 0 or not coarse.is_file() or coarse.stat().st_size == 0:
        return {"empty": True}
    faces = coarse_faces(coarse)
    coarse.unlink()
    guess = estimate(faces, job["tolerance_m"])
    if guess > job["max_triangles"]:
        return {"refused": True, "estimate": guess, "fits_m": fitting_tolerance(faces, job["max_triangles"])}
    status = cascadio.step_to_glb(job["source"], job["out"], tol_linear=job["tolerance_m"] * 1000.0,
                                  tol_angular=ANG_TOL_RAD)
    out = Path(job["out"])
    if status != 0 or not out.is_file() or out.stat().st_size == 0:
        return {"empty": True}
    return {"estimate": guess}


def main(argv: list[str]) -> int:
    job = json.loads(argv[0])
    try:
        result = _child(job)
    except MemoryError:
        result = {"memory": True}
    Path(job["report"]).write_text(json.dumps(result))
    return 0


# --- the parent -----------------------------------------------------------------------


def memory_limit() -> int | None:
    """This process's address-space limit in bytes (the build's, in a worker), or None."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else soft


def run(source: Path, out: Path, tolerance_m: float, max_triangles: int) -> dict:
    """Tessellate `source` into the GLB `out` in a child process. Returns the child's
    report: {"estimate": n} when it tessellated; {"refused": True, "estimate": n,
    "fits_m": tolerance or None}; {"empty": True}; {"memory": True}; or {"died": signal
    name} / {"failed": its last words} when the child did not finish."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
    with tempfile.TemporaryDirectory() as work:
        report = Path(work) / "report.json"
        job = {"source": str(source), "out": str(out), "tolerance_m": float(tolerance_m),
               "max_triangles": int(max_triangles), "work": work, "report": str(report)}
        proc = subprocess.run([sys.executable, "-m", "pipeline.ingest.tessellate", json.dumps(job)],
                              env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        if proc.returncode < 0:
            return {"died": signal.Signals(-proc.returncode).name}
        if proc.returncode != 0 or not report.is_file():
            words = proc.stderr.decode("utf-8", "replace").strip().splitlines()
            return {"memory": True} if words and words[-1].startswith("MemoryError") else \
                {"failed": words[-1] if words else f"exit status {proc.returncode}"}
        return json.loads(report.read_text())


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
