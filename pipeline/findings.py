"""Findings: the records every check returns, the one table of their codes (`RULES`),
and the rules judged on one mesh (GEOM001-007, 011, 012).

Codes are stable (tests, CI filters and reports key on them): a check names a code
and `finding` takes its severity from the table. Who makes them:
- geometry (GEOM0xx) and hierarchy (HIER0xx) on an `ir.Asset`: validate.checks, with
  the mesh rules here (`mesh_findings`); the LOD step compares a visual's levels by
  `visual_verdict`, which the geometry task hands it (geometry imports no checks);
- placement (PLACE00x): scene.checks, during the scene build;
- gazebo (GZ0xx): validate.gazebo, from what Gazebo's own loaders read;
- package (PKG0xx): validate.checks on a built package folder.

This module stands on `ir`, numpy, scipy and geometry's edge keys: validate, scene and
the builder stand on it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Iterable, Literal

import numpy as np

from . import ir
from .geometry.edges import directed_edges, edge_keys

Severity = Literal["error", "warning", "info"]

# code -> (severity, group, description). Never renumber: reports and CI filters use them.
RULES: dict[str, tuple[str, str, str]] = {
    "GEOM001": ("error", "geometry", "non-finite value (NaN or inf) in vertices, normals, UVs, shape keys or poses"),
    "GEOM002": ("warning", "geometry", "degenerate face (repeated vertex or zero area)"),
    "GEOM003": ("warning", "geometry", "non-manifold edge (shared by more than two faces)"),
    "GEOM004": ("warning", "geometry", "inconsistent winding (an edge traversed twice in the same direction)"),
    "GEOM005": ("error", "geometry", "inward normals (closed part with negative signed volume)"),
    "GEOM006": ("error", "geometry", "open collision hull (collision mesh not closed)"),
    "GEOM007": ("error", "geometry", "zero volume (closed part that encloses nothing)"),
    "GEOM008": ("warning", "geometry", "triangle budget exceeded (LOD0 triangles over asset.toml triangle_budget)"),
    "GEOM009": ("warning", "geometry", "LOD error over budget (measured Hausdorff error above the LOD's budget)"),
    "GEOM010": ("error", "geometry", "size betrays a unit mistake (asset bounds under 1 cm or over 200 m)"),
    "GEOM011": ("error", "geometry", "empty mesh (no triangles)"),
    "GEOM012": ("error", "geometry", "face index out of range"),
    "HIER001": ("error", "hierarchy", "not exactly one root link"),
    "HIER002": ("error", "hierarchy", "the joints do not form a tree (a cycle or a closed kinematic loop)"),
    "HIER003": ("error", "hierarchy", "a link unreachable from the root (a joint names a missing link)"),
    "HIER004": ("error", "hierarchy", "duplicate name (after safe_name) among links and joints, visuals, or collisions"),
    "HIER005": ("warning", "hierarchy", "name is not an identifier (writers rename it with safe_name)"),
    "HIER006": ("error", "hierarchy", "zero, near-zero or non-finite joint axis"),
    "HIER007": ("error", "hierarchy", "joint lower limit above upper limit"),
    "HIER008": ("warning", "hierarchy", "joint pivot far outside its child link's bounds"),
    "HIER009": ("error", "hierarchy", "state binding to a missing visual, shape key or material"),
    "HIER010": ("error", "hierarchy", "state binding with an empty or non-finite domain"),
    "HIER011": ("error", "hierarchy", "material binding thresholds do not match its materials"),
    "HIER012": ("error", "hierarchy", "path-like name (/, \\, .. or :) that could leave an output folder"),
    "HIER013": ("warning", "hierarchy", "the source holds what the model does not carry (armature, animation, "
                                        "morph targets, a newer file version): the reader says how it read the rest"),
    "PLACE001": ("error", "placement", "INSERT of an unknown asset block"),
    "PLACE002": ("error", "placement", "duplicate TAG"),
    "PLACE003": ("warning", "placement", "placement outside every platform of its level (on a slope or natural "
                                         "ground: PLACE005 still checks that it stands on the terrain)"),
    "PLACE004": ("warning", "placement", "footprints overlap beyond tolerance"),
    "PLACE005": ("error", "placement", "base not on the terrain (over 1 cm)"),
    "WIRE001": ("warning", "conductor", "conductor nearer the ground than its voltage level's clearance at maximum temperature"),
    "WIRE002": ("warning", "conductor", "conductors of different electrical nodes nearer than the phase-to-phase clearance "
                                        "at maximum temperature"),
    "WIRE003": ("warning", "conductor", "conductor sag beyond the clearance table's limit at maximum temperature"),
    "PKG001": ("error", "package", "XML file not well-formed"),
    "PKG002": ("error", "package", "a referenced file (mesh URI, manifest output, model.sdf) is missing"),
    "PKG003": ("error", "package", "a URI or path that leaves its package"),
    "PKG004": ("error", "package", "manifest hash does not match the file"),
    "PKG005": ("error", "package", "XML declares a DOCTYPE (entities are refused, never resolved)"),
    "PKG006": ("error", "package", "manifest.json missing or unreadable"),
    "GZ001": ("error", "gazebo", "Gazebo's mesh loader crashed or failed on the file"),
    "GZ002": ("error", "gazebo", "Gazebo reads a different number of triangles than the file holds"),
    "GZ003": ("error", "gazebo", "Gazebo's triangle corners (vertex positions) are not the file's"),
    "GZ004": ("error", "gazebo", "Gazebo's mesh bounds differ from the file's"),
    "GZ005": ("error", "gazebo", "Gazebo's normals or texture coordinates differ from the file's"),
    "GZ006": ("error", "gazebo", "a model's visual bounds in Gazebo differ from its manifest's"),
    "GZ007": ("error", "gazebo", "sdformat reports an error loading the world as Gazebo's server does"),
    "GZ008": ("warning", "gazebo", "the world costs sdformat more memory to parse than the budget (1.5 GB)"),
    "GZ009": ("error", "gazebo", "a mesh the world references was not loaded by the probe (missing or unresolved)"),
    "GZ010": ("error", "gazebo", "the COLLADA file's triangles cannot be read (a missing source or a malformed index list)"),
    "GZ011": ("error", "gazebo", "dartsim cannot build the world as gz-sim's Physics system does"),
    "GZ012": ("warning", "gazebo", "the switches are drawn at rest: their moving parts would take the world over "
                                   "sdformat's parse budget ([gazebo] moving_parts = \"auto\")"),
}

# Tolerances, relative to the size of the thing measured so that millimetre parts and
# 50 m busbars are judged alike.
DEGENERATE_AREA_REL = 1e-12   # face area / bbox diagonal^2
ZERO_VOLUME_REL = 1e-6        # |volume| / part bbox diagonal^3


@dataclass(frozen=True, order=True)
class Finding:
    """One problem. site: "asset/link/visual" style path, or a TAG for placements."""

    code: str
    severity: Severity
    site: str
    message: str

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Finding":
        return cls(str(d["code"]), str(d["severity"]), str(d["site"]), str(d["message"]))


def finding(code: str, site: str, message: str) -> Finding:
    """A finding whose severity comes from the rule table (one source of truth)."""
    return Finding(code, RULES[code][0], site, message)


def sort_findings(findings: Iterable[Finding]) -> list[Finding]:
    return sorted(set(findings), key=lambda f: (f.site, f.code, f.message))


def as_dicts(findings: Iterable[Finding]) -> list[dict]:
    return [f.as_dict() for f in sort_findings(findings)]


def finite(*arrays) -> bool:
    """Every value of every array (None: no array) is finite."""
    return all(a is None or bool(np.isfinite(np.asarray(a, dtype=np.float64)).all()) for a in arrays)


# --- the rules of one mesh ------------------------------------------------------------


def _components(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """(m,) int component label of each face; faces sharing a vertex are connected."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = np.concatenate([faces[:, 0], faces[:, 1]])
    b = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return labels[faces[:, 0]]


def _edge_uses(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For faces `f: (m, 3)` on welded vertices with no repeated corner: each directed
    edge's undirected edge id (3m,) (in geometry.edges' order: face k's at 3k..3k+2),
    and per undirected edge the faces using it and how many of them run it from its
    lower to its higher vertex."""
    directed = directed_edges(f)
    keys, edge_id, uses = np.unique(edge_keys(f, int(f.max()) + 1), return_inverse=True, return_counts=True)
    edge_id = edge_id.reshape(-1)
    forward = np.bincount(edge_id, weights=(directed[:, 0] < directed[:, 1]).astype(float), minlength=len(keys))
    return edge_id, uses, forward


def _edge_defects(uses: np.ndarray, forward: np.ndarray) -> tuple[int, int]:
    """(non-manifold edges, edges run twice the same way): GEOM003 and GEOM004 counts.
    A manifold edge of a consistently wound surface is used once in each direction."""
    return int((uses > 2).sum()), int(((uses == 2) & (forward != 1)).sum())


def edge_defect_counts(mesh: ir.Mesh) -> tuple[int, int]:
    """(non-manifold edges, inconsistently wound edges) of a finite mesh, judged on
    positions welded exactly as `mesh_findings` judges them."""
    if len(mesh.faces) == 0:
        return 0, 0
    _, weld = np.unique(mesh.vertices, axis=0, return_inverse=True)
    f = weld.reshape(-1)[mesh.faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    if len(f) == 0:
        return 0, 0
    _, uses, forward = _edge_uses(f)
    return _edge_defects(uses, forward)


def mesh_findings(mesh: ir.Mesh, site: str, *, collision: bool = False, memo=None) -> list[Finding]:
    """Geometry checks of one mesh. Topology is judged on positions welded exactly, as
    an STL's triangle soup means it (unwelded facets are not holes).

    `memo` (engine.memo.ArrayMemo, under this module's code version): the findings of
    a mesh checked before, by its content, so the geometry task's per-part checks and
    the package's checks of the same meshes run once; what comes back is what the
    check finds. Every mesh is kept: a look-up costs less than checking even a small
    part."""
    if memo is None:
        return _mesh_findings(mesh, site, collision)
    key = f"{mesh.digest}:{'collision' if collision else 'visual'}"
    kept = memo.get(key)
    if kept is not None:
        try:
            return [finding(str(code), site, str(message))
                    for code, message in zip(kept["codes"].tolist(), kept["messages"].tolist(), strict=True)]
        except (KeyError, ValueError, TypeError, AttributeError):
            pass  # a damaged entry: checked again below, and replaced
    found = _mesh_findings(mesh, site, collision)
    memo.put(key, {"codes": np.array([f.code for f in found], dtype=np.str_),
                   "messages": np.array([f.message for f in found], dtype=np.str_)})
    return found


def visual_verdict(mesh: ir.Mesh, memo=None) -> tuple[frozenset[str], tuple[int, int]]:
    """What the checks hold against one visual's mesh on its own, as the LOD step
    compares a coarser level with the finer one (geometry.lod.Verdict): its error
    codes, and its (non-manifold, inconsistently wound) edge counts when it has either
    finding, else (0, 0). `memo`: see mesh_findings."""
    found = mesh_findings(mesh, "", memo=memo)
    errors = frozenset(f.code for f in found if f.severity == "error")
    edges = edge_defect_counts(mesh) if any(f.code in ("GEOM003", "GEOM004") for f in found) else (0, 0)
    return errors, edges


def _mesh_findings(mesh: ir.Mesh, site: str, collision: bool) -> list[Finding]:
    verts, faces = mesh.vertices, mesh.faces
    if len(faces) == 0 or len(verts) == 0:
        return [finding("GEOM011", site, "mesh has no triangles")]
    keys = [k.vertices for k in mesh.shape_keys]
    if not finite(verts, mesh.normals, mesh.uvs, *keys):
        bad = int((~np.isfinite(verts)).any(axis=1).sum())
        return [finding("GEOM001", site, f"{bad} of {len(verts)} vertices (or normals/UVs/shape keys) are NaN or inf")]
    if faces.min() < 0 or faces.max() >= len(verts):
        bad = int(((faces < 0) | (faces >= len(verts))).any(axis=1).sum())
        return [finding("GEOM012", site, f"{bad} faces index vertices outside 0..{len(verts) - 1}")]

    out: list[Finding] = []
    _, weld = np.unique(verts, axis=0, return_inverse=True)
    f = weld.reshape(-1)[faces]
    p = verts[faces]
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    diag = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0))) or 1.0
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    degenerate = repeated | (0.5 * area2 <= DEGENERATE_AREA_REL * diag * diag)
    if degenerate.any():
        out.append(finding("GEOM002", site, f"{int(degenerate.sum())} of {len(faces)} faces are degenerate"))

    f = f[~repeated]  # a face with a repeated vertex has no edges to speak of
    if len(f) == 0:
        return out
    edge_id, uses, forward = _edge_uses(f)
    nonmanifold, flipped = _edge_defects(uses, forward)
    if nonmanifold:
        out.append(finding("GEOM003", site, f"{nonmanifold} edges are shared by more than two faces"))
    if flipped:
        out.append(finding("GEOM004", site, f"{flipped} edges are traversed twice in the same direction"))

    labels = _components(int(weld.max()) + 1, f)
    # A part is the faces of one connected component; all faces on an edge share one.
    parts = int(labels.max()) + 1
    part_of_edge = np.zeros(len(uses), dtype=np.int64)
    part_of_edge[edge_id] = np.repeat(labels, 3)
    in_part = np.bincount(labels, minlength=parts) > 0
    closed = np.bincount(part_of_edge, weights=(uses != 2), minlength=parts) == 0
    consistent = np.bincount(part_of_edge, weights=(forward != 1), minlength=parts) == 0
    pf = p[~repeated]
    volumes = np.bincount(labels, weights=np.einsum("ij,ij->i", pf[:, 0], np.cross(pf[:, 1], pf[:, 2])),
                          minlength=parts) / 6.0
    lo = np.full((parts, 3), np.inf)
    hi = np.full((parts, 3), -np.inf)
    corner_part = np.repeat(labels, 3)
    np.minimum.at(lo, corner_part, pf.reshape(-1, 3))
    np.maximum.at(hi, corner_part, pf.reshape(-1, 3))
    sizes = np.linalg.norm(hi - lo, axis=1)
    open_parts = int((in_part & ~closed).sum())
    for part in np.flatnonzero(in_part & closed & consistent):  # winding already reported otherwise
        volume, size = float(volumes[part]), float(sizes[part])
        if abs(volume) <= ZERO_VOLUME_REL * size**3:
            out.append(finding("GEOM007", site, f"closed part {int(part)} encloses no volume ({volume:.3g} m^3)"))
        elif volume < 0:
            out.append(finding("GEOM005", site, f"closed part {int(part)} has negative volume {volume:.6g} m^3: "
                                                "its normals point inward"))
    if collision and open_parts:
        out.append(finding("GEOM006", site, f"{open_parts} parts of the collision mesh are not closed"))
    return out
