"""bench.json (raw figures) and bench.html (plots as base64 PNG, one sentence each, the
summary and targets tables, the machine). Both written by temp-and-rename."""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

from ..files import atomic_write
from . import figures

SCHEMA_ID = "substation-twin/bench/1"


def clean(obj):
    """JSON-safe: non-finite floats become null, numpy scalars become Python numbers."""
    if isinstance(obj, dict):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(doc: dict, path: Path) -> None:
    atomic_write(path, json.dumps(clean(doc), indent=1, sort_keys=True, allow_nan=False) + "\n")


def _fmt(v, unit: str = "") -> str:
    if v is None:
        return "-"
    if unit == "bytes":
        for u in ("B", "kB", "MB", "GB"):
            if abs(v) < 1000 or u == "GB":
                return f"{v:.3g} {u}"
            v /= 1000.0
    if isinstance(v, float):
        return f"{v:.4g}" + (f" {unit}" if unit else "")
    return f"{v}" + (f" {unit}" if unit else "")


def _plots(doc: dict) -> list[tuple[str, bytes, str]]:
    s = {k: v["data"] for k, v in doc["sections"].items() if v.get("ok")}
    todo = [
        ("LOD: time against error", figures.lod, (s.get("lod"),)),
        ("Georeferencing", figures.georef, (s.get("georef"),)),
        ("Sun", figures.sun, (s.get("sun"),)),
        ("Build", figures.build_times, (s.get("build"),)),
        ("Build scaling", figures.build_scaling, (s.get("build"),)),
        ("Runtime", figures.runtime, (s.get("runtime"), s.get("blender_reexport"))),
        ("Peer: Blender monolithic", figures.blender, (s.get("blender"),)),
        ("Peer: glTF-Transform", figures.gltf_transform, (s.get("gltf_transform"),)),
    ]
    out = []
    for title, fn, args in todo:
        if args[0] is None:
            continue
        try:
            got = fn(*args)
        except Exception as e:  # a plot that fails must not lose the page
            out.append((title, b"", f"plot failed: {type(e).__name__}: {e}"))
            continue
        if got:
            out.append((title, got[0], got[1]))
    return out


def write_html(doc: dict, path: Path) -> None:
    e = html.escape
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>substation-twin bench</title>",
             "<style>body{font:14px sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:3px 6px;font-size:12px}.bad{color:#b00}.ok{color:#070}"
             "img{max-width:100%}</style></head><body>",
             f"<h1>substation-twin bench</h1><p>{'quick run (mini sizes) ' if doc['quick'] else ''}"
             f"sources: {e(str(doc['sources']))}; total {doc['total_s']:.0f} s. Ratio = ours / peer, both measured "
             "in this run on the same inputs: below 1 means ours is faster, smaller or more accurate.</p>"]
    parts.append("<h2>Summary</h2><table><tr><th>section</th><th>metric</th><th>ours</th><th>peer</th>"
                 "<th>ratio</th><th>note</th></tr>")
    for r in doc["summary"]:
        parts.append(f"<tr><td>{e(r['section'])}</td><td>{e(r['metric'])}</td><td>{_fmt(r['ours'], r['unit'])}</td>"
                     f"<td>{_fmt(r['peer'], r['unit'])} ({e(r['peer_name'])})</td><td>{_fmt(r['ratio'])}</td>"
                     f"<td>{e(r.get('note', ''))}</td></tr>")
    parts.append("</table>")
    if doc.get("targets"):
        parts.append("<h2>Build targets</h2><table><tr><th>target</th><th>measured</th><th>limit</th><th>met</th></tr>")
        for t in doc["targets"]:
            cls = "ok" if t["met"] else "bad"
            parts.append(f"<tr><td>{e(t['target'])}</td><td>{_fmt(t['value'], t['unit'])}</td>"
                         f"<td>{_fmt(t['limit'], t['unit'])}</td><td class='{cls}'>{'yes' if t['met'] else 'NO'}</td></tr>")
        parts.append("</table>")
    failed = {k: v for k, v in doc["sections"].items() if not v.get("ok")}
    if failed:
        parts.append("<h2>Sections that did not run</h2><ul>")
        parts += [f"<li class='bad'><b>{e(k)}</b>: {e(v.get('error', ''))}</li>" for k, v in failed.items()]
        parts.append("</ul>")
    for title, png, sentence in _plots(doc):
        parts.append(f"<h2>{e(title)}</h2><p>{e(sentence)}</p>")
        if png:
            parts.append(f"<img alt='{e(title)}' src='data:image/png;base64,{base64.b64encode(png).decode()}'>")
    parts.append("<h2>Machine</h2><table>")
    m = doc["machine"]
    for k, v in m.items():
        if k != "libraries":
            parts.append(f"<tr><td>{e(k)}</td><td>{e(str(v))}</td></tr>")
    parts.append("<tr><td>libraries</td><td>" + e(", ".join(f"{k} {v}" for k, v in m["libraries"].items() if v)) +
                 "</td></tr></table>")
    parts.append("<h2>Section times</h2><table>")
    parts += [f"<tr><td>{e(k)}</td><td>{v['seconds']:.1f} s</td></tr>" for k, v in doc["sections"].items()]
    parts.append("</table><p>Raw figures: bench.json beside this page.</p></body></html>")
    atomic_write(path, "\n".join(parts))
