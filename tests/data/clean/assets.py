"""Assets that must give no finding: the writers' articulated fixture, the crate every
bad/ fixture starts from, and the mini sources' kiosk (unwelded STL facets, two boxes)
and pole (cylinder and sphere) as a reader would hand them over."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from fixtures_assets import articulated_asset
from pipeline import ir

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bad"))
from assets import base, two_links  # noqa: E402

import mini_sources  # noqa: E402


def _from_trimesh(asset_id: str, mesh) -> ir.Asset:
    m = ir.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    link = ir.Link("root", visuals=(ir.Visual("body", "default", (m,)),), collisions=(ir.Collision("hull", m),))
    return ir.Asset(id=asset_id, category=asset_id, links=(link,), materials=(ir.Material("default"),))


FIXTURES = {
    "articulated": lambda: articulated_asset(),
    "crate": lambda: base(),
    "crate_with_lid": lambda: two_links(),
    "kiosk": lambda: _from_trimesh("kiosk", mini_sources.kiosk_mesh()),
    "pole": lambda: _from_trimesh("pole", mini_sources.pole_mesh()),
}
