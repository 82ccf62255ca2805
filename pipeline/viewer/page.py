"""build/viewer/: the pages and what they read besides the scene.

- index.html + app/viewer.js: the scene .glb in three.js (app/ holds the page's own
  script and style, copied from viewer/static/).
- globe.html + app/globe.js: the tileset on the globe in CesiumJS.
- data/twin.json: what the pages need that the scene files do not say: the site's
  clock and sun table, the LOD rule's settings, each placed model's LOD errors,
  bounds and state bindings (from the manifests), the inspection points as ENU
  cameras, the scenarios whose runs the page can play (which node output drives
  which placement's variable), and the paths of the scene files relative to the page.
- data/sun.bin: the sun table (viewer.sun_table).

Everything the pages fetch is relative to build/viewer/, so any static server of
build/ serves them (`twin view`, `python -m http.server`).
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from pathlib import Path

import numpy as np

from .. import config
from ..errors import UserError
from . import sun_table

STATIC = Path(__file__).resolve().parent / "static"
PAGES = ("index.html", "globe.html")
APP = ("viewer.js", "globe.js", "renderer.js", "twin.css")
BINDING_KEYS = ("variable", "effect", "target", "link", "domain", "range", "axis", "shape_key", "materials", "thresholds",
                "rest_pose")


def static_files() -> list[Path]:
    """The pages' own files (the viewer task's inputs: code_version hashes .py only)."""
    return [STATIC / name for name in PAGES + APP]


def inspection_cameras(site: config.Site, record: dict, manifests: dict[str, dict]) -> list[dict]:
    """Each inspection point as an eye (ENU) looking at its target placement: at the
    target's state-bound visual (a gauge) nearest to the eye where it has any, else
    level from the eye at the target's position; the site origin without a target."""
    from ..georef import Georeferencer
    from ..scene.placements import inspection_points_enu, yaw_matrix

    origin = record["origin"]
    georef = Georeferencer(site, (origin["latitude_deg"], origin["longitude_deg"], origin["height_m"]))
    eyes = inspection_points_enu(site, georef)
    by_tag = {p["tag"]: p for p in record["placements"]}
    out = []
    for point, eye in zip(site.inspection_points, eyes):
        target = by_tag.get(point.target) if point.target else None
        look = np.array(target["enu"] if target else (0.0, 0.0, 0.0), dtype=np.float64)
        look[2] = eye[2]
        bound = _bound_points(manifests.get(target["asset"], {})) if target else np.zeros((0, 3))
        if len(bound):
            pose = yaw_matrix(target["yaw_rad"], target["enu"])
            world = bound @ pose[:3, :3].T + pose[:3, 3]
            look = world[np.argmin(np.linalg.norm(world - eye, axis=1))]
        out.append({"name": point.name, "target": point.target, "eye": [round(float(v), 6) for v in eye],
                    "look_at": [round(float(v), 6) for v in look]})
    return out


def _bound_points(manifest: dict) -> np.ndarray:
    """(k, 3) positions, in the model frame, of the visuals the state bindings move."""
    links = {link["name"]: np.array(link["pose"], dtype=np.float64).reshape(4, 4) for link in manifest.get("links", [])}
    points = [(links.get(b["link"], np.eye(4)) @ np.array(b["rest_pose"], dtype=np.float64).reshape(4, 4))[:3, 3]
              for b in manifest.get("bindings", []) if b.get("rest_pose") and b.get("link")]
    return np.array(points).reshape(-1, 3)


def scenario_runs(sources: Path, zone) -> list[dict]:
    """The sources' scenarios as the page plays their runs: per placement STATE and
    variable the node output that feeds the render node, the sun node, the clock.
    A scenario that does not load is listed with its error (its run cannot exist)."""
    from ..runtime import graph

    out = []
    for path in sorted((Path(sources) / "scenarios").glob("*.toml")):
        try:
            s = graph.load_scenario(path, zone)
            g = graph.Graph(s)
        except UserError as e:
            out.append({"file": path.name, "error": str(e)})
            continue
        renders = [n for n in g.order if g.nodes[n].type_name == "render"]
        suns = sorted(n for n in g.nodes if g.nodes[n].type_name == "sun")
        render = renders[0] if renders else None
        sun = (g.nodes[render].p["sun"] if render and g.nodes[render].p["sun"] else (suns[0] if len(suns) == 1 else None))
        inputs: dict[str, dict[str, str]] = {}
        for e in (g.feeds[render] if render else []):
            state, _, variable = e.dst[1].partition(".")
            inputs.setdefault(state, {})[variable] = ".".join(e.src)
        out.append({"file": path.name, "name": s.name, "description": s.description,
                    "start_utc_s": s.start.timestamp(), "step_s": s.step_s, "duration_s": s.duration_s,
                    "states": f"../runs/{s.name}/states.jsonl", "inputs": inputs, "sun": sun})
    return out


def asset_record(m: dict) -> dict:
    from .tiles import levels_of

    return {"category": m.get("category", ""), "description": m.get("description", ""),
            "errors_m": levels_of(m), "bounds": m["bounds"],
            "bindings": [{k: b.get(k) for k in BINDING_KEYS} for b in m.get("bindings", []) if b.get("link")]}


def twin_json(site: config.Site, record: dict, manifests: dict[str, dict], sources: Path) -> dict:
    year = dt.date.fromisoformat(site.date).year
    origin = record["origin"]
    described = sun_table.describe(origin["latitude_deg"], origin["longitude_deg"], year, site.zone)
    return {
        "site": site.name, "description": site.description, "crs": site.crs, "date": site.date,
        "timezone": site.timezone, "origin": origin, "built_sun": record.get("sun"),
        "scene": f"../scene/{site.name}.glb", "placements": "../scene/placements.json",
        "tiles": "../tiles/tileset.json",
        "lod": {"screen_tolerance_px": site.screen_tolerance_px, "reference_hfov_rad": site.reference_hfov_rad,
                "reference_width_px": site.reference_width_px},
        "assets": {a: asset_record(m) for a, m in sorted(manifests.items())},
        "inspection_points": inspection_cameras(site, record, manifests),
        "scenarios": scenario_runs(sources, site.zone),
        **described,
    }


def write(staging: Path, *, sources: Path, record: dict, manifests: dict[str, dict], sun_memo=None) -> dict:
    """viewer/ (without lib/) into `staging`. `sun_memo`: a builder FileMemo that keeps
    the sun table by site and year (the ephemeris is the task's slow part)."""
    site = config.load_site(Path(sources) / "site.toml")
    viewer = Path(staging) / "viewer"
    (viewer / "app").mkdir(parents=True, exist_ok=True)
    (viewer / "data").mkdir(exist_ok=True)
    for name in PAGES:
        shutil.copyfile(STATIC / name, viewer / name)
    for name in APP:
        shutil.copyfile(STATIC / name, viewer / "app" / name)
    data = twin_json(site, record, manifests, Path(sources))
    (viewer / "data" / "twin.json").write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    sun = data["sun"]
    table = viewer / "data" / sun["file"]
    key = json.dumps([sun["latitude_deg"], sun["longitude_deg"], sun["year"], sun["step_s"]])
    if sun_memo is None or not sun_memo.link(key, table):
        table.write_bytes(sun_table.table_bytes(sun["latitude_deg"], sun["longitude_deg"], sun["year"]))
        if sun_memo is not None:
            sun_memo.keep(key, table)
    return {"placements": len(record["placements"]), "inspection_points": len(data["inspection_points"]),
            "scenarios": [s.get("name", s["file"]) for s in data["scenarios"]], "sun_samples": sun["count"]}
