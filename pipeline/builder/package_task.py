"""The package task's action: an asset's package in every format from its geometry
task's result and asset.toml's metadata (builder.tasks)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .. import config, ir
from ..errors import UserError
from ..digest import sha256_file
from .layout import ir_path

# what build_asset imports (mostly inside functions), and jsonschema for asset.toml's
# check: an idle worker imports them ahead
WARM = ("pipeline.builder.irfile", "pipeline.engine.memo", "pipeline.export.package", "pipeline.export.collada",
        "pipeline.export.gltf", "pipeline.export.usd", "pipeline.export.sdf", "pipeline.export.thumbnail",
        "pipeline.export.manifest", "pipeline.validate.checks", "collada", "lxml.etree", "PIL.Image",
        "pxr.Usd", "pxr.UsdGeom", "pxr.UsdShade", "pxr.UsdPhysics", "pxr.UsdSkel", "jsonschema")


def with_metadata(asset: ir.Asset, cfg: config.AssetConfig) -> ir.Asset:
    """asset.toml's description, category and mass on an asset the geometry task made:
    the links keep their shares of the mass."""
    total = sum(link.mass for link in asset.links)
    links = asset.links
    if total > 0:
        links = tuple(dataclasses.replace(link, mass=cfg.mass_kg * link.mass / total) for link in links)
    return asset.with_(description=cfg.description, category=cfg.category, links=links)


def terminals(cfg: config.AssetConfig, asset: ir.Asset) -> list[dict]:
    """The manifest's terminals: asset.toml's [[terminals]] as written, then the
    source's (a .blend's `terminal.<name>` empties, to the micrometre: Blender keeps
    single precision). A name given by both is an error naming both places."""
    written = {n: xyz for n, xyz in cfg.terminals}
    clashes = [f"terminal {n!r} is in asset.toml [[terminals]] at {list(written[n])} and in {Path(cfg.source).name} "
               f"(Empty terminal.{n} at {[round(v, 6) for v in xyz]})" for n, xyz in asset.terminals if n in written]
    if clashes:
        raise UserError(cfg.path, "terminals", "; ".join(clashes) + ": keep one of each")
    return [{"name": n, "position": list(xyz)} for n, xyz in cfg.terminals] + \
        [{"name": n, "position": [round(v, 6) + 0.0 for v in xyz]} for n, xyz in asset.terminals]


def build_asset(staging: Path, asset_toml: str, build: str, memo: str | None = None,
                memo_namespace: str = "", checks_namespace: str = "") -> dict:
    """Task action: one asset's package from its geometry task's result. `memo`: the
    cache folder whose memo holds the COLLADA documents of earlier builds, under
    `memo_namespace` (the task's code version), and the per-mesh checks' findings
    (most made by the geometry task's checks of the same meshes), under
    `checks_namespace`."""
    from ..export import manifest
    from ..export.package import write_package
    from ..findings import Finding, as_dicts
    from ..validate.checks import budget_findings, check_asset
    from . import irfile
    from ..engine.memo import ArrayMemo, FileMemo

    t = time.perf_counter()
    cfg = config.load_asset_config(Path(asset_toml))
    documents = None if memo is None else FileMemo(Path(memo), memo_namespace)
    checked = None if memo is None else ArrayMemo(Path(memo), checks_namespace)
    asset, extra = irfile.read(Path(build) / ir_path(cfg.id), cfg.source)
    asset = with_metadata(asset, cfg)
    source_findings = [Finding.from_dict(d) for d in extra["source_findings"]]
    source_findings += budget_findings(asset.id, extra["source_triangles"], cfg.triangle_budget)
    models = Path(staging) / "models"
    models.mkdir(parents=True, exist_ok=True)
    outputs, lod_models, built_findings, reused = write_package(
        asset, models, alongside=lambda: check_asset(asset, cfg.triangle_budget, checked), memo=documents)
    source = {"file": cfg.source.name, "sha256": sha256_file(cfg.source), "config_sha256": sha256_file(cfg.path)}
    data = manifest.content(asset, source=source, outputs=outputs, lod_models=lod_models)
    # conductor attachment points, model frame: what the scene strings its spans between
    data["terminals"] = terminals(cfg, asset)
    data["findings"] = {"source": as_dicts(source_findings), "built": as_dicts(built_findings)}
    manifest.write(data, models / asset.id)
    return {"asset": asset.id, "triangles": [lod["triangles"] for lod in data["lods"]],
            "errors_m": [lod["error_m"] for lod in data["lods"]], "timings": {"write": time.perf_counter() - t},
            **({"collada_documents": reused} if reused else {})}
