"""Gazebo's own loaders on what we wrote: tools/gzprobe against the files themselves.

The probe (C++, built against Debian's sdformat 12, ign-common 4 and ign-physics 5: the
Fortress generation) parses the world once as gz-sim's server does and loads every mesh
through ignition::common::MeshManager, each in a child process. This module runs it and
compares what Gazebo saw with what the files hold, read here with lxml as float64:

- per mesh: triangles, the bounds of every triangle corner, and the sums over all
  corners of position, squared position, normal and texture coordinate (a misread
  index stride or a lost triangle moves them; Gazebo's re-indexing does not);
- per model: the model-frame bounds of its visuals against the manifest's bounds,
  within the LOD's measured error;
- the world: parse time and peak memory, sdformat's errors.

Findings use the GZ rules of findings.RULES.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from .. import safe_xml
from ..scene.world_sdf import PARSE_BUDGET_MB, moving_parts_mb
from ..findings import Finding, finding

PROBE = Path(__file__).resolve().parents[2] / "tools" / "gzprobe" / "gzprobe"
PROBE_HINT = "bash .ci/install-tools (builds tools/gzprobe against Debian's libsdformat-dev, libignition-*-dev)"
# Relative tolerance on corner sums: both sides parse the same decimal text as float64,
# so only the order of summation differs.
SUM_TOLERANCE = 1e-9
# Absolute tolerance on bounds, metres: float text parsed twice is the same double.
BOUNDS_TOLERANCE_M = 1e-9
# A model's bounds may move by the LOD's measured error plus this (float32 vertices).
MODEL_BOUNDS_SLACK_M = 1e-4
# How long a user waits for a world to parse (its memory: world_sdf.PARSE_BUDGET_MB).
WORLD_PARSE_BUDGET_S = 10.0
_TIMEOUT_S = 1800


class ProbeMissing(RuntimeError):
    """tools/gzprobe is not built here."""


@dataclass(frozen=True)
class MeshSummary:
    """What a mesh is, as a renderer would draw it: arrays are float64."""

    triangles: int
    corners: int
    lo: np.ndarray          # (3,) bounds of the triangle corners
    hi: np.ndarray
    corner_sum: np.ndarray  # (3,) sum of corner positions
    corner_sq: np.ndarray   # (3,) sum of squared corner positions
    normals: int            # corners with a normal
    normal_sum: np.ndarray  # (3,)
    uvs: int                # corners with a texture coordinate
    uv_sum: np.ndarray      # (2,)


# --- running the probe ----------------------------------------------------------------

def available() -> bool:
    return PROBE.is_file() and os.access(PROBE, os.X_OK)


def _run(args: list[str], env: dict | None = None) -> dict:
    if not available():
        raise ProbeMissing(f"{PROBE} is not built: {PROBE_HINT}")
    done = subprocess.run([str(PROBE), *args], capture_output=True, text=True, env=env,
                          timeout=_TIMEOUT_S, check=False)
    try:
        return json.loads(done.stdout)
    except json.JSONDecodeError:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"gzprobe {args[0]} gave no report (exit {done.returncode}): {' | '.join(tail)}") from None


def probe_meshes(paths: list[Path], jobs: int = 2) -> dict[str, dict]:
    """path -> the probe's report of that mesh as MeshManager loaded it."""
    if not paths:
        return {}
    return _run(["mesh", *map(str, paths), "--jobs", str(jobs)])["meshes"]


def probe_world(world: Path, sdf_path: list[Path], *, jobs: int = 2, meshes: bool = True,
                physics_s: float = 0.0) -> dict:
    """The probe's report of a world: {"world": figures, "models": [...], "meshes": {...},
    "physics": {...} when physics_s > 0}."""
    env = dict(os.environ, SDF_PATH=os.pathsep.join(str(Path(p).resolve()) for p in sdf_path))
    args = ["world", str(world), "--jobs", str(jobs)]
    if not meshes:
        args.append("--no-meshes")
    if physics_s > 0:
        args += ["--physics", repr(float(physics_s))]
    return _run(args, env)


# --- what the file holds --------------------------------------------------------------

def _by_id(root) -> dict[str, etree._Element]:
    return {el.get("id"): el for el in root.iter() if el.get("id") is not None}


# The text of a <p>: vertex indices (never negative) and XML's whitespace.
_INDICES = re.compile(r"[0-9 \t\r\n]*")


def _indices(text: str) -> np.ndarray:
    """The int64 indices of a <p>'s text, read by numpy's text reader (several times
    faster than split and convert). The text is checked first: the reader stops at the
    first word it cannot read instead of failing, and saturates an index too large for
    int64 (which then fails as out of range); and it reads whitespace alone as one 0."""
    if not _INDICES.fullmatch(text):
        raise ValueError("a <p> holds something other than vertex indices")
    if not text.strip():
        return np.zeros(0, dtype=np.int64)
    return np.fromstring(text, dtype=np.int64, sep=" ")


def _floats(source, ids) -> np.ndarray:
    """(n, stride) float64 array of a <source>."""
    arr = source.find("{*}float_array")
    stride = int(source.find("{*}technique_common/{*}accessor").get("stride", "1"))
    values = np.array((arr.text or "").split(), dtype=np.float64)
    return values.reshape(-1, stride)


def written_summary(path: Path) -> MeshSummary:
    """The summary of every <triangles> of a COLLADA file, read as float64 from its text.

    Honours each input's offset, <vertices> inputs and <unit meter>; node transforms are
    not applied (our meshes are written in their own frame, node matrix identity)."""
    root = etree.parse(str(path), safe_xml.parser(huge_tree=True)).getroot()
    ids = _by_id(root)
    unit = root.find("{*}asset/{*}unit")
    scale = float(unit.get("meter", "1")) if unit is not None else 1.0
    positions, normals, uvs, triangles = [], [], [], 0
    for tris in root.iter("{*}triangles"):
        count = int(tris.get("count", "0"))
        inputs = tris.findall("{*}input")
        stride = 1 + max(int(i.get("offset", "0")) for i in inputs)
        p = _indices(tris.findtext("{*}p") or "")
        p = p[: count * 3 * stride].reshape(-1, stride)
        triangles += len(p) // 3
        for inp in inputs:
            semantic, offset = inp.get("semantic"), int(inp.get("offset", "0"))
            target = ids[inp.get("source").lstrip("#")]
            streams = ([(v.get("semantic"), ids[v.get("source").lstrip("#")]) for v in target.findall("{*}input")]
                       if semantic == "VERTEX" else [(semantic, target)])
            for name, source in streams:
                data = _floats(source, ids)[p[:, offset]]
                if name == "POSITION":
                    positions.append(data[:, :3] * scale)
                elif name == "NORMAL":
                    # gz-common normalizes each normal as it loads (ColladaLoader::LoadNormals)
                    length = np.linalg.norm(data[:, :3], axis=1, keepdims=True)
                    normals.append(np.divide(data[:, :3], length, out=np.zeros_like(data[:, :3]), where=length > 0))
                elif name == "TEXCOORD":
                    uvs.append(data[:, :2])
    corners = np.concatenate(positions) if positions else np.zeros((0, 3))
    normal = np.concatenate(normals) if normals else np.zeros((0, 3))
    uv = np.concatenate(uvs) if uvs else np.zeros((0, 2))
    return MeshSummary(
        triangles=triangles, corners=len(corners),
        lo=corners.min(axis=0) if len(corners) else np.zeros(3),
        hi=corners.max(axis=0) if len(corners) else np.zeros(3),
        corner_sum=corners.sum(axis=0), corner_sq=(corners**2).sum(axis=0),
        normals=len(normal), normal_sum=normal.sum(axis=0), uvs=len(uv), uv_sum=uv.sum(axis=0))


def probed_summary(report: dict) -> MeshSummary:
    """The same summary from a probe report (ok reports only)."""
    vec = lambda key: np.asarray(report[key], dtype=np.float64)  # noqa: E731
    return MeshSummary(
        triangles=int(report["triangles"]), corners=int(report["corners"]),
        lo=vec("min"), hi=vec("max"), corner_sum=vec("corner_sum"), corner_sq=vec("corner_sq"),
        normals=int(report["normals"]), normal_sum=vec("normal_sum"),
        uvs=int(report["uvs"]), uv_sum=vec("uv_sum"))


# --- comparing ------------------------------------------------------------------------

def _sums_agree(a: np.ndarray, b: np.ndarray, count: int, magnitude: float) -> bool:
    return bool(np.all(np.abs(a - b) <= SUM_TOLERANCE * max(count, 1) * max(magnitude, 1.0)))


def compare_mesh(site: str, written: MeshSummary | None, report: dict) -> list[Finding]:
    """Findings for one mesh: Gazebo's reading of it against the file's content (None:
    the file could not be read here, so only the loader's failure can be judged)."""
    if not report.get("ok"):
        why = (f"signal {report['signal']}" if "signal" in report
               else report.get("error") or f"exit {report.get('exit')}")
        return [finding("GZ001", site, f"Gazebo's mesh loader failed on this file ({why})")]
    if written is None:
        return []
    seen = probed_summary(report)
    out = []
    if seen.triangles != written.triangles:
        out.append(finding("GZ002", site, f"Gazebo reads {seen.triangles} triangles, the file has {written.triangles}"))
    magnitude = float(np.abs(np.concatenate([written.lo, written.hi])).max(initial=0.0))
    if (seen.corners != written.corners
            or not _sums_agree(seen.corner_sum, written.corner_sum, written.corners, magnitude)
            or not _sums_agree(seen.corner_sq, written.corner_sq, written.corners, magnitude**2)):
        out.append(finding("GZ003", site, "Gazebo's triangle corners are not the file's: "
                           f"{seen.corners} corners summing to {np.round(seen.corner_sum, 6).tolist()}, "
                           f"the file {written.corners} summing to {np.round(written.corner_sum, 6).tolist()}"))
    if written.corners and (np.abs(seen.lo - written.lo).max() > BOUNDS_TOLERANCE_M
                            or np.abs(seen.hi - written.hi).max() > BOUNDS_TOLERANCE_M):
        out.append(finding("GZ004", site, f"Gazebo's bounds {np.round(seen.lo, 6).tolist()}..{np.round(seen.hi, 6).tolist()}"
                           f" differ from the file's {np.round(written.lo, 6).tolist()}..{np.round(written.hi, 6).tolist()}"))
    if written.normals and (seen.normals != written.normals
                            or not _sums_agree(seen.normal_sum, written.normal_sum, written.normals, 1.0)):
        out.append(finding("GZ005", site, f"Gazebo's normals differ from the file's ({seen.normals} of {written.normals} corners,"
                           f" sums {np.round(seen.normal_sum, 6).tolist()} against {np.round(written.normal_sum, 6).tolist()})"))
    # gz-common flips V as it loads (LoadTexCoords: 1 - v), from COLLADA's bottom-left
    # image origin to OGRE's top-left one: the same texel, so compare with it flipped.
    flipped_uv_sum = np.array([written.uv_sum[0], written.uvs - written.uv_sum[1]])
    if written.uvs and (seen.uvs != written.uvs
                        or not _sums_agree(seen.uv_sum, flipped_uv_sum, written.uvs, 1.0)):
        out.append(finding("GZ005", site, f"Gazebo's texture coordinates differ from the file's ({seen.uvs} of {written.uvs} corners)"))
    return out


def compare_model_bounds(site: str, probed: list, expected: list, slack_m: float) -> list[Finding]:
    """probed: [[lo], [hi]] of a model's visuals as Gazebo placed its meshes; expected:
    the manifest's bounds. Both in the model frame."""
    gap = float(np.abs(np.asarray(probed, dtype=np.float64) - np.asarray(expected, dtype=np.float64)).max())
    if gap <= slack_m:
        return []
    return [finding("GZ006", site, f"the model's visual bounds in Gazebo {np.round(probed, 4).tolist()} differ from"
                    f" the manifest's {np.round(expected, 4).tolist()} by {gap:.4g} m (allowed {slack_m:.4g} m)")]


def world_findings(site: str, figures: dict, joints: int = 0) -> list[Finding]:
    """sdformat's errors and the parse budget of a world; `joints`: the joints dartsim
    built (the switches' moving parts), which the budget finding names."""
    out = [finding("GZ007", site, f"sdformat: {message}") for message in figures.get("errors", [])]
    # memory, not time: the parse time follows the machine's load (bench reports it)
    peak = float(figures["peak_rss_mb"])
    if peak > PARSE_BUDGET_MB:
        moving = (f"; its {joints:,} joints (the switches' moving parts) take about {moving_parts_mb(joints):.0f} MB"
                  " of it: site.toml "
                  '[gazebo] moving_parts = "none", or a list of the tags whose switches must move, keeps the '
                  "others at rest") if joints else ""
        out.append(finding("GZ008", site, f"parsing the world takes {peak:.0f} MB (budget {PARSE_BUDGET_MB:.0f} MB;"
                           f" {figures['parse_s']:.1f} s on this machine now){moving}"))
    return out


def physics_findings(site: str, physics: dict) -> list[Finding]:
    """dartsim's verdict on the world: every shape and joint built, the world stepped."""
    if not physics or (physics.get("ok") and not physics.get("failed_shapes") and not physics.get("failed_joints")):
        return []
    why = physics.get("error") or "; ".join(f"{physics.get(k)} {what} failed" for k, what in (
        ("failed_shapes", "shapes"), ("failed_joints", "joints")) if physics.get(k))
    return [finding("GZ011", site, f"dartsim could not build the world as gz-sim would: {why}")]


def mesh_findings(paths: list[Path], reports: dict[str, dict], site_of) -> list[Finding]:
    """Compare each written mesh with the probe's report of it; site_of(path) -> site."""
    out = []
    for path in paths:
        report = reports.get(str(path))
        if report is None:
            out.append(finding("GZ009", site_of(path), "the probe has no report of this mesh"))
            continue
        try:
            written = written_summary(path)
        except (KeyError, ValueError, IndexError, AttributeError, etree.XMLSyntaxError) as e:
            out.append(finding("GZ010", site_of(path), f"the file's triangles cannot be read: {type(e).__name__}: {e}"))
            if not report.get("ok"):
                out.extend(compare_mesh(site_of(path), None, report))
            continue
        out.extend(compare_mesh(site_of(path), written, report))
    return out


# --- a build --------------------------------------------------------------------------

@dataclass
class BuildCheck:
    """What the probe found in a build: findings by asset id (package meshes and model
    bounds) and for the scene (the world), the world's entity counts (the same in every
    run) and its measured figures (parse time and memory, physics: these vary)."""

    assets: dict[str, list[Finding]]
    scene: list[Finding]
    world: dict
    figures: dict
    missing: dict | None = None  # the report's "skipped" row when the probe is not built


def _packages_world(folder: Path, models: list[str]) -> Path:
    """A world that includes each model once, at the origin: sdformat reads each
    model.sdf as a world of placements would."""
    includes = "".join(f"<include><uri>model://{m}</uri><name>{m}</name></include>" for m in models)
    path = folder / "packages.sdf"
    path.write_text(f'<?xml version="1.0"?><sdf version="1.9"><world name="packages">{includes}</world></sdf>\n')
    return path


def _model_findings(report: dict, manifests: dict[str, tuple[str, int, dict]]) -> dict[str, list[Finding]]:
    """Each package model's visual bounds as Gazebo placed its meshes, against its
    manifest: equal for a package (LOD 0), inside them by the level's measured error
    for a LOD variant (its merged meshes have tighter boxes than its parts')."""
    out: dict[str, list[Finding]] = {}
    for model in report.get("models", []):
        asset, level, manifest = manifests[model["name"]]
        if "visual_bounds" not in model or not manifest.get("bounds"):
            continue
        probed = np.asarray(model["visual_bounds"], dtype=np.float64)
        expected = np.asarray(manifest["bounds"], dtype=np.float64)
        if level == 0:
            found = compare_model_bounds(model["name"], probed, expected, MODEL_BOUNDS_SLACK_M)
        else:
            errors = {row.get("level"): float(row.get("error_m", 0.0)) for row in manifest.get("lods", [])}
            slack = errors.get(level, 0.0) + MODEL_BOUNDS_SLACK_M
            inside = bool(np.all(probed[0] >= expected[0] - slack) and np.all(probed[1] <= expected[1] + slack))
            found = [] if inside else compare_model_bounds(model["name"], probed, expected, slack)
        out.setdefault(asset, []).extend(found)
    return out


def check_build(models: Path, world: Path | None, packages: dict[str, tuple[Path, dict, list[Path]]],
                scratch: Path, physics_s: float = 1.0) -> BuildCheck:
    """Probe every package (its model and variants, each mesh) and the world.

    packages: asset id -> (package folder, manifest, LOD variant folders). scratch: a
    folder for the probe's own world of packages."""
    manifests, meshes = {}, {}
    root = models.resolve()
    for asset, (folder, manifest, variants) in packages.items():
        for model in [folder, *variants]:
            manifests[model.name] = (asset, _variant_level(model.name), manifest)
        for path in sorted((folder / "meshes").glob("*.dae")):
            meshes[path.resolve()] = asset
    report = probe_world(_packages_world(scratch, sorted(manifests)), [models]) if manifests else {}
    found: dict[str, list[Finding]] = {a: [] for a in packages}
    for asset, rows in _model_findings(report, manifests).items():
        found[asset].extend(rows)
    # the packages' world loaded the meshes its models use; the rest (the whole-model
    # files the scene's world draws, collision meshes a primitive stands in for) are
    # loaded on their own
    reports = {str(Path(k).resolve()): v for k, v in report.get("meshes", {}).items()}
    unread = [p for p in meshes if str(p) not in reports]
    reports.update({str(Path(k).resolve()): v for k, v in probe_meshes(unread).items()})
    for f in mesh_findings(list(meshes), reports, lambda p: f"{meshes[p]}/{p.relative_to(root / meshes[p])}"):
        found[f.site.split("/", 1)[0]].append(f)

    scene, world_counts, figures = [], {}, {}
    if world is not None:
        seen = probe_world(world, [models], meshes=False, physics_s=physics_s)
        figures = {"world": {k: seen["world"][k] for k in ("parse_s", "parse_cpu_s", "peak_rss_mb") if k in seen["world"]},
                   "physics": seen.get("physics", {})}
        world_counts = {k: seen["world"][k] for k in ("models", "links", "visuals", "collisions")}
        scene += world_findings(world.name, seen["world"], seen.get("physics", {}).get("joints", 0))
        for model in seen.get("models", []):
            for use in model["meshes"]:
                if not use["path"]:
                    scene.append(finding("GZ009", f"{world.name}/{model['name']}", f"{use['uri']} does not resolve"))
        scene += _scene_mesh_findings(world, seen)
        scene += physics_findings(world.name, seen.get("physics", {}))
    return BuildCheck(found, scene, world_counts, figures)


def _scene_mesh_findings(world: Path, seen: dict) -> list[Finding]:
    """The meshes the world names beside itself (its collision cells), as Gazebo's
    loader reads them against what the files hold; the packages' meshes are checked
    with their packages."""
    folder = world.parent.resolve()
    paths = sorted({Path(use["path"]).resolve() for model in seen.get("models", []) for use in model["meshes"]
                    if use["path"] and Path(use["path"]).resolve().is_relative_to(folder)})
    reports = {str(Path(k).resolve()): v for k, v in probe_meshes(paths).items()}
    return mesh_findings(paths, reports, lambda path: f"{world.name}/{path.relative_to(folder)}")


def _variant_level(name: str) -> int:
    """LOD level of a model folder: <id>__lod<k>, else 0."""
    head, sep, tail = name.rpartition("__lod")
    return int(tail) if sep and tail.isdigit() else 0
