"""`twin validate`: every check and every format owner's validator over a build, into
build/reports/ as validation.json (schemas/report.schema.json), validation.html and
junit.xml; wall-clock timings go to timings.json so the others stay byte-identical.

Counting rules:
- a finding counts at its rule's severity, except a finding on the *source* asset
  (before cleaning), which counts at most as a warning: the build repaired it or it
  appears again on the built asset, where it counts in full;
- an external validator that failed counts as an error; one that was skipped (tool not
  installed) is counted as skipped, never as passed.
"""

from __future__ import annotations

import dataclasses
import html
import json
import os
import re
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from lxml import etree

from ..errors import UserError
from ..files import atomic_write
from ..findings import RULES, Finding, finding
from . import external, gazebo
from .cache import ResultCache
from .checks import check_package

REPORT_FORMAT = 1
_LOD_VARIANT = re.compile(r"^(?P<base>.+)__lod\d+$")
# Two subprocess validators at a time: the machine running CI is often small.
_WORKERS = 2
_SDF_PROCESSES = 2  # the model files' sdformat checks: two children, each checking half


# --- gathering ------------------------------------------------------------------------


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _manifest_findings(manifest: dict) -> list[tuple[str, Finding]]:
    """(stage, finding) from a manifest's "findings": either {"source": [...],
    "built": [...]} or a plain list (the built asset's)."""
    raw = manifest.get("findings") or []
    staged = raw.items() if isinstance(raw, dict) else [("built", raw)]
    out = []
    for stage, items in staged:
        for d in items if isinstance(items, list) else []:
            try:
                out.append((str(stage), Finding.from_dict(d)))
            except (KeyError, TypeError):
                out.append(("built", finding("PKG006", manifest.get("asset", "?"),
                                             f"malformed finding in manifest.json: {d!r}"[:300])))
    return out


def _counted(stage: str, severity: str) -> str:
    return "warning" if stage == "source" and severity == "error" else severity


def _finding_row(stage: str, f: Finding) -> dict:
    return {"code": f.code, "severity": f.severity, "counted": _counted(stage, f.severity),
            "site": f.site, "message": f.message, "stage": stage}


def _sort_rows(rows: list[dict]) -> list[dict]:
    return sorted(rows, key=lambda r: (r["stage"], r["site"], r["code"], r["message"]))


def _joint_rows(manifest: dict) -> list[dict]:
    return sorted(({"name": str(j.get("name")), "type": str(j.get("type")), "parent": str(j.get("parent")),
                    "child": str(j.get("child")), "lower": j.get("lower"), "upper": j.get("upper"),
                    "axis": [float(a) for a in j.get("axis", [])]}
                   for j in manifest.get("joints", []) if isinstance(j, dict)), key=lambda j: j["name"])


def _lod_rows(manifest: dict) -> list[dict]:
    rows, seen = [], set()
    for lod in manifest.get("lods", []):
        # the manifest writes LOD0 itself; an asset whose lods also name level 0
        # would show it twice
        if isinstance(lod, dict) and int(lod.get("level", 0)) not in seen:
            seen.add(int(lod.get("level", 0)))
            rows.append({"level": int(lod.get("level", 0)), "triangles": int(lod.get("triangles", 0)),
                         "error_m": float(lod.get("error_m", 0.0)), "budget_m": float(lod.get("budget_m", 0.0)),
                         "within_budget": bool(lod.get("within_budget", True))})
    return sorted(rows, key=lambda r: r["level"])


def _root(joints: list[dict], links: list[str]) -> str | None:
    children = {j["child"] for j in joints}
    roots = [n for n in links if n not in children]
    return roots[0] if len(roots) == 1 else None


# --- external validators --------------------------------------------------------------


class _Clock:
    """Wall time per validator, for timings.json only; each run is a step of
    `progress` (progress.Bar, or None)."""

    def __init__(self, progress=None):
        self.seconds: dict[str, float] = {}
        self.progress = progress

    def expect(self, steps: int) -> None:
        if self.progress is not None:
            self.progress.add(steps)

    def run(self, key: str, fn, *args):
        try:
            return self.time(key, fn, *args)
        finally:
            self.step(key)

    def time(self, key: str, fn, *args):
        """fn(*args), timed and not a step (its steps are its own)."""
        t = time.perf_counter()
        try:
            return fn(*args)
        finally:
            self.seconds[key] = self.seconds.get(key, 0.0) + time.perf_counter() - t

    def step(self, key: str) -> None:
        if self.progress is not None:
            self.progress.step(key)


def _usd_references(path: Path) -> external.ExternalResult:
    """The scene stage with every reference resolved: composition errors or a
    reference to a missing layer fail it (UsdValidation alone does not look)."""
    name = "USD composition"
    try:
        from pxr import Usd
    except ImportError as e:
        return external.ExternalResult(name, str(path), "skipped", (f"not installed: {e}",), external._USD_HINT)
    stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    if stage is None:
        return external.ExternalResult(name, str(path), "failed", ("USD could not open the file",))
    messages = [str(e.GetErrorAsString()) for e in stage.GetCompositionErrors()]
    return external.ExternalResult(name, str(path), "failed" if messages else "passed", tuple(sorted(messages)))


def _run_external(out: Path, sdf: list[Path], world: Path | None, usd: list[Path], scene_usd: Path | None,
                  glb: list[Path], dae: list[Path], clock: _Clock,
                  digests: dict[str, str] | None = None) -> dict[str, list[external.ExternalResult]]:
    """Every validator on its files; returns file (as given) -> results. `digests`:
    str(path) -> content hash; COLLADA files of the same bytes are checked once (the
    schema's verdict names no path)."""
    models = out / "models"
    results: dict[str, list[external.ExternalResult]] = {}

    def add(path: Path, r: external.ExternalResult):
        results.setdefault(str(path), []).append(r)

    alike: dict[str, list[Path]] = {}
    for p in dae:
        alike.setdefault((digests or {}).get(str(p)) or str(p), []).append(p)

    with ThreadPoolExecutor(max_workers=_WORKERS) as pool:
        # ign sdf (child processes checking many files each) and the COLLADA schema run
        # beside USD, which stays on this thread: pxr stages are not shared across threads here.
        sdf_job = pool.submit(clock.time, "ign sdf", external.ign_sdf_files, sdf, [models], _SDF_PROCESSES,
                              lambda: clock.step("ign sdf"))
        world_job = pool.submit(clock.run, "ign sdf", external.ign_sdf_world, world, [models]) if world else None
        dae_jobs = {pool.submit(clock.run, "collada schema", external.collada_schema, same[0]): same
                    for same in alike.values()}
        for p in usd + ([scene_usd] if scene_usd else []):
            add(p, clock.run("usd validation", external.usd_validation, p))
        if scene_usd:
            add(scene_usd, clock.run("usd validation", _usd_references, scene_usd))
        for p, r in zip(glb, clock.run("gltf validator", external.gltf_validator, glb)):
            add(p, r)
        for p, r in zip(sdf, sdf_job.result()):
            add(p, r)
        if world_job:
            add(world, world_job.result())
        for fut, same in dae_jobs.items():
            r = fut.result()
            for p in same:
                add(p, dataclasses.replace(r, target=str(p)))
    return results


def _ext_rows(out: Path, paths: list[Path], results: dict) -> list[dict]:
    root = str(out.resolve()) + os.sep
    rows = []
    for p in paths:
        for r in results.get(str(p), []):
            rel = os.path.relpath(Path(r.target).resolve(), out.resolve())
            rows.append({"validator": r.validator, "target": rel, "status": r.status,
                         # absolute paths differ between checkouts; the report must not
                         "messages": [m.replace(root, "") for m in r.messages],
                         "install_hint": r.install_hint if r.status == "skipped" else ""})
    return sorted(rows, key=lambda r: (r["target"], r["validator"]))


# --- the report -----------------------------------------------------------------------


def _package_files(folder: Path) -> dict[str, list[Path]]:
    return {"usd": sorted(folder.glob("*.usdc")), "glb": sorted(folder.glob("*.glb")),
            "dae": sorted((folder / "meshes").glob("*.dae")) if (folder / "meshes").is_dir() else []}


def _scene_files(out: Path, placements: dict | None) -> tuple[str | None, dict[str, Path | None]]:
    scene = out / "scene"
    site = placements.get("site") if placements else None
    if site is None:
        worlds = sorted(scene.glob("*.sdf")) if scene.is_dir() else []
        site = worlds[0].stem if worlds else None
    if site is None:
        return None, {"sdf": None, "usda": None, "glb": None}
    return str(site), {ext: (scene / f"{site}.{ext}") if (scene / f"{site}.{ext}").is_file() else None
                       for ext in ("sdf", "usda", "glb")}


def _split_folders(models: Path) -> tuple[list[Path], dict[str, list[Path]]]:
    """(package folders, base name -> its LOD variant folders)."""
    folders = sorted(d for d in models.iterdir() if d.is_dir()) if models.is_dir() else []
    variants: dict[str, list[Path]] = {}
    packages = []
    for d in folders:
        m = _LOD_VARIANT.match(d.name)
        if m and not (d / "manifest.json").exists() and (models / m.group("base")).is_dir():
            variants.setdefault(m.group("base"), []).append(d)
        else:
            packages.append(d)
    return packages, variants


def _asset_entry(d: Path, manifest: dict, variants: list[Path], rows: list[dict], files: list[Path]) -> dict:
    joints = _joint_rows(manifest)
    links = [str(link.get("name")) for link in manifest.get("links", []) if isinstance(link, dict)]
    return {
        "id": d.name,
        "category": str(manifest.get("category", "")),
        "thumbnail": f"../models/{d.name}/thumbnail.png" if (d / "thumbnail.png").is_file() else None,
        "lods": _lod_rows(manifest),
        "links": links,
        "root": _root(joints, links),
        "joints": joints,
        "lod_models": sorted(v.name for v in variants),
        "findings": _sort_rows(rows),
        "_files": files,
    }


def build_report(sources: Path, out: Path, progress=None) -> tuple[dict, dict]:
    """(validation.json content, timings). Raises UserError when nothing was built.
    `progress`: a progress.Bar that each check and validator run advances.
    A package judged before as it is now (validate.cache) takes its verdicts from
    build/.validate/; the others, and the scene, are judged now."""
    out = Path(out)
    models = out / "models"
    packages, variants = _split_folders(models)
    if not packages:
        raise UserError(str(out), None, "nothing built yet: run twin build")
    clock = _Clock(progress)
    cache = ResultCache(out)
    started = time.perf_counter()
    keys = {d.name: cache.key(d.name, [d, *variants.get(d.name, [])]) for d in packages}
    clock.seconds["cache keys"] = time.perf_counter() - started
    cached = {name: hit for name, key in keys.items() if (hit := cache.get(key)) is not None}
    clock.expect(len(packages) + sum(map(len, variants.values())))  # package checks
    assets = []
    fresh: dict[str, list[Path]] = {"sdf": [], "usd": [], "glb": [], "dae": []}
    for d in packages:
        manifest = _read_json(d / "manifest.json") or {}
        rows = [_finding_row(stage, f) for stage, f in _manifest_findings(manifest)]
        for folder in [d, *variants.get(d.name, [])]:
            rows += [_finding_row("package", f) for f in clock.run("package checks", check_package, folder)]
        files = _package_files(d)
        files["sdf"] = [f / "model.sdf" for f in [d, *variants.get(d.name, [])] if (f / "model.sdf").is_file()]
        if d.name not in cached:
            for kind, paths in files.items():
                fresh[kind] += paths
        assets.append(_asset_entry(d, manifest, variants.get(d.name, []), rows,
                                   files["sdf"] + files["usd"] + files["glb"] + files["dae"]))

    placements = _read_json(out / "scene" / "placements.json")
    site, scene_files = _scene_files(out, placements)
    glb = fresh["glb"] + ([scene_files["glb"]] if scene_files["glb"] else [])
    # ign sdf each, the world's, COLLADA each, USD each (the scene's twice), glTF at once, Gazebo
    scene_usd = 2 if scene_files["usda"] else 0
    distinct_dae = len({cache.hashes.get(str(p), str(p)) for p in fresh["dae"]})
    clock.expect(len(fresh["sdf"]) + bool(scene_files["sdf"]) + distinct_dae + len(fresh["usd"])
                 + scene_usd + 1 + 1)
    probed_packages = [d for d in packages if d.name not in cached]
    with ThreadPoolExecutor(max_workers=1) as side:
        # Gazebo's own loaders (processes of their own) beside the format validators
        probe = side.submit(clock.run, "gazebo probe", _gazebo, models, scene_files["sdf"], probed_packages, variants)
        results = _run_external(out, fresh["sdf"], scene_files["sdf"], fresh["usd"], scene_files["usda"], glb,
                                fresh["dae"], clock, cache.hashes)
        probed = probe.result()

    for a in assets:
        if a["id"] in cached:
            ext, found = cached[a["id"]]
            for r in ext:
                results.setdefault(str(Path(r.target)), []).append(r)
        else:
            found = probed.assets.get(a["id"], [])
            if not probed.missing:  # no probe, no Gazebo verdict to keep
                cache.put(keys[a["id"]], [r for p in a["_files"] for r in results.get(str(p), [])], found)
        a["external"] = _ext_rows(out, a.pop("_files"), results)
        a["findings"] = _sort_rows(a["findings"] + [_finding_row("package", f) for f in found])
    cache.save()
    scene_rows = []
    for d in (placements or {}).get("findings", []):
        try:
            scene_rows.append(_finding_row("scene", Finding.from_dict(d)))
        except (KeyError, TypeError):
            continue
    scene = {
        "site": site,
        "present": placements is not None,
        "placements": len((placements or {}).get("placements", [])),
        "lod_histogram": {str(k): int(v) for k, v in sorted((placements or {}).get("lod_histogram", {}).items())},
        "findings": _sort_rows(scene_rows + [_finding_row("scene", f) for f in probed.scene]),
        "external": _ext_rows(out, [p for p in scene_files.values() if p is not None], results),
        "gazebo": probed.world,
    }
    if probed.missing:
        scene["external"] = _sort_rows_ext(scene["external"] + [probed.missing])
    report = {
        "format": REPORT_FORMAT,
        "summary": _summary(assets, scene),
        "rules": {code: {"severity": s, "group": g, "description": d} for code, (s, g, d) in sorted(RULES.items())},
        "assets": sorted(assets, key=lambda a: a["id"]),
        "scene": scene,
    }
    timings = {k: round(v, 6) for k, v in sorted(clock.seconds.items())}
    timings["cached_packages"] = len(cached)
    if probed.figures:
        timings["gazebo"] = probed.figures
    return report, timings


def _gazebo(models: Path, world: Path | None, packages: list[Path], variants: dict[str, list[Path]]):
    """validate.gazebo.check_build on this build; without the probe, a skipped row that
    says how to build it (never a clean report for want of the tool)."""
    if not gazebo.available():
        row = {"validator": "gazebo probe", "target": "scene", "status": "skipped", "messages": ["tools/gzprobe is not built"],
               "install_hint": gazebo.PROBE_HINT}
        return gazebo.BuildCheck({}, [], {}, {}, missing=row)
    manifests = {d.name: (d, _read_json(d / "manifest.json") or {}, variants.get(d.name, [])) for d in packages}
    with tempfile.TemporaryDirectory(prefix="gzprobe-") as scratch:
        return gazebo.check_build(models, world, manifests, Path(scratch))


def _sort_rows_ext(rows: list[dict]) -> list[dict]:
    return sorted(rows, key=lambda r: (r["target"], r["validator"]))


def _summary(assets: list[dict], scene: dict) -> dict:
    findings = [f for a in assets for f in a["findings"]] + scene["findings"]
    ext = [r for a in assets for r in a["external"]] + scene["external"]
    by_code: dict[str, int] = {}
    for f in findings:
        by_code[f["code"]] = by_code.get(f["code"], 0) + 1
    status = {s: sum(r["status"] == s for r in ext) for s in ("passed", "failed", "skipped")}
    return {
        "errors": sum(f["counted"] == "error" for f in findings) + status["failed"],
        "warnings": sum(f["counted"] == "warning" for f in findings),
        "infos": sum(f["counted"] == "info" for f in findings),
        "skipped": status["skipped"],
        "validators": status,
        "assets": len(assets),
        "by_code": dict(sorted(by_code.items())),
    }


# --- writers --------------------------------------------------------------------------


def to_json(report: dict) -> bytes:
    return (json.dumps(report, sort_keys=True, indent=1, allow_nan=False) + "\n").encode()


def _targets(report: dict):
    """(classname target, findings, applicable groups) of every checked target."""
    for a in report["assets"]:
        yield a["id"], a["findings"], ("geometry", "hierarchy", "package")
    if report["scene"]["present"]:
        yield f"scene.{report['scene']['site']}", report["scene"]["findings"], ("placement", "conductor")


def to_junit(report: dict) -> bytes:
    """One testcase per rule per target (failed when it has a counted error) and one
    per external validator run per file (skipped stays skipped)."""
    suites = etree.Element("testsuites", name="twin validate")
    for target, findings, groups in _targets(report):
        suite = etree.SubElement(suites, "testsuite", name=target)
        for code, rule in report["rules"].items():
            if rule["group"] not in groups:
                continue
            case = etree.SubElement(suite, "testcase", classname=f"{rule['group']}.{target}",
                                    name=f"{code} {rule['description']}")
            hits = [f for f in findings if f["code"] == code]
            text = "\n".join(f"[{f['stage']}] {f['site']}: {f['message']}" for f in hits)
            if any(f["counted"] == "error" for f in hits):
                etree.SubElement(case, "failure", message=f"{code} at {len(hits)} sites", type=code).text = text
            elif hits:
                etree.SubElement(case, "system-out").text = text
        _suite_counts(suite)
    ext = etree.SubElement(suites, "testsuite", name="external validators")
    rows = [r for a in report["assets"] for r in a["external"]] + report["scene"]["external"]
    for r in sorted(rows, key=lambda r: (r["validator"], r["target"])):
        case = etree.SubElement(ext, "testcase", classname=f"external.{r['validator']}", name=r["target"])
        if r["status"] == "failed":
            etree.SubElement(case, "failure", message=f"{r['validator']} rejected {r['target']}",
                             type="external").text = "\n".join(r["messages"])
        elif r["status"] == "skipped":
            etree.SubElement(case, "skipped", message="; ".join(r["messages"] + [r["install_hint"]]))
    _suite_counts(ext)
    return etree.tostring(suites, xml_declaration=True, encoding="utf-8", pretty_print=True)


def _suite_counts(suite) -> None:
    cases = suite.findall("testcase")
    suite.set("tests", str(len(cases)))
    suite.set("failures", str(sum(c.find("failure") is not None for c in cases)))
    suite.set("skipped", str(sum(c.find("skipped") is not None for c in cases)))
    suite.set("errors", "0")


_CSS = """body{font:14px/1.4 sans-serif;margin:1.5em;color:#222}table{border-collapse:collapse;margin:.4em 0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}.error{background:#fdd}.warning{background:#ffe9b3}
.info{background:#e6f0ff}.asset{border-top:2px solid #888;margin-top:1.5em;overflow:auto}
.asset img{float:right;width:192px;border:1px solid #ccc;margin-left:1em}.passed{color:#060}.failed{color:#b00}
.skipped{color:#a60}.summary span{margin-right:1.5em;font-weight:bold}ul.tree{margin:.2em 0}"""

_JS = """function applyFilter(){var s=document.getElementById('sev').value,
c=document.getElementById('code').value.trim().toUpperCase();
document.querySelectorAll('tr.finding').forEach(function(r){
var ok=(!s||r.dataset.severity===s)&&(!c||r.dataset.code.indexOf(c)===0);r.style.display=ok?'':'none';});}"""


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _findings_table(rows: list[dict]) -> str:
    if not rows:
        return "<p class='none'>no findings</p>"
    body = "".join(
        f"<tr class='finding {_e(f['counted'])}' data-severity='{_e(f['counted'])}' data-code='{_e(f['code'])}'>"
        f"<td>{_e(f['code'])}</td><td>{_e(f['counted'])}</td><td>{_e(f['stage'])}</td><td>{_e(f['site'])}</td>"
        f"<td>{_e(f['message'])}</td></tr>" for f in rows)
    return ("<table class='findings'><tr><th>code</th><th>severity</th><th>stage</th><th>site</th>"
            f"<th>message</th></tr>{body}</table>")


def _external_table(rows: list[dict]) -> str:
    if not rows:
        return "<p>no validator ran</p>"
    body = "".join(f"<tr><td>{_e(r['validator'])}</td><td>{_e(r['target'])}</td>"
                   f"<td class='{_e(r['status'])}'>{_e(r['status'])}</td>"
                   f"<td>{_e('; '.join(r['messages'])[:600])}</td></tr>" for r in rows)
    return f"<table class='external'><tr><th>validator</th><th>file</th><th>status</th><th>messages</th></tr>{body}</table>"


def _joint_tree(asset: dict) -> str:
    """Nested lists from the root link down through each joint."""
    by_parent: dict[str, list[dict]] = {}
    for j in asset["joints"]:
        by_parent.setdefault(j["parent"], []).append(j)

    def below(link: str, seen: frozenset) -> str:
        items = ""
        for j in sorted(by_parent.get(link, []), key=lambda j: j["name"]):
            if j["child"] in seen:  # a loop: say so instead of recursing forever
                items += f"<li>{_e(j['name'])} ({_e(j['type'])}) -&gt; {_e(j['child'])} (loop)</li>"
                continue
            limits = "" if j["lower"] is None else f" [{_e(j['lower'])}, {_e(j['upper'])}]"
            items += (f"<li>{_e(j['name'])} ({_e(j['type'])}{limits}) -&gt; <b>{_e(j['child'])}</b>"
                      f"{below(j['child'], seen | {j['child']})}</li>")
        return f"<ul class='tree'>{items}</ul>" if items else ""

    root = asset["root"]
    if root is None:
        return "<p>no single root link</p>" if asset["links"] else ""
    return f"<div class='joints'><b>{_e(root)}</b>{below(root, frozenset({root}))}</div>"


def _lod_table(lods: list[dict]) -> str:
    body = "".join(f"<tr class='{'' if l['within_budget'] else 'warning'}'><td>{l['level']}</td>"
                   f"<td>{l['triangles']}</td><td>{l['error_m']:.6g}</td><td>{l['budget_m']:.6g}</td></tr>"
                   for l in lods)
    return ("<table class='lods'><tr><th>LOD</th><th>triangles</th><th>error (m)</th><th>budget (m)</th></tr>"
            f"{body}</table>")


def to_html(report: dict) -> bytes:
    s = report["summary"]
    codes = sorted(s["by_code"])
    options = "".join(f"<option value='{_e(c)}'>" for c in codes)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>twin validate</title>",
        f"<style>{_CSS}</style><script>{_JS}</script></head><body>",
        "<h1>Validation report</h1>",
        f"<p class='summary'><span id='n-errors'>{s['errors']} errors</span><span>{s['warnings']} warnings</span>"
        f"<span>{s['skipped']} validators skipped</span><span>{s['validators']['passed']} validator runs passed"
        "</span></p>",
        "<p>severity <select id='sev' onchange='applyFilter()'><option value=''>all</option>"
        "<option>error</option><option>warning</option><option>info</option></select> code "
        f"<input id='code' list='codes' oninput='applyFilter()' placeholder='e.g. GEOM'><datalist id='codes'>"
        f"{options}</datalist></p>",
    ]
    sc = report["scene"]
    parts.append(f"<section id='scene'><h2>Scene {_e(sc['site'] or '(not built)')}</h2>"
                 f"<p>{sc['placements']} placements; LODs used: "
                 f"{_e(', '.join(f'LOD{k}: {v}' for k, v in sc['lod_histogram'].items()) or '-')}</p>"
                 f"{_findings_table(sc['findings'])}{_external_table(sc['external'])}</section>")
    for a in report["assets"]:
        img = (f"<img class='thumbnail' src='{_e(a['thumbnail'])}' alt='{_e(a['id'])} thumbnail'>"
               if a["thumbnail"] else "")
        parts.append(f"<section class='asset' id='asset-{_e(a['id'])}'>{img}<h2>{_e(a['id'])}</h2>"
                     f"<p>{_e(a['category'])}</p>{_lod_table(a['lods'])}<h3>Joints</h3>{_joint_tree(a)}"
                     f"<h3>Findings</h3>{_findings_table(a['findings'])}"
                     f"<h3>Validators</h3>{_external_table(a['external'])}</section>")
    parts.append("</body></html>\n")
    return "".join(parts).encode()


def validate_build(sources: Path, out: Path, progress=None) -> dict:
    """Write out/reports/{validation.json,validation.html,junit.xml,timings.json};
    return {"errors": n, "warnings": n, "skipped": n}. `progress`: build_report's."""
    report, timings = build_report(Path(sources), Path(out), progress)
    reports = Path(out) / "reports"
    reports.mkdir(parents=True, exist_ok=True)
    atomic_write(reports / "validation.json", to_json(report))
    atomic_write(reports / "validation.html", to_html(report))
    atomic_write(reports / "junit.xml", to_junit(report))
    atomic_write(reports / "timings.json", (json.dumps(timings, sort_keys=True, indent=1) + "\n").encode())
    s = report["summary"]
    return {"errors": s["errors"], "warnings": s["warnings"], "skipped": s["skipped"]}
