"""pipeline.export.thumbnail: a numpy z-buffer render, no Blender."""

from __future__ import annotations

import time

import numpy as np
import pytest
from PIL import Image

from fixtures_assets import box_mesh
from pipeline import ir
from pipeline.export import thumbnail

def sphere(nu: int, nv: int, r: float = 1.0) -> ir.Mesh:
    """A UV sphere of 2 * nu * nv triangles (poles included as degenerate ones)."""
    th = np.linspace(0, np.pi, nv + 1)
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), r * np.cos(t)], -1).reshape(-1, 3)
    i = np.arange(nv)[:, None] * nu
    j = np.arange(nu)[None, :]
    a, b, c, d = i + j, i + (j + 1) % nu, i + nu + j, i + nu + (j + 1) % nu
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return ir.Mesh(v, faces)


def translate(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


RED = ir.Material("red", (0.8, 0.02, 0.02, 1.0))
BLUE = ir.Material("blue", (0.02, 0.02, 0.8, 1.0))
GLASS = ir.Material("glass", (0.9, 0.9, 1.0, 0.2))


def asset_of(*visuals, materials=(RED, BLUE, GLASS)) -> ir.Asset:
    return ir.Asset("a", "test", (ir.Link("base", visuals=visuals),), materials=materials)


def simple() -> ir.Asset:
    return asset_of(
        ir.Visual("ball", "red", (sphere(40, 20),), translate(0, 0, 1.2)),
        ir.Visual("plinth", "blue", (box_mesh((3, 3, 0.4)),)),
    )


def test_png_exists_has_size_and_content(tmp_path):
    names = thumbnail.write(simple(), tmp_path, size=128)
    assert names == ["thumbnail.png"]
    img = Image.open(tmp_path / "thumbnail.png")
    assert img.size == (128, 128) and img.mode == "RGB"
    px = np.asarray(img).reshape(-1, 3).astype(int)
    drawn = px[(px != 255).any(axis=1)]
    assert 0.15 * len(px) < len(drawn) < 0.9 * len(px)
    reddish = (drawn[:, 0] > drawn[:, 2] + 60).sum()
    bluish = (drawn[:, 2] > drawn[:, 0] + 60).sum()
    assert reddish > 500 and bluish > 500  # each visual in its own base colour
    assert len(np.unique(drawn[:, 0])) > 10  # shaded, not flat
    assert not list(tmp_path.glob(".*.tmp"))


def test_rerun_is_byte_identical_and_has_no_metadata(tmp_path):
    thumbnail.write(simple(), tmp_path / "a")
    thumbnail.write(simple(), tmp_path / "b")
    a = (tmp_path / "a" / "thumbnail.png").read_bytes()
    assert a == (tmp_path / "b" / "thumbnail.png").read_bytes()
    assert not any(chunk in a for chunk in (b"tEXt", b"tIME", b"iTXt", b"zTXt", b"pHYs"))


def test_nearer_surface_wins():
    toward = thumbnail.view_basis()[2]
    near = ir.Visual("near", "red", (box_mesh((1, 1, 1)),), translate(*(toward * 2.0)))
    far = ir.Visual("far", "blue", (box_mesh((1, 1, 1)),))
    for order in ((near, far), (far, near)):
        img = thumbnail.render(asset_of(*order), 64).astype(int)
        centre = img[32, 32]
        assert centre[0] > centre[2] + 60


def test_transparent_visuals_are_skipped_and_empty_asset_is_white():
    glass = ir.Visual("cover", "glass", (box_mesh((4, 4, 4)),))
    with_glass = thumbnail.render(asset_of(glass, *simple().link("base").visuals), 64)
    assert np.array_equal(with_glass, thumbnail.render(simple(), 64))
    assert np.all(thumbnail.render(asset_of(glass), 32) == 255)


def test_heavy_asset_draws_its_coarsest_lod():
    heavy = sphere(400, 250)  # 200k triangles
    assert heavy.triangle_count > thumbnail.MAX_TRIANGLES
    lod_box = box_mesh((1, 2, 3))
    both = asset_of(ir.Visual("v", "red", (heavy, lod_box)))
    coarse_only = asset_of(ir.Visual("v", "red", (lod_box,)))
    assert np.array_equal(thumbnail.render(both, 64), thumbnail.render(coarse_only, 64))


def test_300k_triangles_without_lods_render_fully():
    mesh = sphere(500, 300)
    assert mesh.triangle_count == 300_000
    t0 = time.perf_counter()
    img = thumbnail.render(asset_of(ir.Visual("ball", "red", (mesh,))), 256)
    print(f"300k triangles: {time.perf_counter() - t0:.2f} s")
    # A closed sphere renders as a disc with no holes: every pixel inside is drawn.
    yy, xx = np.mgrid[0:256, 0:256]
    radius = 256 * (1 - 2 * thumbnail.MARGIN) / 2
    inner = (xx + 0.5 - 128) ** 2 + (yy + 0.5 - 128) ** 2 < (radius - 2) ** 2
    assert np.all((img[inner] != 255).any(axis=1))
    outer = (xx + 0.5 - 128) ** 2 + (yy + 0.5 - 128) ** 2 > (radius + 2) ** 2
    assert np.all(img[outer] == 255)


@pytest.mark.parametrize("size", [16, 100])
def test_any_size(tmp_path, size):
    thumbnail.write(simple(), tmp_path, size=size)
    assert Image.open(tmp_path / "thumbnail.png").size == (size, size)
