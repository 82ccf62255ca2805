"""`twin render --study`: the study's light conditions of one gauge (PAPER_NOTES.md;
the gauge, the camera and the conditions in sources/study.toml), with its metrics C, S
and H on the gauge's ROI, set against the shape of the study's Table 1."""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import config
from ..files import atomic_write
from ..runtime import camera as camera_model
from .. import sun as sun_model
from ..perception.metrics import measure
from .frames import render_shots, write_json
from ..perception.gauge import placed_dial
from ..geometry import rays
from ..geometry.pinhole import intrinsics, look_at, project
from .sensor import PhoneCamera
from ..runtime.site import Shot, BuiltSite, load_site

CONFIG = "study.toml"  # in the sources folder
NOON = "solar_noon"  # a condition's time: the site's solar noon on its date


@dataclass(frozen=True)
class StudyConfig:
    """sources/study.toml: the gauge, the camera and the conditions of the study."""

    path: Path
    target: str  # the placement whose main-tank gauge is read
    zoom: float
    distance_m: float
    max_obliquity: float  # rad, from the dial's normal
    faces_sun_of: str  # the condition whose sun the camera turns towards
    seed: int
    conditions: tuple[tuple[str, str], ...]  # (name, "HH:MM" or NOON), in the sequence's order


def load_study(path: Path) -> StudyConfig:
    """Read a study.toml (SOURCES/study.toml) against schemas/study.schema.json, then
    check what a schema cannot say; every problem at once, in one UserError naming
    the file and each key."""
    from ..errors import raise_all

    path = Path(path)
    data = config.read_config(path, "study")
    conditions = tuple((c["name"], c["time"]) for c in data["conditions"])
    raise_all(path, _problems(data, conditions))
    return StudyConfig(path, data["target"], float(data["zoom"]), float(data["distance_m"]),
                       math.radians(data["max_obliquity_deg"]), data["faces_sun_of"], data["seed"], conditions)


def _problems(data: dict, conditions: tuple[tuple[str, str], ...]) -> list[tuple[str, str]]:
    """Condition names used once, real times, faces_sun_of one of the conditions."""
    out, names = [], set()
    for i, (name, time) in enumerate(conditions):
        if name in names:
            out.append((f"conditions[{i}].name", f"{name!r}: a name used by no other condition is expected"))
        names.add(name)
        if time != NOON and _hhmm(time) is None:
            out.append((f"conditions[{i}].time", f"{time!r}: a local time \"HH:MM\" or \"{NOON}\" is expected"))
    if data["faces_sun_of"] not in names:
        out.append(("faces_sun_of", f"{data['faces_sun_of']!r}: the name of one of the conditions is expected"))
    return out


def _hhmm(text: str) -> dt.time | None:
    try:
        h, m = text.split(":")
        return dt.time(int(h), int(m)) if len(h) == 2 and len(m) == 2 else None
    except ValueError:
        return None


def study_times(site: BuiltSite, cfg: StudyConfig) -> list[tuple[str, dt.datetime]]:
    import astral
    import astral.sun

    from ..errors import UserError

    if site.zone is None:
        raise UserError(site.build / "scene" / "placements.json", "timezone",
                        "the study's local times need the site's time zone: site.toml [site] timezone, then rebuild")
    date = dt.date.fromisoformat(site.date)
    noon = astral.sun.noon(astral.Observer(site.origin[0], site.origin[1]), date, tzinfo=site.zone)
    out = []
    for i, (name, hhmm) in enumerate(cfg.conditions):
        if hhmm == NOON:
            out.append((name, noon.replace(microsecond=0)))
            continue
        try:
            out.append((name, config.local_time(dt.datetime.combine(date, _hhmm(hhmm)), site.zone)))
        except ValueError as e:
            raise UserError(cfg.path, f"conditions[{i}].time", str(e)) from None
    return out


def _ray_hits_box(origin: np.ndarray, direction: np.ndarray, length: float, pose: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray) -> bool:
    """Does the segment origin + t direction, t in [0, length], cross the box [lo, hi]
    of the model at `pose` (slab test in the model frame)?"""
    o = pose[:3, :3].T @ (origin - pose[:3, 3])
    d = pose[:3, :3].T @ direction
    return bool(rays.ray_box_entry(o, d, np.asarray(lo, float)[None], np.asarray(hi, float)[None])[0] <= length)


def _blocked(site: BuiltSite, origin: np.ndarray, direction: np.ndarray, length: float, skip: str = "") -> bool:
    """Does a built placement's bounding box (other than `skip`) cut the segment?"""
    for p in site.placements:
        m = site.manifests.get(p["asset"])
        if m is None or p["tag"] == skip or m.get("kind") == "terrain" or p["asset"].endswith("_terrain"):
            continue
        pose = site.pose(p)
        if np.linalg.norm(pose[:3, 3] - origin) > length + 40.0:
            continue
        if _ray_hits_box(origin, direction, length, pose, np.array(m["bounds"][0]), np.array(m["bounds"][1])):
            return True
    return False


def study_viewpoint(site: BuiltSite, sun: np.ndarray, cfg: StudyConfig) -> np.ndarray:
    """The study's camera pose: cfg.distance_m from the target's main-tank dial, at a
    phone's height (1.6 m above the reactor's level), turned from the dial's normal
    towards `sun` (the sun of cfg.faces_sun_of) as far as cfg.max_obliquity allows, so
    that the low sun faces the lens as much as the dial's orientation permits, while the
    line of sight to the dial and the sun itself stay clear of the built models' bounding
    boxes (a sun hidden behind the reactor would make no glare)."""
    p = site.placement(cfg.target)
    dial = placed_dial(site, cfg.target)
    centre, normal = dial.centre, dial.axis
    candidates = []
    for a in np.linspace(-cfg.max_obliquity, cfg.max_obliquity, 91):
        c, s = math.cos(a), math.sin(a)
        u = np.array([c * normal[0] - s * normal[1], s * normal[0] + c * normal[1], 0.0])
        eye = centre + cfg.distance_m * u
        eye[2] = p["enu"][2] + 1.6
        dist = float(np.linalg.norm(centre - eye))
        axis = (centre - eye) / dist
        if _blocked(site, eye, axis, dist - 1.0, skip=cfg.target):
            continue
        sun_clear = sun[2] > 0 and not _blocked(site, eye, sun, 300.0)
        candidates.append((sun_clear, float(axis @ sun), -abs(a), eye))
    if not candidates:
        raise RuntimeError(f"no clear view of {cfg.target}'s gauge from {cfg.distance_m:g} m")
    best = max(candidates, key=lambda c: c[:3])
    return look_at(best[3], centre)


def study_shots(site: BuiltSite, cfg: StudyConfig, *,
                tau_atm: float = sun_model.DEFAULT_TAU_ATM) -> list[tuple[str, Shot]]:
    """The study's shots (PAPER_NOTES.md): same camera, one instant per condition; the
    tank level follows the study's leak trace over the sequence so H has something to
    follow."""
    from ..errors import UserError

    if not any(p["tag"] == cfg.target for p in site.placements) \
            or site.placement(cfg.target)["asset"] not in site.manifests:
        raise UserError(cfg.path, "target", f"{cfg.target!r} is not a built placement of {site.build}")
    if placed_dial(site, cfg.target) is None:
        raise UserError(cfg.path, "target", f"{cfg.target!r} has no gauge (no binding turns its pointer)")
    times = study_times(site, cfg)
    lat, lon = site.origin[0], site.origin[1]
    suns = []
    for _, when in times:
        el, az = sun_model.ephemeris(lat, lon, when)
        e = math.radians(el)
        suns.append((e, math.radians(az), sun_model.irradiance(e, tau_atm)))
    faced = next(sun_model.direction_enu(e, a) for (n, _), (e, a, _) in zip(times, suns) if n == cfg.faces_sun_of)
    pose = study_viewpoint(site, faced, cfg)
    lens = camera_model.lens(cfg.zoom)
    shots = []
    for i, ((name, when), (e, a, g)) in enumerate(zip(times, suns)):
        level = 100.0 - 12.0 * i  # 100, 88, ... 40 %: a slow leak between the conditions
        shots.append((name, _tank_shot(site, cfg.target, when, pose, lens, e, a, g, level)))
    return shots


def _tank_shot(site, target, when, pose, lens, e, a, g, level) -> Shot:
    from ..runtime import nodes

    p = site.placement(target)
    ob = nodes.Observed(p["tag"], p.get("state"), p["asset"], site.manifests[p["asset"]])
    values = {p.get("state"): {"oil_level_tank": level}}
    return Shot(when, pose, lens, e, a, g, {p["tag"]: {"oil_level_tank": level}},
                nodes.visual_states(values, [ob]), target)


def study_roi(record: dict) -> tuple[int, int, int, int]:
    """The fixed ROI: the dial's projected box (the same for every frame: one camera)."""
    x0, y0, x1, y1 = record["labels"]["gauges"]["gauge_tank"]["box"]
    return int(math.floor(x0)), int(math.floor(y0)), int(math.ceil(x1)), int(math.ceil(y1))


def face_only(bgr_crop: np.ndarray, site: BuiltSite, shot: Shot, cam: PhoneCamera, offset) -> np.ndarray:
    """The crop with everything outside the projected dial face set to a neutral grey
    (neither red, white nor dark for the H masks)."""
    import cv2

    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    dial = placed_dial(site, shot.target)
    uv = project(dial.circle(dial.face_radius * 0.97, 64), shot.cam_pose, k)
    poly = np.round(uv - np.asarray(offset, float)).astype(np.int32)
    mask = np.zeros(bgr_crop.shape[:2], np.uint8)
    cv2.fillPoly(mask, [poly], 1)
    out = bgr_crop.copy()
    out[mask == 0] = 128
    return out


def render_study(out, sources: Path, *, cam: PhoneCamera | None = None, progress=None) -> Path:
    """`twin render --study`: the conditions of sources/study.toml, metrics C, S, H on
    the gauge ROI set against the study's Table 1, out/reports/study.html + study.json,
    frames in out/reports/study/."""
    cam = cam or PhoneCamera()
    out = Path(out)
    cfg = load_study(Path(sources) / CONFIG)
    site = load_site(out, sources)
    shots = study_shots(site, cfg)
    folder = out / "reports" / "study"
    rows = []
    h_ref = true_ref = None
    # One scene for the conditions (loaded once, kept between frames); the phone
    # re-meters at each condition.
    records = render_shots(site, [s for _, s in shots], folder, cam=cam, seed=cfg.seed,
                           names=[n for n, _ in shots], meter_each=True, progress=progress)
    for (name, shot), rec in zip(shots, records):
        x0, y0, x1, y1 = study_roi(rec)
        crop = rec["rgb"][y0:y1, x0:x1, ::-1]
        m = measure(crop, face_only(crop, site, shot, cam, (x0, y0)))
        m["H"] = m["extent_px"] / h_ref if h_ref else 0.0
        if h_ref is None:
            h_ref = m["extent_px"] or None
            m["H"] = 1.0 if h_ref else 0.0
        lab = rec["labels"]
        rows_px = lab.get("pointer_rows_px")
        true_ref = true_ref or rows_px
        h_true = rows_px / true_ref if rows_px and true_ref else None
        row = {"condition": name, "time": lab["time"], "image": f"study/{rec['image']}",
               "sun_elevation_deg": lab["sun"]["elevation_deg"], "sun_azimuth_deg": lab["sun"]["azimuth_deg"],
               "irradiance_w_m2": lab["sun"]["irradiance_w_m2"], "oil_level_tank": lab["oil_levels"]["oil_level_tank"],
               "exposure_gain": lab["camera"]["exposure_gain"], "veil": lab["camera"]["veil"],
               "sun_off_axis_deg": _off_axis_deg(shot), "roi": [x0, y0, x1, y1],
               "C": m["C"], "S": m["S"], "H": m["H"], "H_true": h_true,
               "render_s": lab["render_s"], "frame_s": lab["frame_s"]}
        row["table1"] = table1(row)
        rows.append(row)
    report = {"config": cfg.path.name, "target": cfg.target, "zoom": cfg.zoom, "seed": cfg.seed, "h_ref_px": h_ref,
              "camera": dict(cam.__dict__), "conditions": rows,
              "table1_matches": sum(c["match"] for r in rows for c in r["table1"]),
              "table1_checks": sum(len(r["table1"]) for r in rows)}
    (out / "reports").mkdir(parents=True, exist_ok=True)
    write_json(out / "reports" / "study.json", report)
    atomic_write(out / "reports" / "study.html", _study_html(report))
    return out / "reports" / "study.html"


def _off_axis_deg(shot: Shot) -> float:
    """The sun's angle to the camera's axis (deg)."""
    return math.degrees(math.acos(float(np.clip(-shot.cam_pose[:3, 2] @ shot.sun_dir, -1.0, 1.0))))


# --- the study's Table 1, in shape (PAPER_NOTES.md, "what the study saw") --------------------

C_BAND = (0.18, 0.30)  # "contrast about 0.2 to 0.27 in all conditions"
S_FEW = (0.005, 0.10)  # "a few per cent at morning and noon"
S_MOST = 0.5  # "most of the crop saturated under late-afternoon glare"
H_NEAR = 0.2  # "H near 1 in good views": H within this of the pointer's true extent
LIGHT = {"early_morning": "day", "solar_noon": "day", "late_afternoon": "glare",
         "early_night": "night", "midnight": "night", "late_night": "night"}


def table1(row: dict) -> list[dict]:
    """The study's figures for a condition of its name, in shape: per metric what the
    study saw, our figure, and whether it matches. H is read against the pointer's true
    extent (our tank level changes along the sequence; the study's "near 1" is a reading
    of an unchanged pointer); where the study lost the pointer (late-afternoon glare)
    H = 0 is its figure; at night it saw either (darkness can lose the pointer)."""
    light = LIGHT.get(row["condition"])
    if light is None:
        return []
    c, s, h, h_true = row["C"], row["S"], row["H"], row["H_true"]
    reads = h_true is not None and abs(h - h_true) <= H_NEAR
    checks = [("C", "about 0.2-0.27", c, C_BAND[0] <= c <= C_BAND[1])]
    if light == "day":
        checks += [("S", "a few per cent", s, S_FEW[0] <= s <= S_FEW[1]),
                   ("H", "reads the pointer (near 1 in good views)", h, reads)]
    elif light == "glare":
        checks += [("S", "most of the crop (> 0.5)", s, s > S_MOST),
                   ("H", "0: pointer lost in glare", h, h == 0.0)]
    else:
        checks += [("S", "none (0)", s, s == 0.0),
                   ("H", "reads the pointer where lit, 0 where lost in darkness", h, reads or h == 0.0)]
    return [{"metric": m, "study": text, "ours": float(v), "match": bool(ok)} for m, text, v, ok in checks]


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _study_html(report: dict) -> str:
    import html

    head = "<tr><th>condition</th><th>time</th><th>sun el / az (deg)</th><th>sun off axis (deg)</th>" \
           "<th>G (W/m2)</th><th>oil %</th><th>gain</th><th>veil (W/m2/sr)</th><th>C</th><th>S</th><th>H</th>" \
           "<th>H true</th><th>the study's Table 1</th><th>frame</th></tr>"

    def shape(r: dict) -> str:
        return "<br>".join(f"{c['metric']}: {html.escape(c['study'])}, ours {c['ours']:.3f} "
                           f"{'&#10003;' if c['match'] else '&#10007; no'}" for c in r["table1"]) or "-"

    rows = "".join(
        f"<tr><td>{html.escape(r['condition'])}</td><td>{html.escape(r['time'])}</td>"
        f"<td>{r['sun_elevation_deg']:.1f} / {r['sun_azimuth_deg']:.1f}</td><td>{r['sun_off_axis_deg']:.1f}</td>"
        f"<td>{r['irradiance_w_m2']:.0f}</td><td>{r['oil_level_tank']:.0f}</td><td>{r['exposure_gain']:.3g}</td>"
        f"<td>{r['veil']:.3g}</td><td>{r['C']:.3f}</td><td>{r['S']:.3f}</td><td>{r['H']:.2f}</td>"
        f"<td>{_fmt(r['H_true'])}</td><td>{shape(r)}</td>"
        f"<td><img src=\"{html.escape(r['image'])}\" width=\"240\"></td></tr>"
        for r in report["conditions"])
    return ("<!doctype html><html><head><meta charset=\"utf-8\"><title>Gauge study</title>"
            "<style>body{font-family:sans-serif}td,th{padding:4px 8px;border-bottom:1px solid #ccc}</style></head>"
            f"<body><h1>Main-tank gauge of {html.escape(report['target'])} at {report['zoom']:g}x: "
            f"{len(report['conditions'])} conditions</h1>"
            "<p>C: RMS contrast, S: share of grey levels above 240, H: pointer extent / first frame's "
            f"(H_ref = {report['h_ref_px']} px), on the dial's fixed ROI; H true: the same ratio of the "
            "pointer's projected geometry (what H should read while the pointer is visible). Veil: the mean "
            "radiance the lens's glare adds over the frame. Conditions in a day's order from the first light in "
            f"which the pointer is visible ({html.escape(report['config'])}).</p>"
            f"<p>Against the shape of the study's Table 1: {report['table1_matches']} of {report['table1_checks']} "
            "figures match.</p>"
            f"<table>{head}{rows}</table></body></html>\n")
