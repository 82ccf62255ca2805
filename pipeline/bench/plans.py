"""Sources folders made for the build benches, all derived from a given sources folder.

- copy_sources: a private copy (the one-asset edit must not touch the user's files).
- repeated: the floor plan repeated m times, each copy of every INSERT and platform
  offset onto new ground in a grid, tags suffixed; assets/ is a symlink to the
  original's, so asset task keys (which hash the resolved asset paths' content) are
  unchanged and a shared build folder rebuilds only terrain and scene.
- unique_assets: one INSERT of each of the first n placed asset kinds, nothing else.
- at_scale: a plan of a given number of placements as real site plans are drawn: the
  layout repeated as above, and a share of the INSERTs piled on one insertion point
  (blocks whose base point is not the device's own stack up where they were inserted).

A `salt` adds one TEXT entity (the reader counts and ignores it) so the plan's hash
changes and the scene work really reruns on each repeat instead of coming from the cache.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

GAP_M = 60.0  # between copies: leaves room for slopes (drop x slope ratio) and skirts


def copy_sources(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("authoring", "__pycache__"))
    return dst


def _site_floorplan(sources: Path) -> str:
    from .. import config

    return config.load_site(Path(sources) / "site.toml").floorplan


def _shell(src: Path, dst: Path, scenarios: bool = True) -> tuple[Path, Path]:
    """dst with the site's settings (site.toml and the other top-level .toml files it
    reads beside it: conductors, clearances, study) and scenarios copied, assets/
    linked; returns (src plan, dst plan)."""
    dst.mkdir(parents=True, exist_ok=True)
    for settings in sorted(src.glob("*.toml")):
        shutil.copy2(settings, dst / settings.name)
    if scenarios and (src / "scenarios").is_dir():
        shutil.copytree(src / "scenarios", dst / "scenarios", dirs_exist_ok=True)
    if not (dst / "assets").exists():
        os.symlink((src / "assets").resolve(), dst / "assets", target_is_directory=True)
    rel = _site_floorplan(src)
    (dst / rel).parent.mkdir(parents=True, exist_ok=True)
    return src / rel, dst / rel


def salt_plan(path: Path, salt: str) -> None:
    """Add an ignored TEXT entity so the plan's content hash changes."""
    import ezdxf

    doc = ezdxf.readfile(path)
    doc.modelspace().add_text(f"bench {salt}", dxfattribs={"layer": "BENCH_NOTE"})
    doc.saveas(path)


def repeated(src: Path, dst: Path, copies: int) -> Path:
    """Sources whose floor plan holds `copies` copies of src's placements and platforms."""
    import ezdxf

    src_plan, dst_plan = _shell(Path(src), Path(dst))
    doc = ezdxf.readfile(src_plan)
    msp = doc.modelspace()
    inserts = list(msp.query("INSERT"))
    platforms = [e for e in msp.query("LWPOLYLINE") if e.dxf.layer.upper().startswith("PLATFORM_")]
    xs, ys = [], []
    for p in platforms:
        for x, y, *_ in p.get_points():
            xs.append(x)
            ys.append(y)
    unit = 1000.0 if doc.header.get("$INSUNITS", 6) == 4 else 1.0
    width = (max(xs) - min(xs)) + GAP_M * unit
    height = (max(ys) - min(ys)) + GAP_M * unit
    cols = math.ceil(math.sqrt(copies))
    for k in range(1, copies):
        dx, dy = (k % cols) * width, (k // cols) * height
        for e in inserts:
            c = e.copy()
            c.translate(dx, dy, 0)
            for a in c.attribs:
                if a.dxf.tag.upper() == "TAG":
                    a.dxf.text = f"{a.dxf.text}-R{k}"
            msp.add_entity(c)
        for p in platforms:
            c = p.copy()
            c.translate(dx, dy, 0)
            msp.add_entity(c)
    doc.saveas(dst_plan)
    return Path(dst)


def at_scale(src: Path, dst: Path, placements: int, piled: int) -> Path:
    """Sources with exactly `placements` INSERTs: src's layout repeated (the last copy
    cut short), `piled` of them copies of src's INSERTs (in turn) all inserted at its
    first INSERT's point and level, tags suffixed -P<k>."""
    import ezdxf

    per_copy = _insert_count(Path(src))
    laid = placements - piled
    repeated(src, dst, math.ceil(laid / per_copy))
    plan = Path(dst) / _site_floorplan(dst)
    doc = ezdxf.readfile(plan)
    msp = doc.modelspace()
    inserts = list(msp.query("INSERT"))
    for e in inserts[laid:]:
        msp.delete_entity(e)
    spot, level = inserts[0].dxf.insert, inserts[0].get_attrib_text("LEVEL")
    for k in range(piled):
        c = inserts[k % per_copy].copy()
        c.translate(*(spot - c.dxf.insert))
        for a in c.attribs:
            if a.dxf.tag.upper() == "TAG":
                a.dxf.text = f"{a.dxf.text}-P{k}"
            elif a.dxf.tag.upper() == "LEVEL":
                a.dxf.text = level
        msp.add_entity(c)
    doc.saveas(plan)
    return Path(dst)


def _insert_count(sources: Path) -> int:
    import ezdxf

    return len(ezdxf.readfile(sources / _site_floorplan(sources)).modelspace().query("INSERT"))


def unique_assets(src: Path, dst: Path, count: int) -> tuple[Path, list[str]]:
    """Sources placing each of the first `count` placed asset kinds (sorted ids) once, at
    the position of its first INSERT in src's plan (same platforms). Scenarios are left
    out: they would add their assets. Returns (folder, asset ids)."""
    import ezdxf

    src_plan, dst_plan = _shell(Path(src), Path(dst), scenarios=False)
    doc = ezdxf.readfile(src_plan)
    msp = doc.modelspace()
    inserts = list(msp.query("INSERT"))
    first: dict[str, object] = {}
    for e in sorted(inserts, key=lambda e: e.dxf.name):
        first.setdefault(e.dxf.name, e)
    chosen = sorted(first)[:count]
    keep = {id(first[a]) for a in chosen}
    for e in inserts:
        if id(e) not in keep:
            msp.delete_entity(e)
    doc.saveas(dst_plan)
    return Path(dst), chosen
