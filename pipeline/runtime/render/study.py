"""`twin render --study`: the study's six conditions of one gauge (PAPER_NOTES.md),
with its metrics C, S and H on the gauge's ROI."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

import numpy as np

from ... import config
from .. import camera as camera_model
from .. import sun as sun_model
from .frames import measure, render_shots, write_json
from .gauge import FACE_RADIUS, dial_outline, dial_world
from .pinhole import intrinsics, look_at, project
from .sensor import PhoneCamera
from .site import Shot, Site, load_site

STUDY_TARGET = "RE-B3"  # bank B faces ENE: its reader looks WSW, into the late sun
STUDY_ZOOM = 45.0
STUDY_DISTANCE_M = 25.0  # at 45x the 0.34 m dial spans about half of the frame's width
STUDY_MAX_OBLIQUITY = math.radians(45.0)  # beyond, the glass's Fresnel reflection hides the dial
# Local times (site.toml [site] timezone) on the site's date (sunrise ~05:40, sunset ~17:45): early night at the end of
# civil twilight, late afternoon 40 min before sunset. The sequence runs in a day's
# order from the first light in which the pointer is visible (the study's H_ref is its
# first image): morning, noon, late afternoon, then the three night conditions.
CONDITIONS = (("early_morning", "06:45"), ("solar_noon", None), ("late_afternoon", "17:05"),
              ("early_night", "18:05"), ("midnight", "23:59"), ("late_night", "04:00"))
LATE = "late_afternoon"


def study_times(site: Site) -> list[tuple[str, dt.datetime]]:
    import astral
    import astral.sun

    from ...errors import UserError

    if site.zone is None:
        raise UserError(site.build / "scene" / "placements.json", "timezone",
                        "the study's local times need the site's time zone: site.toml [site] timezone, then rebuild")
    date = dt.date.fromisoformat(site.date)
    noon = astral.sun.noon(astral.Observer(site.origin[0], site.origin[1]), date, tzinfo=site.zone)
    out = []
    for name, hhmm in CONDITIONS:
        if hhmm is None:
            out.append((name, noon.replace(microsecond=0)))
        else:
            h, m = map(int, hhmm.split(":"))
            out.append((name, config.local_time(dt.datetime.combine(date, dt.time(h, m)), site.zone)))
    return out


def _ray_hits_box(origin: np.ndarray, direction: np.ndarray, length: float, pose: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray) -> bool:
    """Does the segment origin + t direction, t in [0, length], cross the box [lo, hi]
    of the model at `pose` (slab test in the model frame)?"""
    o = pose[:3, :3].T @ (origin - pose[:3, 3])
    d = pose[:3, :3].T @ direction
    t0, t1 = 0.0, length
    for i in range(3):
        if abs(d[i]) < 1e-12:
            if o[i] < lo[i] or o[i] > hi[i]:
                return False
            continue
        a, b = (lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        if t0 > t1:
            return False
    return True


def _blocked(site: Site, origin: np.ndarray, direction: np.ndarray, length: float, skip: str = "") -> bool:
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


def study_viewpoint(site: Site, late_sun: np.ndarray) -> np.ndarray:
    """The study's camera pose: STUDY_DISTANCE_M from the main-tank dial, at a phone's
    height (1.6 m above the reactor's level), turned from the dial's normal towards the
    late-afternoon sun as far as STUDY_MAX_OBLIQUITY allows, so that the low sun faces
    the lens as much as the dial's orientation permits, while the line of sight to the
    dial and the sun itself stay clear of the built models' bounding boxes (a sun hidden
    behind the reactor would make no glare)."""
    p = site.placement(STUDY_TARGET)
    centre, normal = dial_world(site.pose(p))
    candidates = []
    for a in np.linspace(-STUDY_MAX_OBLIQUITY, STUDY_MAX_OBLIQUITY, 91):
        c, s = math.cos(a), math.sin(a)
        u = np.array([c * normal[0] - s * normal[1], s * normal[0] + c * normal[1], 0.0])
        eye = centre + STUDY_DISTANCE_M * u
        eye[2] = p["enu"][2] + 1.6
        dist = float(np.linalg.norm(centre - eye))
        axis = (centre - eye) / dist
        if _blocked(site, eye, axis, dist - 1.0, skip=STUDY_TARGET):
            continue
        sun_clear = late_sun[2] > 0 and not _blocked(site, eye, late_sun, 300.0)
        candidates.append((sun_clear, float(axis @ late_sun), -abs(a), eye))
    if not candidates:
        raise RuntimeError(f"no clear view of {STUDY_TARGET}'s gauge from {STUDY_DISTANCE_M} m")
    best = max(candidates, key=lambda c: c[:3])
    return look_at(best[3], centre)


def study_shots(site: Site, *, tau_atm: float = sun_model.DEFAULT_TAU_ATM) -> list[tuple[str, Shot]]:
    """Six shots of the study (PAPER_NOTES.md): same camera, six instants; the tank level
    follows the study's leak trace over the sequence so H has something to follow."""
    times = study_times(site)
    lat, lon = site.origin[0], site.origin[1]
    suns = []
    for _, when in times:
        el, az = sun_model.ephemeris(lat, lon, when)
        e = math.radians(el)
        suns.append((e, math.radians(az), sun_model.irradiance(e, tau_atm)))
    late = next(sun_model.direction_enu(e, a) for (n, _), (e, a, _) in zip(times, suns) if n == LATE)
    pose = study_viewpoint(site, late)
    lens = camera_model.lens(STUDY_ZOOM)
    shots = []
    for i, ((name, when), (e, a, g)) in enumerate(zip(times, suns)):
        level = 100.0 - 12.0 * i  # 100, 88, ... 40 %: a slow leak between the conditions
        shots.append((name, _tank_shot(site, when, pose, lens, e, a, g, level)))
    return shots


def _tank_shot(site, when, pose, lens, e, a, g, level) -> Shot:
    from .. import nodes

    p = site.placement(STUDY_TARGET)
    ob = nodes.Observed(p["tag"], p.get("state"), p["asset"], site.manifests[p["asset"]])
    values = {p.get("state"): {"oil_level_tank": level}}
    return Shot(when, pose, lens, e, a, g, {p["tag"]: {"oil_level_tank": level}},
                nodes.visual_states(values, [ob]), STUDY_TARGET)


def study_roi(record: dict) -> tuple[int, int, int, int]:
    """The fixed ROI: the dial's projected box (the same for every frame: one camera)."""
    x0, y0, x1, y1 = record["labels"]["gauges"]["gauge_tank"]["box"]
    return int(math.floor(x0)), int(math.floor(y0)), int(math.ceil(x1)), int(math.ceil(y1))


def face_only(bgr_crop: np.ndarray, site: Site, shot: Shot, cam: PhoneCamera, offset) -> np.ndarray:
    """The crop with everything outside the projected dial face set to a neutral grey
    (neither red, white nor dark for the H masks)."""
    import cv2

    k = intrinsics(shot.lens.hfov, cam.width, cam.height)
    uv = project(dial_outline(site.pose(site.placement(shot.target)), 64, FACE_RADIUS * 0.97), shot.cam_pose, k)
    poly = np.round(uv - np.asarray(offset, float)).astype(np.int32)
    mask = np.zeros(bgr_crop.shape[:2], np.uint8)
    cv2.fillPoly(mask, [poly], 1)
    out = bgr_crop.copy()
    out[mask == 0] = 128
    return out


def render_study(out, *, cam: PhoneCamera | None = None, sources: Path | None = None) -> Path:
    """`twin render --study`: the six conditions, metrics C, S, H on the gauge ROI,
    out/reports/study.html + study.json, frames in out/reports/study/."""
    cam = cam or PhoneCamera()
    out = Path(out)
    site = load_site(out, sources)
    shots = study_shots(site)
    folder = out / "reports" / "study"
    seed = 20250920
    rows = []
    h_ref = true_ref = None
    # One scene for the six conditions (loaded once, kept between frames); the phone
    # re-meters at each condition.
    records = render_shots(site, [s for _, s in shots], folder, cam=cam, seed=seed,
                           names=[n for n, _ in shots], meter_each=True)
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
        rows.append({"condition": name, "time": lab["time"], "image": f"study/{rec['image']}",
                     "sun_elevation_deg": lab["sun"]["elevation_deg"], "sun_azimuth_deg": lab["sun"]["azimuth_deg"],
                     "irradiance_w_m2": lab["sun"]["irradiance_w_m2"], "oil_level_tank": lab["oil_levels"]["oil_level_tank"],
                     "exposure_gain": lab["camera"]["exposure_gain"], "veil": lab["camera"]["veil"],
                     "roi": [x0, y0, x1, y1], "C": m["C"], "S": m["S"], "H": m["H"], "H_true": h_true,
                     "render_s": lab["render_s"], "frame_s": lab["frame_s"]})
    report = {"target": STUDY_TARGET, "zoom": STUDY_ZOOM, "seed": seed, "h_ref_px": h_ref,
              "camera": cam.__dict__, "conditions": rows}
    (out / "reports").mkdir(parents=True, exist_ok=True)
    write_json(out / "reports" / "study.json", report)
    (out / "reports" / "study.html").write_text(_study_html(report))
    return out / "reports" / "study.html"


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _study_html(report: dict) -> str:
    import html

    head = "<tr><th>condition</th><th>time</th><th>sun el / az (deg)</th><th>G (W/m2)</th><th>oil %</th>" \
           "<th>gain</th><th>C</th><th>S</th><th>H</th><th>H true</th><th>frame</th></tr>"
    rows = "".join(
        f"<tr><td>{html.escape(r['condition'])}</td><td>{html.escape(r['time'])}</td>"
        f"<td>{r['sun_elevation_deg']:.1f} / {r['sun_azimuth_deg']:.1f}</td><td>{r['irradiance_w_m2']:.0f}</td>"
        f"<td>{r['oil_level_tank']:.0f}</td><td>{r['exposure_gain']:.3g}</td><td>{r['C']:.3f}</td>"
        f"<td>{r['S']:.3f}</td><td>{r['H']:.2f}</td><td>{_fmt(r['H_true'])}</td><td><img src=\"{html.escape(r['image'])}\" width=\"240\"></td></tr>"
        for r in report["conditions"])
    return ("<!doctype html><html><head><meta charset=\"utf-8\"><title>Gauge study</title>"
            "<style>body{font-family:sans-serif}td,th{padding:4px 8px;border-bottom:1px solid #ccc}</style></head>"
            f"<body><h1>Main-tank gauge of {html.escape(report['target'])} at {report['zoom']:g}x: six conditions</h1>"
            "<p>C: RMS contrast, S: share of grey levels above 240, H: pointer extent / first frame's "
            f"(H_ref = {report['h_ref_px']} px), on the dial's fixed ROI; H true: the same ratio of the "
            "pointer's projected geometry (what H should read while the pointer is visible). Conditions in "
            "a day's order from the first light in which the pointer is visible.</p>"
            f"<table>{head}{rows}</table></body></html>\n")
