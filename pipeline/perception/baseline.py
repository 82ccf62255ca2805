"""`twin baseline DATASET`: the study's gauge reader over a dataset's conditions.

Every gauge a frame labels visible is read by gauge_reader (the ROI of the dial's
projected rim, the study's C, S and H on it, the level the reader infers) and scored
against the frame's true reading; the report bins the errors by sun elevation (night,
0-10, 10-30, above 30 deg) and plots them against sun elevation and local time:
OUT/reports/baseline_<name>.json and .html, the plots' PNGs beside them.

H's reference. The study divides the extent by the first frame's (H_ref): one camera,
one pointer angle, so the ratio follows the view's loss alone. A dataset changes the
camera, the zoom and the pointer's angle from frame to frame, so a reference frame
would mix those changes into H. Here H_ref is the pointer's true projected row extent
in the same frame (its authored outline at the true angle, projected with the frame's
K and pose): H is then the study's H over H_true with a perfect reference, 1 when the
metric finds the whole pointer and nothing else, below when darkness or glare hides
it, above when shadows or a dark face add rows. H_true is 1 by construction.
"""

from __future__ import annotations

import datetime as dt
import html
import io
import json
import os
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..files import atomic_write
from ..geometry.pinhole import project
from .gauge import Dial, dial_of
from .gauge_reader import (DARK_OF_FACE, DARK_V, MIN_DIAL_PX, POINTER_OUTLINE, READERS, SCORED, STATUS_READ,
                           UNREADABLE, score_gauge)

# --- a dataset ------------------------------------------------------------------------------------


def camera_of(frame: dict) -> tuple[np.ndarray, dict]:
    """(4, 4) world-from-camera pose and the pinhole dict of a frames.jsonl record."""
    c = frame["camera"]
    kmat = np.asarray(c["K"], float)
    k = {"fx": kmat[0, 0], "fy": kmat[1, 1], "cx": kmat[0, 2], "cy": kmat[1, 2],
         "width": int(c["width"]), "height": int(c["height"])}
    return np.asarray(c["pose"], float), k


def read_frames(folder: Path) -> list[dict]:
    path = folder / "frames.jsonl"
    if not path.is_file():
        raise UserError(path, None, "not a dataset folder (no frames.jsonl): give OUT/datasets/<name>/")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def local_hours(iso: str) -> float:
    """The local clock time of an ISO time with offset, in hours."""
    t = dt.datetime.fromisoformat(iso)
    return t.hour + t.minute / 60.0 + t.second / 3600.0


def score_dataset(folder: Path, site, frames: list[dict], progress=None) -> list[dict]:
    """One row per gauge a frame (a frames.jsonl record) labels visible, in frame then
    tag order. `progress(done, total)` is called before the first frame and after each."""
    import cv2

    dials: dict[str, Dial | None] = {}
    rows = []
    for i, f in enumerate(frames):
        if progress:
            progress(i, len(frames))
        seen = [g for g in f["gauges"] if g.get("visible")]
        if not seen:
            continue
        bgr = cv2.imread(str(folder / f["image"]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise UserError(folder / f["image"], f["frame_id"], "missing or unreadable image")
        cam_pose, k = camera_of(f)
        for g in sorted(seen, key=lambda g: g["tag"]):
            if g["tag"] not in dials:
                p = site.placement(g["tag"])
                dials[g["tag"]] = dial_of(site.pose(p), site.manifests.get(p["asset"], {}))
            dial = dials[g["tag"]]
            if dial is None:
                continue
            row = {"frame_id": f["frame_id"], "image": f["image"], "tag": g["tag"], "camera": f["camera"].get("name"),
                   "zoom": f["camera"].get("zoom"), "local_time": f["local_time"],
                   "local_hours": local_hours(f["local_time"]), "sun_elevation_deg": f["sun"]["elevation_deg"],
                   "sun_azimuth_deg": f["sun"]["azimuth_deg"], "irradiance": f["sun"]["irradiance"],
                   "true": g["reading"]}
            scored = score_gauge(bgr, dial, cam_pose, k, g["reading"])
            for name in READERS:
                if isinstance(scored.get(name), dict):
                    scored[name]["angle_error_deg"] = keypoint_angle_error(
                        dial, scored[name].get("angle_rad"), g.get("keypoints"), cam_pose, k)
            rows.append({**row, **scored})
    if progress:
        progress(len(frames), len(frames))
    return rows


def keypoint_angle_error(dial: Dial, angle: float | None, keypoints: list | None, cam_pose: np.ndarray,
                         k: dict) -> float | None:
    """The reader's pointer direction against the frame's keypoints, in the picture
    (deg, signed, -180..180): the angle at the dial-centre keypoint between the
    pointer-tip keypoint and the tip the reader's angle puts there, projected. None
    without a reading, keypoints (a dataset made before them) or both points in frame."""
    if angle is None or not keypoints or keypoints[2] == 0 or keypoints[5] == 0:
        return None
    centre, tip = np.array(keypoints[0:2], float), np.array(keypoints[3:5], float)
    read = project((dial.centre + float(POINTER_OUTLINE[:, 1].max()) * dial.direction(angle))[None, :], cam_pose, k)[0]
    if np.isnan(read).any():
        return None
    a, b = tip - centre, read - centre
    return float(np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))


def run_baseline(folder, out=None, *, sources: Path, progress=None) -> Path:
    """`twin baseline`: score the dataset at `folder` (OUT/datasets/<name>/) and write
    OUT/reports/baseline_<name>.json, .html and its plots; OUT defaults to the build
    the dataset lies in. Returns the HTML's path."""
    from ..runtime.site import load_site

    folder = Path(folder).resolve()
    frames = read_frames(folder)
    build = folder.parents[1] if len(folder.parents) > 1 else folder
    if not (build / "scene" / "placements.json").is_file():
        raise UserError(folder, None, "a dataset folder lies in a build: OUT/datasets/<name>/ beside OUT/scene/")
    site = load_site(build, sources)
    rows = score_dataset(folder, site, frames, progress)
    name = json.loads((folder / "dataset.json").read_text())["dataset"] if (folder / "dataset.json").is_file() \
        else folder.name
    return write_report(Path(out) if out else build, name, folder, rows, frames=len(frames))


# --- the bins ------------------------------------------------------------------------------------

# (name, the highest sun elevation it holds, deg): each bin starts above the one before
BINS = (("night (sun <= 0 deg)", 0.0), ("sun 0-10 deg", 10.0), ("sun 10-30 deg", 30.0), ("sun > 30 deg", 90.0))


def bin_of(elevation_deg: float) -> str:
    return next((name for name, top in BINS if elevation_deg <= top), BINS[-1][0])


def _mean(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def reader_summary(scored: list[dict], reader: str) -> dict:
    """One reader over scored rows: how many it read, the share, the mean and largest
    absolute reading error of those read, their mean absolute pointer-angle error
    against the keypoints (deg, in the picture), and why it read none of the others."""
    read = [r[reader] for r in scored if r[reader]["status"] == STATUS_READ]
    return {"read": len(read), "share_read": len(read) / len(scored) if scored else None,
            "mae": _mean(abs(r["error"]) for r in read),
            "angle_mae_deg": _mean(abs(r["angle_error_deg"]) for r in read if r.get("angle_error_deg") is not None),
            "max_abs_error": max((abs(r["error"]) for r in read), default=None),
            "unreadable": {why: sum(r[reader]["status"] == why for r in scored) for why in UNREADABLE}}


def summary(rows: list[dict]) -> dict:
    """Counts and errors of a set of gauge rows: seen (labelled visible), not scored
    (too small, cut), scored; per reader what reader_summary says; H's mean and mean
    |H - 1| over the scored."""
    scored = [r for r in rows if r["status"] == SCORED]
    hs = [r["H"] for r in scored if r.get("H") is not None]
    return {"seen": len(rows), "too_small": sum(r["status"] == "too_small" for r in rows),
            "cut": sum(r["status"] == "cut" for r in rows), "scored": len(scored),
            "readers": {name: reader_summary(scored, name) for name in READERS},
            "mean_H": _mean(hs), "mae_H": _mean(abs(h - 1.0) for h in hs)}


def bins_table(rows: list[dict]) -> list[dict]:
    out = [{"bin": name, **summary([r for r in rows if bin_of(r["sun_elevation_deg"]) == name])}
           for name, _ in BINS]
    return out + [{"bin": "all", **summary(rows)}]


# --- plots ------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    """PNG bytes without the Software stamp: the same rows give the same file."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
    _plt().close(fig)
    return buf.getvalue()


STYLE = {"relative": ("o", "C0"), "study": ("^", "C1")}
H_CAP = 3.0  # H above this is drawn on the plot's upper edge


def plot(rows: list[dict], key: str, label: str, marks: tuple[float, ...]) -> bytes:
    """Per reader, |reading error| of the scored gauges against rows[key] (top; those
    it could not read as crosses along the upper edge) and H (bottom)."""
    plt = _plt()
    scored = [r for r in rows if r["status"] == SCORED]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.0, 5.6), sharex=True)
    errors = [abs(r[n]["error"]) for r in scored for n in READERS if r[n]["error"] is not None]
    ceiling = max(errors + [10.0]) * 1.15
    for i, name in enumerate(READERS):
        marker, colour = STYLE.get(name, ("s", f"C{i + 2}"))
        read = [r for r in scored if r[name]["status"] == STATUS_READ]
        lost = [r for r in scored if r[name]["status"] != STATUS_READ]
        top.scatter([r[key] for r in read], [abs(r[name]["error"]) for r in read], s=20, marker=marker,
                    color=colour, label=f"{name}: read")
        if lost:
            top.scatter([r[key] for r in lost], [ceiling * (1.0 + 0.04 * i)] * len(lost), marker="x", s=22,
                        color=colour, label=f"{name}: unreadable")
    top.set_ylim(0.0, ceiling * 1.12)
    top.set_ylabel("|reading error| (% level)")
    top.legend(loc="center left", fontsize=7)
    with_h = [r for r in scored if r.get("H") is not None]
    inside = [r for r in with_h if r["H"] <= H_CAP]
    above = [r for r in with_h if r["H"] > H_CAP]
    bottom.scatter([r[key] for r in inside], [r["H"] for r in inside], s=18, color="C2")
    if above:  # shadows or a dark face counted as pointer rows: drawn on the cap
        bottom.scatter([r[key] for r in above], [H_CAP] * len(above), s=24, marker="^", color="C2",
                       label=f"H > {H_CAP:g}")
        bottom.legend(loc="upper left", fontsize=7)
    bottom.set_ylim(-0.05, H_CAP * 1.08)
    bottom.axhline(1.0, color="grey", lw=0.8, ls="--")
    bottom.set_ylabel("H: dark extent / true extent\n(H true = 1)")
    bottom.set_xlabel(label)
    for ax in (top, bottom):
        for x in marks:
            ax.axvline(x, color="grey", lw=0.6, ls=":")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _png(fig)


# --- the report ---------------------------------------------------------------------------------------


def write_report(out: Path, name: str, folder: Path, rows: list[dict], *, frames: int | None = None) -> Path:
    reports = out / "reports"
    reports.mkdir(parents=True, exist_ok=True)
    plots = {"sun": f"baseline_{name}_sun.png", "time": f"baseline_{name}_time.png"}
    atomic_write(reports / plots["sun"], plot(rows, "sun_elevation_deg", "sun elevation (deg)",
                                              tuple(top for _, top in BINS[:-1])))
    atomic_write(reports / plots["time"], plot(rows, "local_hours", "local time (h)", ()))
    report = {"dataset": name, "frames": frames, "min_dial_px": MIN_DIAL_PX, "bins": bins_table(rows), "gauges": rows,
              "plots": plots, "frames_with_gauges": len({r["frame_id"] for r in rows}),
              "examples": write_examples(rows, folder, reports, f"baseline_{name}")}
    atomic_write(reports / f"baseline_{name}.json", json.dumps(report, sort_keys=True, indent=1, allow_nan=False) + "\n")
    images = Path(os.path.relpath(folder.resolve(), reports.resolve()))
    atomic_write(reports / f"baseline_{name}.html", _html(report, images))
    return reports / f"baseline_{name}.html"


EXAMPLES_PER_BIN = 4
EXAMPLE_HEIGHT_PX = 96


def write_examples(rows: list[dict], folder: Path, reports: Path, stem: str) -> dict[str, list[dict]]:
    """The first EXAMPLES_PER_BIN scored gauges of each bin as ROI crops scaled to
    EXAMPLE_HEIGHT_PX (nearest neighbour: the pixels the readers saw) in reports/<stem>/;
    bin -> [{file, row index}]."""
    import cv2

    out: dict[str, list[dict]] = {}
    for name, _ in BINS:
        picked = [i for i, r in enumerate(rows) if r["status"] == SCORED and bin_of(r["sun_elevation_deg"]) == name]
        for i in picked[:EXAMPLES_PER_BIN]:
            r = rows[i]
            x0, y0, x1, y1 = r["roi"]
            crop = cv2.imread(str(folder / r["image"]), cv2.IMREAD_COLOR)[y0:y1, x0:x1]
            scale = EXAMPLE_HEIGHT_PX / crop.shape[0]
            crop = cv2.resize(crop, (max(1, round(crop.shape[1] * scale)), EXAMPLE_HEIGHT_PX),
                              interpolation=cv2.INTER_NEAREST)
            ok, buf = cv2.imencode(".png", crop)
            file = f"{stem}/{r['frame_id']}_{r['tag']}.png"
            atomic_write(reports / file, buf.tobytes())
            out.setdefault(name, []).append({"file": file, "row": i})
    return out


def _f(x, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def _reader_cells(b: dict) -> str:
    return "".join(f"<td>{x['read']}</td><td>{_f(x['share_read'], '.0%')}</td><td>{_f(x['mae'])}</td>"
                   f"<td>{_f(x['max_abs_error'])}</td><td>{_f(x.get('angle_mae_deg'))}</td>"
                   f"<td>{' / '.join(str(x['unreadable'][w]) for w in UNREADABLE)}</td>"
                   for x in (b["readers"][n] for n in READERS))


def _gallery(report: dict, caption) -> str:
    e = html.escape
    rows = report["gauges"]
    out = []
    for name, _ in BINS:
        shots = report["examples"].get(name, [])
        cells = "".join(f"<figure><img src=\"{e(x['file'])}\" height=\"{EXAMPLE_HEIGHT_PX}\">"
                        f"<figcaption>{caption(rows[x['row']])}</figcaption></figure>" for x in shots)
        out.append(f"<h3>{e(name)}</h3><div class=\"gallery\">{cells or 'no scored dial'}</div>")
    return "".join(out)


def _html(report: dict, images: Path) -> str:
    e = html.escape
    per_reader = "".join(f"<th colspan=\"6\">reader: {e(n)}</th>" for n in READERS)
    head = ("<tr><th rowspan=\"2\">condition</th><th rowspan=\"2\">gauges seen</th><th rowspan=\"2\">too small</th>"
            "<th rowspan=\"2\">cut by the frame</th><th rowspan=\"2\">scored</th>" + per_reader +
            "<th rowspan=\"2\">mean H</th><th rowspan=\"2\">mean |H - 1|</th></tr><tr>" +
            ("<th>read</th><th>share read</th><th>MAE (% level)</th><th>max |error|</th>"
             "<th>angle MAE against the keypoints (deg)</th>"
             "<th>unreadable: no pointer / dark face / no line</th>") * len(READERS) + "</tr>")
    body = "".join(
        f"<tr><td>{e(b['bin'])}</td><td>{b['seen']}</td><td>{b['too_small']}</td><td>{b['cut']}</td>"
        f"<td>{b['scored']}</td>{_reader_cells(b)}<td>{_f(b['mean_H'], '.2f')}</td><td>{_f(b['mae_H'], '.2f')}</td></tr>"
        for b in report["bins"])
    gauge_head = ("<tr><th>frame</th><th>tag</th><th>camera</th><th>local time</th><th>sun el (deg)</th>"
                  "<th>dial (px)</th><th>true %</th>" + "".join(f"<th>{e(n)}: read %</th>" for n in READERS) +
                  "<th>C</th><th>S</th><th>H</th></tr>")

    def reading(r: dict, n: str) -> str:
        if r["status"] != SCORED:
            return e(r["status"])
        x = r[n]
        return f"{x['read']:.1f} ({x['error']:+.1f})" if x["status"] == STATUS_READ else e(x["status"])

    def caption(r: dict) -> str:
        return f"{r['frame_id']} {e(r['tag'])}<br>true {r['true']:.1f}" + "".join(
            f"<br>{e(n)}: {reading(r, n)}" for n in READERS)

    gauge_rows = "".join(
        f"<tr><td><a href=\"{e((images / r['image']).as_posix())}\">{e(r['frame_id'])}</a></td><td>{e(r['tag'])}</td>"
        f"<td>{e(str(r['camera']))}</td><td>{e(r['local_time'])}</td><td>{r['sun_elevation_deg']:.1f}</td>"
        f"<td>{r['dial_px']:.0f}</td><td>{_f(r['true'])}</td>" + "".join(f"<td>{reading(r, n)}</td>" for n in READERS) +
        f"<td>{_f(r.get('C'), '.3f')}</td><td>{_f(r.get('S'), '.3f')}</td><td>{_f(r.get('H'), '.2f')}</td></tr>"
        for r in report["gauges"])
    return (
        "<!doctype html><html><head><meta charset=\"utf-8\">"
        f"<title>Gauge-reading baseline: {e(report['dataset'])}</title>"
        "<style>body{font-family:sans-serif;max-width:1200px}td,th{padding:3px 7px;border-bottom:1px solid #ccc;"
        "font-size:90%}.gallery{display:flex;flex-wrap:wrap;gap:10px}figure{margin:0;font-size:80%}</style></head><body>"
        f"<h1>Gauge-reading baseline on dataset {e(report['dataset'])}</h1>"
        f"<p>{'' if report['frames'] is None else str(report['frames']) + ' frames, '}"
        f"{report['frames_with_gauges']} showing a dial labelled visible, {len(report['gauges'])} dial views.</p>"
        "<p>What the dataset is for: every frame carries the true level of every dial it shows, so a gauge "
        "reader can be scored against the conditions it was taken in. The baseline reads a dial the study's "
        "way: on the dial's projected box (the ROI) it takes the dark pixels of the dial face, finds the ray "
        "from the pivot along which they run, and turns that angle into a level through the inverse of the "
        "gauge's level &rarr; angle binding. Two readers differ in what is dark: <b>study</b> takes the study's "
        f"fixed V &le; {DARK_V}; <b>relative</b> takes V &le; {DARK_OF_FACE:g} of the face's median V, which "
        "follows the phone's auto-exposure. Error = read &minus; true, in % of the level. "
        f"Dials narrower than {report['min_dial_px']} px, or not wholly in the frame, are counted, not scored; "
        "a scored dial is unreadable when its face shows no dark pixel (glare), too many or too dim a face "
        "(night, shadow), or no dark run along one ray. C, S: the study's RMS contrast and share of grey levels "
        "above 240 on the ROI; H: the study's pointer extent (dark rows, V &le; 80) on the face over the true "
        "row extent of the pointer's projected outline in the same frame (1: the whole pointer and nothing "
        "else; H true = 1).</p>"
        f"<h2>Error by condition</h2><table>{head}{body}</table>"
        "<h2>Against sun elevation</h2>"
        f"<img src=\"{e(report['plots']['sun'])}\" alt=\"reading error and H against sun elevation\">"
        "<h2>Against local time</h2>"
        f"<img src=\"{e(report['plots']['time'])}\" alt=\"reading error and H against local time\">"
        "<h2>What the readers saw</h2><p>The first scored dials of each condition, their ROI as the frame "
        "holds it (true level; each reader's reading or why it has none).</p>" + _gallery(report, caption) +
        f"<h2>Every gauge seen</h2><table>{gauge_head}{gauge_rows}</table></body></html>\n")
