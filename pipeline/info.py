"""`twin info`: what a sources folder holds and what is wrong with it."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.table import Table

from . import config
from .digest import sha256_file
from .errors import UserError
from .ingest import size


@dataclass
class InfoReport:
    sources: Path
    site: str = ""
    assets: dict[str, dict] = field(default_factory=dict)  # id -> category, source, triangles
    per_level: dict[str, int] = field(default_factory=dict)
    per_asset: dict[str, int] = field(default_factory=dict)
    unused: list[str] = field(default_factory=list)
    ignored: list[tuple[str, int]] = field(default_factory=list)
    absorbed: list[tuple[str, int]] = field(default_factory=list)  # mapped block -> INSERTs it absorbs
    warnings: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    conductors: dict[str, int] = field(default_factory=dict)  # spans in site.toml, lines in the plan, types


def _triangles(cfg: config.AssetConfig, build: Path) -> int | None:
    """LOD0 triangles: from a built manifest of the same source, else by reading it. A
    source its reader refuses by size is refused before it is hashed."""
    refused = size.refusal(cfg.source)
    if refused is not None:
        raise refused
    manifest = build / "models" / cfg.id / "manifest.json"
    if manifest.is_file():
        data = json.loads(manifest.read_text())
        if data.get("source", {}).get("sha256") == sha256_file(cfg.source):
            return data["lods"][0]["triangles"]
    from .ingest.readers import read_source

    return read_source(cfg).triangle_count(0)


def gather(sources: Path, build: Path = Path("build"), progress=None) -> InfoReport:
    """Every problem of the sources, each file on its own: a broken site.toml still
    lets the assets be checked, a broken asset the others and the floor plan.
    `progress`: a progress.Bar that each asset read advances."""
    sources = Path(sources)
    r = InfoReport(sources=sources)
    try:
        site = config.load_site(sources / "site.toml")
        r.site = site.name
    except UserError as e:
        site = None
        r.problems.append(str(e))
    assets, problems = config.load_assets(sources)
    r.problems.extend(str(p) for p in problems)
    if progress is not None:
        progress.add(len(assets))
    for asset_id, cfg in sorted(assets.items()):
        entry = {"category": cfg.category, "source": cfg.source.name, "triangles": None}
        try:
            entry["triangles"] = _triangles(cfg, build)
        except UserError as e:
            r.problems.append(str(e))
        except MemoryError:
            r.problems.append(f"{cfg.source}: ran out of memory reading it")
        except Exception as e:  # noqa: BLE001 - a reader's bug on this file hides no other problem
            r.problems.append(f"{cfg.source}: cannot be read ({type(e).__name__}: {e})")
        r.assets[asset_id] = entry
        if progress is not None:
            progress.step(asset_id)
    for asset_id in sorted(config.asset_ids(sources) - set(assets)):  # its asset.toml is a problem above
        r.assets[asset_id] = {"category": "?", "source": "?", "triangles": None}
    if site is None:  # the floor plan is read with site.toml's levels and block names
        return r
    from .ingest.floorplan import require_placements_and_platforms, scan_floorplan

    try:
        # every asset folder: a broken asset.toml is its own problem, not its INSERTs'
        fp, plan_problems = scan_floorplan(site.root / site.floorplan, known_assets=config.asset_ids(sources),
                                           levels=set(site.level_names), options=site.floorplan_options)
    except UserError as e:
        r.problems.append(str(e))
        return r
    r.problems.extend(str(p) for p in plan_problems)
    r.warnings = [w for w in fp.warnings if not w.startswith(("no placements", "no platforms"))]
    try:
        require_placements_and_platforms(fp)
    except UserError as e:
        r.problems.append(str(e))
    from . import site_frame

    try:
        site_frame.check(site, fp)
    except UserError as e:
        r.problems.append(str(e))
    r.per_level = dict(sorted(Counter(p.level for p in fp.placements).items()))
    r.per_asset = dict(sorted(Counter(p.asset_id for p in fp.placements).items()))
    from .builder.tasks import scenario_assets

    used = set(r.per_asset) | scenario_assets(sources)
    r.unused = sorted(set(assets) - used)
    r.ignored = list(fp.ignored)
    _conductors(r, site, fp, assets)
    r.absorbed = list(fp.absorbed)
    return r


def _conductors(r: InfoReport, site, fp, assets: dict) -> None:
    """The conductors' sources: counts, and every [[conductors]] end whose tag or
    terminal does not exist (the plan's lines are snapped when the scene is built; a
    .blend's own terminals are known once it is read, at build time)."""
    from .wiring import load_wiring

    try:
        w = load_wiring(site)
    except UserError as e:
        r.problems.append(str(e))
        return
    if w.empty:
        return
    r.conductors = {"spans in site.toml": len(w.specs), "lines in the floor plan": len(fp.conductor_lines),
                    "conductor types": len(w.types)}
    asset_of = {p.tag: p.asset_id for p in fp.placements}
    for spec in w.specs:
        for tag, name in (spec.start, spec.end):
            if tag not in asset_of:
                r.problems.append(f"{site.path}: conductors: conductor {spec.id}: no placement is tagged {tag!r}")
            elif asset_of[tag] in assets and name not in {n for n, _ in assets[asset_of[tag]].terminals} \
                    and assets[asset_of[tag]].source.suffix.lower() != ".blend":
                # a .blend's terminals are its `terminal.<name>` empties, read when it is built
                r.problems.append(f"{site.path}: conductors: conductor {spec.id}: {tag} ({asset_of[tag]}) has no "
                                  f"terminal {name!r}")


def render(r: InfoReport, console: Console | None = None, errors: Console | None = None) -> None:
    """The report on `console` (stdout); every problem on `errors` (stderr), one line
    each, as `twin build` ends with its errors."""
    console = console or Console(width=140)
    errors = errors or Console(stderr=True, width=140)
    console.print(f"[bold]{r.site or 'site.toml unread'}[/] ({r.sources})")
    table = Table("category", "asset", "source", "triangles", "placements")
    for asset_id, a in sorted(r.assets.items(), key=lambda kv: (kv[1]["category"], kv[0])):
        tri = "?" if a["triangles"] is None else f"{a['triangles']:,}"
        table.add_row(a["category"], asset_id, a["source"], tri, str(r.per_asset.get(asset_id, 0)))
    console.print(table)
    if r.site:  # the floor plan was read
        levels = Table("level", "placements")
        for level, n in r.per_level.items():
            levels.add_row(level, str(n))
        levels.add_row("[bold]all", str(sum(r.per_level.values())))
        console.print(levels)
    if r.conductors:
        console.print("conductors: " + ", ".join(f"{k} {n}" for k, n in r.conductors.items()))
    if r.unused:
        console.print(f"assets no placement or scenario uses: {', '.join(r.unused)}")
    if r.absorbed:
        console.print(f"INSERTs absorbed by mapped blocks (their models stand for them): "
                      f"{sum(n for _, n in r.absorbed)} in " + ", ".join(f"{k} x{n}" for k, n in r.absorbed))
    if r.ignored:
        console.print("ignored drawing entities: " + ", ".join(f"{k} x{n}" for k, n in r.ignored))
    from rich.markup import escape

    for w in r.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    for p in r.problems:
        errors.print(f"[red]error:[/] {escape(p)}", soft_wrap=True)
