"""The checks of an asset and of a built package (DESIGN.md s.7).

Every check returns `findings.Finding` records, never raises on bad data: a report
must list everything wrong with a model, not stop at the first problem. The codes
and what each means are findings.RULES.

- geometry (GEOM0xx) and hierarchy (HIER0xx) run on an `ir.Asset` (`check_asset`),
  each mesh by findings.mesh_findings;
- package (PKG0xx) run on a built package folder (`check_package`), parsing its XML
  with entities, DTDs and network access disabled: a package is untrusted input.
"""

from __future__ import annotations

import json
import re
from pathlib import Path, PurePosixPath

import numpy as np
from lxml import etree

from .. import ir, safe_xml
from ..digest import sha256_file
from ..export import names
from ..findings import Finding, finding, finite, mesh_findings, sort_findings

# Tolerances, relative to the size of the thing measured so that millimetre parts and
# 50 m busbars are judged alike.
NEAR_ZERO_AXIS = 1e-6         # the blend reader's MIN_AXIS_LENGTH order of magnitude
MIN_SIZE_M = 0.01             # a part smaller than 1 cm is a metre/millimetre mix-up
MAX_SIZE_M = 200.0            # nothing in a substation is bigger than 200 m
PIVOT_SLACK_M = 0.1           # a pivot may sit this far outside its link's box ...
PIVOT_SLACK_REL = 1.0         # ... or one box diagonal, whichever is larger
LOD_ERROR_SLACK = 1e-9        # float noise in the measured error


# --- geometry -------------------------------------------------------------------------


def _placed_bounds(parts) -> np.ndarray | None:
    """(2, 3) bounds of meshes placed by two poses: `parts` yields (vertices (n, 3),
    outer (4, 4), inner (4, 4)), each placed by outer @ inner; an empty or non-finite
    part is left out, and None is returned when none is left."""
    pts = []
    for v, outer, inner in parts:
        if len(v) and finite(v, outer, inner):
            m = outer @ inner
            pts.append(v @ m[:3, :3].T + m[:3, 3])
    if not pts:
        return None
    allp = np.concatenate(pts)
    return np.stack([allp.min(axis=0), allp.max(axis=0)])


def _asset_bounds(asset: ir.Asset) -> np.ndarray | None:
    """(2, 3) model-frame bounds of the LOD0 visuals, or None without finite geometry."""
    return _placed_bounds((visual.mesh.vertices, link.pose, visual.pose) for link, visual in asset.visuals())


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
        if not finite(link.pose):
            out.append(finding("GEOM001", lsite, "link pose is not finite"))
        for visual in link.visuals:
            vsite = f"{lsite}/{visual.name}"
            if not finite(visual.pose):
                out.append(finding("GEOM001", vsite, "visual pose is not finite"))
            for level, mesh in enumerate(visual.lods):
                out += mesh_findings(mesh, vsite if level == 0 else f"{vsite}/lod{level}", memo=memo)
        for col in link.collisions:
            csite = f"{lsite}/{col.name}"
            if not finite(col.pose):
                out.append(finding("GEOM001", csite, "collision pose is not finite"))
            out += mesh_findings(col.mesh, csite, collision=True, memo=memo)
    for joint in asset.joints:
        if not finite(joint.pose):
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
    """(2, 3) model-frame bounds of a link's visuals and collisions, or None."""
    return _placed_bounds((part.mesh.vertices, link.pose, part.pose) for part in (*link.visuals, *link.collisions))


def _joint_findings(asset: ir.Asset) -> list[Finding]:
    out: list[Finding] = []
    links = {link.name: link for link in asset.links}
    for j in asset.joints:
        site = f"{asset.id}/{j.name}"
        if j.type != "fixed":
            length = float(np.linalg.norm(j.axis)) if finite(j.axis) else float("nan")
            if not length >= NEAR_ZERO_AXIS:
                out.append(finding("HIER006", site, f"axis {[float(a) for a in j.axis]} has length {length:.3g}"))
        if j.type in ("revolute", "prismatic") and j.lower is not None and j.upper is not None \
                and j.lower > j.upper:
            out.append(finding("HIER007", site, f"lower limit {j.lower} above upper limit {j.upper}"))
        child = links.get(j.child)
        bounds = _child_bounds(child) if child is not None else None
        if bounds is not None and finite(j.pose):
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
            if len(t) != max(0, len(b.materials) - 1) or t != sorted(t) or not finite(t):
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


def parse_xml(path: Path, site: str) -> tuple[etree._ElementTree | None, list[Finding]]:
    """Parse with safe_xml's parser; any DOCTYPE is refused (COLLADA and SDF need none,
    so one can only be there to declare entities)."""
    try:
        doctype = safe_xml.declares_doctype(path)
    except OSError as e:
        return None, [finding("PKG002", site, f"cannot read: {e.strerror}")]
    if doctype:
        return None, [finding("PKG005", site, "declares a DOCTYPE; refused, entities not resolved")]
    try:
        tree = etree.parse(str(path), safe_xml.parser())
    except etree.XMLSyntaxError as e:
        # e.msg, not str(e): the latter names the absolute path, which differs per checkout
        return None, [finding("PKG001", site, f"not well-formed XML: {e.msg} (line {e.lineno})")]
    except OSError as e:
        return None, [finding("PKG002", site, f"cannot read: {e.strerror}")]
    if safe_xml.has_doctype(tree):
        return None, [finding("PKG005", site, f"declares DOCTYPE {tree.docinfo.doctype!r}; refused, entities not resolved")]
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
        elif sha256_file(target) != digest:
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

