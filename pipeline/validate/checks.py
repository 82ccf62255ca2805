"""Checks with stable codes (DESIGN.md s.7): geometry, hierarchy, placement, package.

Every check returns `Finding` records, never raises on bad data: a report must list
everything wrong with a model, not stop at the first problem. Codes are stable (tests
and CI filters key on them); `RULES` is the one table of what each code means.

- geometry (GEOM0xx) and hierarchy (HIER0xx) run on an `ir.Asset` (`check_asset`);
- placement (PLACE00x) findings are made by pipeline/scene/checks.py during the scene
  build and read back from build/scene/placements.json (listed here for the table);
- gazebo (GZ0xx) compare what Gazebo's own loaders read (tools/gzprobe, run by
  validate/gazebo.py) with what the files hold;
- package (PKG0xx) run on a built package folder (`check_package`), parsing its XML
  with entities, DTDs and network access disabled: a package is untrusted input.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath
from typing import Iterable, Literal

import numpy as np
from lxml import etree

from .. import ir
from ..export import names

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
}

SEVERITIES = ("error", "warning", "info")

# Tolerances, relative to the size of the thing measured so that millimetre parts and
# 50 m busbars are judged alike.
DEGENERATE_AREA_REL = 1e-12   # face area / bbox diagonal^2
ZERO_VOLUME_REL = 1e-6        # |volume| / part bbox diagonal^3
NEAR_ZERO_AXIS = 1e-6         # the blend reader's MIN_AXIS_LENGTH order of magnitude
MIN_SIZE_M = 0.01             # a part smaller than 1 cm is a metre/millimetre mix-up
MAX_SIZE_M = 200.0            # nothing in a substation is bigger than 200 m
PIVOT_SLACK_M = 0.1           # a pivot may sit this far outside its link's box ...
PIVOT_SLACK_REL = 1.0         # ... or one box diagonal, whichever is larger
LOD_ERROR_SLACK = 1e-9        # float noise in the measured error


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


# --- geometry -------------------------------------------------------------------------


def _finite(*arrays) -> bool:
    return all(a is None or bool(np.isfinite(np.asarray(a, dtype=np.float64)).all()) for a in arrays)


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
    edge's undirected edge id (3m,), and per undirected edge the faces using it and
    how many of them run it from its lower to its higher vertex."""
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).astype(np.int64)
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    # One int64 per undirected edge: a 1-D sort, many times faster than unique rows.
    edge_keys, edge_id, uses = np.unique(lo * (int(hi.max()) + 1) + hi, return_inverse=True, return_counts=True)
    edge_id = edge_id.reshape(-1)
    forward = np.bincount(edge_id, weights=(directed[:, 0] < directed[:, 1]).astype(float), minlength=len(edge_keys))
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

    `memo` (builder.memo.ArrayMemo, under this module's code version): the findings of
    a mesh checked before, by its content, so the geometry task's per-part checks and
    the package's checks of the same meshes run once; what comes back is what the
    check finds (a look-up costs a tenth of a millisecond, checking a small part five
    times that: every mesh is kept)."""
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
    if not _finite(verts, mesh.normals, mesh.uvs, *keys):
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
    part_of_edge[edge_id] = np.tile(labels, 3)
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


def _asset_bounds(asset: ir.Asset) -> np.ndarray | None:
    """(2, 3) model-frame bounds of the LOD0 visuals, or None without finite geometry."""
    pts = []
    for link, visual in asset.visuals():
        v = visual.mesh.vertices
        if len(v) == 0 or not _finite(v, link.pose, visual.pose):
            continue
        m = link.pose @ visual.pose
        pts.append(v @ m[:3, :3].T + m[:3, 3])
    if not pts:
        return None
    allp = np.concatenate(pts)
    return np.stack([allp.min(axis=0), allp.max(axis=0)])


def budget_findings(asset_id: str, triangles: int, budget_triangles: int | None) -> list[Finding]:
    """GEOM008 when an asset's LOD0 has more triangles than its asset.toml allows."""
    if budget_triangles is None or triangles <= budget_triangles:
        return []
    return [finding("GEOM008", asset_id, f"{triangles} triangles at LOD0, budget {budget_triangles}")]


def geometry_findings(asset: ir.Asset, budget_triangles: int | None = None, memo=None) -> list[Finding]:
    """`memo`: see mesh_findings."""
    out: list[Finding] = []
    for link in asset.links:
        lsite = f"{asset.id}/{link.name}"
        if not _finite(link.pose):
            out.append(finding("GEOM001", lsite, "link pose is not finite"))
        for visual in link.visuals:
            vsite = f"{lsite}/{visual.name}"
            if not _finite(visual.pose):
                out.append(finding("GEOM001", vsite, "visual pose is not finite"))
            for level, mesh in enumerate(visual.lods):
                out += mesh_findings(mesh, vsite if level == 0 else f"{vsite}/lod{level}", memo=memo)
        for col in link.collisions:
            csite = f"{lsite}/{col.name}"
            if not _finite(col.pose):
                out.append(finding("GEOM001", csite, "collision pose is not finite"))
            out += mesh_findings(col.mesh, csite, collision=True, memo=memo)
    for joint in asset.joints:
        if not _finite(joint.pose):
            out.append(finding("GEOM001", f"{asset.id}/{joint.name}", "joint pose is not finite"))

    out += budget_findings(asset.id, asset.triangle_count(0), budget_triangles)
    for lod in asset.lods:
        if lod.level > 0 and not (lod.error_m <= lod.budget_m + LOD_ERROR_SLACK):
            out.append(finding("GEOM009", f"{asset.id}/lod{lod.level}",
                               f"measured error {lod.error_m:.6g} m over the budget {lod.budget_m:.6g} m"))
    bounds = _asset_bounds(asset)
    if bounds is not None:
        size = float((bounds[1] - bounds[0]).max())
        if size < MIN_SIZE_M or size > MAX_SIZE_M:
            hint = "millimetres read as metres?" if size > MAX_SIZE_M else "metres scaled as millimetres?"
            out.append(finding("GEOM010", asset.id, f"largest extent {size:.6g} m ({hint})"))
    return out


# --- hierarchy ------------------------------------------------------------------------

_PATH_LIKE = re.compile(r"[/\\:]|\.\.")


def _name_findings(kind: str, name: str, site: str) -> list[Finding]:
    if _PATH_LIKE.search(name) or name in ("", "."):
        return [finding("HIER012", site, f"{kind} name {name!r} is path-like")]
    if names.safe_name(name) != name:
        return [finding("HIER005", site, f"{kind} name {name!r} will be written as {names.safe_name(name)!r}")]
    return []


def _duplicates(kind: str, items: list[tuple[str, str]]) -> list[Finding]:
    """items: (name, site). Two names that safe_name maps alike collide in every file."""
    seen: dict[str, list[tuple[str, str]]] = {}
    for name, site in items:
        seen.setdefault(names.safe_name(name), []).append((name, site))
    out = []
    for safe, group in sorted(seen.items()):
        if len(group) > 1:
            raw = sorted({n for n, _ in group})
            out.append(finding("HIER004", group[1][1], f"{kind} name {safe!r} used {len(group)} times ({raw})"))
    return out


def _joint_graph(asset: ir.Asset) -> list[Finding]:
    """Root, tree and reachability of links and joints."""
    aid = asset.id
    link_names = [link.name for link in asset.links]
    known = set(link_names)
    out: list[Finding] = []
    dangling = [j for j in asset.joints if j.parent not in known or j.child not in known]
    for j in dangling:
        missing = sorted({j.parent, j.child} - known)
        out.append(finding("HIER003", f"{aid}/{j.name}", f"joint names missing link(s) {missing}"))
    joints = [j for j in asset.joints if j not in dangling]

    # Union-find over the undirected joint graph: a joint joining two links that are
    # already connected closes a loop (a directed cycle or a link with two parents).
    parent = {n: n for n in known}

    def find(n):
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    looped: set[str] = set()
    for j in joints:
        a, b = find(j.parent), find(j.child)
        if a == b:
            out.append(finding("HIER002", f"{aid}/{j.name}", f"joint {j.parent!r} -> {j.child!r} closes a loop"))
            looped.add(a)
        else:
            parent[a] = b
    looped = {find(n) for n in looped}

    children = {j.child for j in asset.joints}
    roots = [n for n in link_names if n not in children]
    on_loop = {n for n in known if find(n) in looped}
    if len(roots) != 1 and not (not roots and on_loop):
        out.append(finding("HIER001", aid, f"{len(roots)} root links {sorted(roots)}, expected exactly one"))
    if len(roots) == 1:
        reach, todo = {roots[0]}, [roots[0]]
        while todo:
            n = todo.pop()
            for j in joints:
                if j.parent == n and j.child not in reach:
                    reach.add(j.child)
                    todo.append(j.child)
        for n in sorted(known - reach - on_loop):
            out.append(finding("HIER003", f"{aid}/{n}", f"link not reachable from the root link {roots[0]!r}"))
    return out


def _child_bounds(link: ir.Link) -> np.ndarray | None:
    pts = []
    for pose, mesh in [(v.pose, v.mesh) for v in link.visuals] + [(c.pose, c.mesh) for c in link.collisions]:
        if len(mesh.vertices) and _finite(mesh.vertices, pose, link.pose):
            m = link.pose @ pose
            pts.append(mesh.vertices @ m[:3, :3].T + m[:3, 3])
    if not pts:
        return None
    allp = np.concatenate(pts)
    return np.stack([allp.min(axis=0), allp.max(axis=0)])


def _joint_findings(asset: ir.Asset) -> list[Finding]:
    out: list[Finding] = []
    links = {link.name: link for link in asset.links}
    for j in asset.joints:
        site = f"{asset.id}/{j.name}"
        if j.type != "fixed":
            length = float(np.linalg.norm(j.axis)) if _finite(j.axis) else float("nan")
            if not length >= NEAR_ZERO_AXIS:
                out.append(finding("HIER006", site, f"axis {[float(a) for a in j.axis]} has length {length:.3g}"))
        if j.type in ("revolute", "prismatic") and j.lower is not None and j.upper is not None \
                and j.lower > j.upper:
            out.append(finding("HIER007", site, f"lower limit {j.lower} above upper limit {j.upper}"))
        child = links.get(j.child)
        bounds = _child_bounds(child) if child is not None else None
        if bounds is not None and _finite(j.pose):
            pivot = j.pose[:3, 3]
            gap = float(np.linalg.norm(np.maximum(0.0, np.maximum(bounds[0] - pivot, pivot - bounds[1]))))
            slack = max(PIVOT_SLACK_M, PIVOT_SLACK_REL * float(np.linalg.norm(bounds[1] - bounds[0])))
            if gap > slack:
                out.append(finding("HIER008", site, f"pivot {gap:.3f} m outside the bounds of link {j.child!r}"))
    return out


def _binding_findings(asset: ir.Asset) -> list[Finding]:
    out: list[Finding] = []
    visuals = {v.name: v for _, v in asset.visuals()}
    materials = {m.name for m in asset.materials}
    for b in asset.bindings:
        site = f"{asset.id}/{b.target}/{b.variable}"
        target = visuals.get(b.target)
        if target is None:
            out.append(finding("HIER009", site, f"{b.effect} binding of {b.variable!r} targets missing visual "
                                                f"{b.target!r}"))
        elif b.effect == "shape" and b.shape_key not in {k.name for k in target.mesh.shape_keys}:
            out.append(finding("HIER009", site, f"shape binding names missing shape key {b.shape_key!r}"))
        if b.effect == "material":
            missing = sorted(set(b.materials) - materials)
            if missing:
                out.append(finding("HIER009", site, f"material binding names missing materials {missing}"))
            t = list(b.thresholds)
            if len(t) != max(0, len(b.materials) - 1) or t != sorted(t) or not _finite(t):
                out.append(finding("HIER011", site, f"{len(t)} thresholds {t} for {len(b.materials)} materials "
                                                    "(need ascending, one fewer)"))
        d0, d1 = (float(x) for x in b.domain)
        if not (np.isfinite(d0) and np.isfinite(d1)) or d0 == d1:
            out.append(finding("HIER010", site, f"domain [{d0}, {d1}] is empty"))
    return out


def carried_findings(asset: ir.Asset) -> list[Finding]:
    """The readers' `warning.<what>` metadata: what the source holds that no output
    carries, one finding each (ingest.blend, ingest.mesh)."""
    return [finding("HIER013", asset.id, message) for key, message in asset.metadata if key.startswith("warning.")]


def hierarchy_findings(asset: ir.Asset) -> list[Finding]:
    aid = asset.id
    out = _name_findings("asset", aid, aid)
    frames = [(link.name, f"{aid}/{link.name}") for link in asset.links]
    frames += [(j.name, f"{aid}/{j.name}") for j in asset.joints]
    visuals = [(v.name, f"{aid}/{link.name}/{v.name}") for link, v in asset.visuals()]
    collisions = [(c.name, f"{aid}/{link.name}/{c.name}") for link in asset.links for c in link.collisions]
    for kind, items in (("link/joint", frames), ("visual", visuals), ("collision", collisions)):
        for name, site in items:
            out += _name_findings(kind.split("/")[0] if kind != "link/joint" else "frame", name, site)
        out += _duplicates(kind, items)
    if not asset.links:
        out.append(finding("HIER001", aid, "asset has no links"))
    else:
        out += _joint_graph(asset)
    out += _joint_findings(asset)
    out += _binding_findings(asset)
    out += carried_findings(asset)
    return out


def check_asset(asset: ir.Asset, budget_triangles: int | None = None, memo=None) -> list[Finding]:
    """Geometry and hierarchy findings of an asset, sorted by site then code. `memo`:
    see mesh_findings."""
    return sort_findings(geometry_findings(asset, budget_triangles, memo) + hierarchy_findings(asset))


# --- package --------------------------------------------------------------------------

_LOD_VARIANT = re.compile(r"^(?P<base>.+)__lod\d+$")
_HASH_CHUNK = 1 << 20
_PROLOG_BYTES = 1 << 16
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)


def hardened_parser() -> etree.XMLParser:
    """No entity expansion, no DTD loading, no network: a package is untrusted."""
    return etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False,
                           dtd_validation=False, huge_tree=False)


def parse_xml(path: Path, site: str) -> tuple[etree._ElementTree | None, list[Finding]]:
    """Parse with the hardened parser; any DOCTYPE is refused (COLLADA and SDF need none,
    so one can only be there to declare entities)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_PROLOG_BYTES)
    except OSError as e:
        return None, [finding("PKG002", site, f"cannot read: {e.strerror}")]
    # Refuse before libxml2 sees it: it would still read the entity declarations.
    if _DOCTYPE.search(head):
        return None, [finding("PKG005", site, "declares a DOCTYPE; refused, entities not resolved")]
    try:
        tree = etree.parse(str(path), hardened_parser())
    except etree.XMLSyntaxError as e:
        # e.msg, not str(e): the latter names the absolute path, which differs per checkout
        return None, [finding("PKG001", site, f"not well-formed XML: {e.msg} (line {e.lineno})")]
    except OSError as e:
        return None, [finding("PKG002", site, f"cannot read: {e.strerror}")]
    info = tree.docinfo
    if info.doctype or info.internalDTD is not None or info.externalDTD is not None:
        return None, [finding("PKG005", site, f"declares DOCTYPE {info.doctype!r}; refused, entities not resolved")]
    return tree, []


def _inside(path: Path, root: Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
        return True
    except (ValueError, OSError, RuntimeError):
        return False


def _uri_target(uri: str, folder: Path, owners: set[str]) -> tuple[Path | None, str | None]:
    """The file a model.sdf URI names, or (None, why it leaves the package)."""
    uri = uri.strip()
    if uri.startswith("model://"):
        rest = PurePosixPath(uri[len("model://"):])
        if not rest.parts or rest.parts[0] not in owners:
            return None, f"names another model {rest.parts[0] if rest.parts else ''!r}"
        root, rel = folder.parent / rest.parts[0], PurePosixPath(*rest.parts[1:])
    elif re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:", uri) or uri.startswith(("/", "\\")):
        return None, "is absolute or has a scheme other than model://"
    else:
        root, rel = folder, PurePosixPath(uri)
    if ".." in rel.parts or "\\" in str(rel):
        return None, "climbs out with .."
    target = root / rel
    if not _inside(target, root):
        return None, "resolves (through a link) outside its package"
    return target, None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_HASH_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def _manifest_findings(folder: Path, pkg: str) -> list[Finding]:
    path = folder / "manifest.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        outputs = data["outputs"]
        if not isinstance(outputs, dict):
            raise TypeError("outputs is not an object")
    except FileNotFoundError:
        return [finding("PKG006", f"{pkg}/manifest.json", "no manifest.json in the package")]
    except (OSError, ValueError, KeyError, TypeError) as e:
        return [finding("PKG006", f"{pkg}/manifest.json", f"unreadable: {type(e).__name__}: {e}")]
    out: list[Finding] = []
    for rel, digest in sorted(outputs.items()):
        site = f"{pkg}/{rel}"
        rp = PurePosixPath(str(rel))
        if rp.is_absolute() or ".." in rp.parts or "\\" in str(rel):
            out.append(finding("PKG003", site, "manifest output path leaves the package"))
            continue
        target = folder / rp
        if not _inside(target, folder):
            out.append(finding("PKG003", site, "manifest output resolves outside the package"))
        elif not target.is_file():
            out.append(finding("PKG002", site, "listed in manifest.json but missing"))
        elif _sha256(target) != digest:
            out.append(finding("PKG004", site, "sha256 differs from manifest.json"))
    return out


def check_package(folder: Path) -> list[Finding]:
    """Package findings of a built model folder (a package, or a LOD variant folder
    holding only model.config and model.sdf): manifest hashes, XML well-formedness
    with DOCTYPEs refused, and every model.sdf URI resolved inside its package."""
    folder = Path(folder)
    pkg = folder.name
    variant = _LOD_VARIANT.match(pkg)
    owners = {pkg} | ({variant.group("base")} if variant else set())
    out: list[Finding] = []
    if not variant or (folder / "manifest.json").exists():
        out += _manifest_findings(folder, pkg)

    xml_files: dict[Path, str] = {}
    for name in ("model.config", "model.sdf"):
        if not (folder / name).is_file():
            out.append(finding("PKG002", f"{pkg}/{name}", f"no {name} in the package"))
    _, errs = parse_xml(folder / "model.config", f"{pkg}/model.config") \
        if (folder / "model.config").is_file() else (None, [])
    out += errs
    sdf_tree, errs = parse_xml(folder / "model.sdf", f"{pkg}/model.sdf") \
        if (folder / "model.sdf").is_file() else (None, [])
    out += errs
    if sdf_tree is not None:
        for el in sdf_tree.iter("uri"):
            uri = (el.text or "").strip()
            site = f"{pkg}/model.sdf:{el.sourceline}"
            target, why = _uri_target(uri, folder, owners)
            if target is None:
                out.append(finding("PKG003", site, f"URI {uri!r} {why}"))
            elif not target.is_file():
                out.append(finding("PKG002", site, f"URI {uri!r}: no such file"))
            elif target.suffix.lower() == ".dae" and _inside(target, folder):
                # another owner's meshes (a LOD variant's base) are checked with it
                xml_files[target.resolve()] = f"{pkg}/{target.resolve().relative_to(folder.resolve())}"
    for dae in sorted((folder / "meshes").glob("*.dae")) if (folder / "meshes").is_dir() else []:
        if _inside(dae, folder):
            xml_files.setdefault(dae.resolve(), f"{pkg}/meshes/{dae.name}")
    for path, site in sorted(xml_files.items()):
        out += parse_xml(path, site)[1]
    return sort_findings(out)


def as_dicts(findings: Iterable[Finding]) -> list[dict]:
    return [f.as_dict() for f in sort_findings(findings)]
