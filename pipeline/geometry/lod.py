"""The LOD-chain step: each free visual gets error-bounded coarser meshes (simplify)
and the asset a LodInfo per level.

The caller passes in what lies outside geometry: the memo of the level search, the
checks' verdict on one visual's mesh (findings.visual_verdict, which stands on
geometry), and the cores the search may use.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .. import ir
from ..errors import UserError
from . import clean as _clean
from .simplify import ITERATIONS, METHODS, Memo, Simplified, Parallelism, simplify_levels
from .transform import linear_scale

# What the checks hold against one mesh on its own: its error codes, and its
# (non-manifold, inconsistently wound) edge counts. A coarser level of a visual may
# have neither a code nor an edge of either kind more than its finer level.
Verdict = Callable[[ir.Mesh], tuple[frozenset[str], tuple[int, int]]]


@dataclass(frozen=True)
class LodOptions:
    """budgets_m: two-sided Hausdorff budget per level (LOD1, LOD2, ...), ascending;
    method: one of METHODS; iterations: simplify+measure rounds per level at most;
    samples: area-weighted samples per measurement (see metrics for the accuracy)."""

    budgets_m: tuple[float, ...] = (0.005, 0.02, 0.08)
    method: str = "meshoptimizer"
    iterations: int = ITERATIONS
    samples: int = 20_000


def frozen_visuals(asset: ir.Asset) -> set[str]:
    """Names of visuals that keep their mesh at every LOD: shape keys or a state binding."""
    bound = {b.target for b in asset.bindings}
    return {v.name for _, v in asset.visuals() if v.name in bound or v.mesh.shape_keys}


def lod_chain(options: LodOptions = LodOptions(), memo: Memo | None = None, verdict: Verdict | None = None,
              workers: Parallelism = Parallelism()) -> Callable[[ir.Asset], ir.Asset]:
    """Step: Visual.lods = (authored, LOD1, ..., LODk) and Asset.lods = LodInfo for
    levels 0..k (level 0: the authored meshes, budget and error 0).

    With meshoptimizer the free visuals of a link are simplified together, in the link
    frame: CAD-like assets are hundreds of small parts, and one search over their union
    (over each piece of it, for a large one: see simplify_levels) costs one
    measurement instead of hundreds. meshoptimizer collapses only along edges and
    keeps the original vertices, so every new face belongs to one part and the result
    splits back per visual exactly. Other methods move vertices and run per visual. A
    level's error is the measured two-sided Hausdorff distance of the union (the
    largest piece's, for one searched in pieces). Frozen visuals (shape keys, state
    bindings) repeat their Mesh object at every level; a part that would vanish keeps
    its previous level's mesh, so nothing disappears.

    `memo`: see simplify_levels. `verdict`: the checks' judgement of one visual's
    mesh (findings.visual_verdict); with it, a visual whose coarser mesh it judges worse keeps its finer one
    (None: no such judgement). `workers`: see simplify_levels.
    """
    budgets = tuple(float(b) for b in options.budgets_m)
    if list(budgets) != sorted(budgets) or any(b <= 0 for b in budgets):
        raise ValueError("LOD budgets must be positive and ascending")
    if options.method not in METHODS:
        raise ValueError(f"unknown simplifier {options.method!r}; one of {METHODS}")

    def step(asset: ir.Asset) -> ir.Asset:
        frozen = frozen_visuals(asset)
        errors = np.zeros(len(budgets))
        links = []
        for link in asset.links:
            chains: dict[str, list[ir.Mesh]] = {}
            free = []
            for vis in link.visuals:
                if vis.name in frozen or vis.mesh.triangle_count == 0:
                    chains[vis.name] = [vis.mesh] * (len(budgets) + 1)
                else:
                    _check_clean(asset, vis)
                    free.append(vis)
            groups = [free] if options.method == "meshoptimizer" else [[v] for v in free]
            for group in (g for g in groups if g):
                lods, errs = _group_chain(group, budgets, options, linear_scale(link.pose), memo, verdict, workers)
                chains.update(lods)
                errors = np.maximum(errors, errs)
            visuals = [replace(v, lods=tuple(chains[v.name])) for v in link.visuals]
            links.append(replace(link, visuals=tuple(visuals)))
        out = asset.with_(links=tuple(links))
        infos = [ir.LodInfo(0, 0.0, 0.0, out.triangle_count(0))]
        infos += [ir.LodInfo(i + 1, b, float(errors[i]), out.triangle_count(i + 1)) for i, b in enumerate(budgets)]
        return out.with_(lods=tuple(infos))

    return step


def _group_chain(group: list[ir.Visual], budgets, options: LodOptions, link_scale: float, memo: Memo | None,
                 verdict: Verdict | None, workers: Parallelism):
    """LOD chains of visuals simplified as one mesh in their link's frame.
    Returns ({visual name: [mesh per level]}, errors per level in the model frame)."""
    poses = [v.pose for v in group]
    parts = [(np.c_[v.mesh.vertices, np.ones(len(v.mesh.vertices))] @ p.T)[:, :3] for v, p in zip(group, poses)]
    offsets = np.cumsum([0] + [len(p) for p in parts])
    vertices = np.concatenate(parts)
    faces = np.concatenate([v.mesh.faces.astype(np.int64) + o for v, o in zip(group, offsets[:-1])])
    rotations = [p[:3, :3] for p in poses]
    has_normals = all(v.mesh.normals is not None for v in group)
    normals = np.concatenate([v.mesh.normals @ r.T for v, r in zip(group, rotations)]) if has_normals else None
    parts_id = np.repeat(np.arange(len(group)), np.diff(offsets))
    scale = max(link_scale, 1e-12)
    chains = {v.name: [v.mesh] for v in group}
    errors = np.zeros(len(budgets))
    known: dict = {}  # id(mesh) -> (mesh, its verdict)
    levels = simplify_levels(vertices, faces, [b / scale for b in budgets], options.method, options.iterations,
                             options.samples, normals=normals, parts=parts_id, memo=memo, workers=workers)
    for i, r in enumerate(levels):
        errors[i] = r.error_m * scale
        if r.faces is faces:
            for v in group:
                chains[v.name].append(v.mesh)
            continue
        if len(group) == 1 and r.kept is None:
            per_visual = {group[0].name: _lod_mesh(group[0].mesh, r)}
        else:
            per_visual = _split(group, offsets, r)
        for v in group:
            finer = chains[v.name][-1]
            mesh = per_visual.get(v.name)
            if mesh is None or mesh.triangle_count >= finer.triangle_count or _judged_worse(finer, mesh, known,
                                                                                            verdict):
                # a part never vanishes, collapses flat, or grows at a coarser level: it
                # keeps its finer level, whose error is within the finer (smaller) budget
                mesh = finer
                errors[i] = max(errors[i], errors[i - 1] if i else 0.0)
            chains[v.name].append(mesh)
    return chains, errors


def _lod_mesh(mesh: ir.Mesh, r: Simplified) -> ir.Mesh:
    if r.kept is None:  # new vertex positions: attributes are not transferred
        return ir.Mesh(r.vertices, r.faces)
    return ir.Mesh(
        r.vertices, r.faces,
        normals=None if mesh.normals is None else mesh.normals[r.kept],
        uvs=None if mesh.uvs is None else mesh.uvs[r.kept],
    )


def _split(group: list[ir.Visual], offsets: np.ndarray, r: Simplified) -> dict[str, ir.Mesh]:
    """The union's simplification back per visual (meshoptimizer keeps original
    vertices, so every face has one owner); visuals left with no face are absent."""
    owner = np.searchsorted(offsets, r.kept, side="right") - 1
    face_owner = owner[r.faces[:, 0]]
    out = {}
    for k, v in enumerate(group):
        sel = r.faces[face_owner == k]
        if len(sel):
            used, local_faces = _clean.compact(sel, len(r.kept))
            kept = r.kept[used] - offsets[k]
            out[v.name] = _lod_mesh(v.mesh, Simplified(v.mesh.vertices[kept], local_faces, kept, r.error_m, 0, 0))
    return out


def _judged_worse(finer: ir.Mesh, coarser: ir.Mesh, known: dict, verdict: Verdict | None) -> bool:
    """Does `verdict` hold more against the coarser mesh than the finer one (a cap
    thinner than the budget collapses into a closed part of no volume; more
    non-manifold or inconsistently wound edges)? The union of a link's visuals is
    judged as a whole while simplifying; this judges each visual on its own.
    `known` keeps each mesh's verdict by id, holding the mesh so the id stays its own."""
    if verdict is None:
        return False

    def judged(mesh: ir.Mesh):
        if id(mesh) not in known:
            known[id(mesh)] = (mesh, *verdict(mesh))
        return known[id(mesh)][1:]

    (coarse_errors, coarse_edges), (fine_errors, fine_edges) = judged(coarser), judged(finer)
    return bool(coarse_errors - fine_errors) or any(c > f for c, f in zip(coarse_edges, fine_edges))


def _check_clean(asset: ir.Asset, vis: ir.Visual) -> None:
    """Refuse what would crash a simplifier, naming the visual (run clean() first)."""
    f = vis.mesh.faces
    _clean.check_finite(vis.mesh.vertices, asset.source, vis.name)
    if len(f) and ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])).any():
        raise UserError(asset.source, vis.name, "mesh has faces with repeated vertices; run the clean step before LODs")
