"""The geometry task's .ir file: exact round trip, same bytes every time, data only."""

from __future__ import annotations

import dataclasses
import json
import struct

import numpy as np
import pytest

from fixtures_assets import articulated_asset, box_mesh
from helpers import ROOT
from pipeline import config, ir
from pipeline.builder import irfile
from pipeline.builder.geometry_task import asset_steps
from pipeline.ingest.readers import read_source
from pipeline.errors import UserError


def _same(a, b, where="asset") -> None:
    """Field-by-field equality of two ir trees, arrays bit for bit."""
    assert type(a) is type(b), where
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), where
    elif isinstance(a, tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


@pytest.fixture(scope="module")
def shunt_reactor() -> ir.Asset:
    """A sample asset with shape keys (oil columns), bindings and materials, as read."""
    cfg = config.load_asset_config(ROOT / "sources/assets/shunt_reactor/asset.toml")
    return read_source(cfg)


def test_sample_asset_round_trips_exactly(shunt_reactor):
    asset = shunt_reactor
    assert asset.bindings and any(m.shape_keys for _, v in asset.visuals() for m in v.lods)
    data = irfile.dumps(asset, {"note": [1, 2.5]})
    back, extra = irfile.loads(data)
    _same(asset, back)
    assert extra == {"note": [1, 2.5]}
    assert irfile.dumps(back, {"note": [1, 2.5]}) == data


def test_articulated_processed_asset_round_trips(tmp_path):
    cfg = config.load_asset_config(ROOT / "sources/assets/disconnect_switch_vb/asset.toml")
    asset = read_source(cfg)
    for name, step in asset_steps(cfg)[:2]:  # clean, collision: hulls beside the visuals
        asset = step(asset)
    assert asset.joints and any(link.collisions for link in asset.links)
    path = tmp_path / "a.ir"
    irfile.write(path, asset)
    # the file names the source by file name (the same bytes wherever the sources sit);
    # the reader is handed its path
    assert str(cfg.source.parent).encode() not in path.read_bytes()
    assert irfile.read(path)[0].source == cfg.source.name
    back, _ = irfile.read(path, cfg.source)
    _same(asset, back)


def _header(data: bytes) -> tuple[dict, bytes]:
    (n,) = struct.unpack_from("<Q", data, len(irfile.MAGIC))
    start = len(irfile.MAGIC) + 8
    return json.loads(data[start:start + n]), data[start + n:]


def _with_header(header: dict, body: bytes) -> bytes:
    text = json.dumps(header).encode()
    text += b" " * (-(len(irfile.MAGIC) + 8 + len(text)) % 8)
    return irfile.MAGIC + struct.pack("<Q", len(text)) + text + body


@pytest.mark.parametrize("tamper", ["object dtype", "unknown class", "truncated", "not an ir file"])
def test_a_tampered_file_is_refused_without_running_anything(shunt_reactor, tmp_path, tamper):
    data = irfile.dumps(shunt_reactor)
    header, body = _header(data)
    if tamper == "object dtype":
        header["arrays"][0]["dtype"] = "|O"
        data = _with_header(header, body)
    elif tamper == "unknown class":
        header["asset"]["$"] = "Popen"
        data = _with_header(header, body)
    elif tamper == "truncated":
        data = data[: len(data) // 2]
    else:
        data = b"\x80\x04pickle" + data
    path = tmp_path / "bad.ir"
    path.write_bytes(data)
    with pytest.raises(UserError, match="bad.ir"):
        irfile.read(path)


def test_mesh_digest_follows_content_not_identity(tmp_path):
    """The memos know a mesh by `Mesh.digest`: the same arrays give the same digest,
    also as read back from an .ir file; any array changed, another one."""
    box = box_mesh(attributes=True)
    twin = ir.Mesh(box.vertices.copy(), box.faces.copy(), box.normals.copy(), box.uvs.copy())
    assert twin.digest == box.digest
    assert ir.Mesh(box.vertices + 1e-9, box.faces, box.normals, box.uvs).digest != box.digest
    assert ir.Mesh(box.vertices, box.faces, None, box.uvs).digest != box.digest
    keyed = ir.Mesh(box.vertices, box.faces, box.normals, box.uvs, (ir.ShapeKey("open", box.vertices * 2),))
    assert keyed.digest != box.digest
    renamed = ir.Mesh(box.vertices, box.faces, box.normals, box.uvs, (ir.ShapeKey("shut", box.vertices * 2),))
    assert renamed.digest != keyed.digest
    asset = articulated_asset()
    irfile.write(tmp_path / "a.ir", asset)
    back, _ = irfile.read(tmp_path / "a.ir")
    assert [v.mesh.digest for _, v in back.visuals()] == [v.mesh.digest for _, v in asset.visuals()]


def test_a_textured_asset_round_trips_its_images(tmp_path):
    """Image bytes (a PNG and an image that is only bytes to the file) come back equal,
    the material's other fields too: a textured source's task result is storable."""
    png = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 3
    jpeg = b"\xff\xd8\xff" + b"\x00\x01" * 500
    mat = ir.Material("painted", base_color=(1.0, 0.5, 0.25, 1.0), base_color_texture=ir.Texture("albedo", png),
                      normal_texture=ir.Texture("bumps", jpeg))
    asset = ir.Asset("t", "x", (ir.Link("l", visuals=(ir.Visual("v", "painted", (box_mesh(attributes=True),)),)),),
                     materials=(mat,))
    irfile.write(tmp_path / "a.ir", asset)
    back, _ = irfile.read(tmp_path / "a.ir")
    got = back.material("painted")
    assert got.base_color_texture.data == png and got.normal_texture.data == jpeg
    assert got.key() == mat.key() and got.normal_texture.mime == "image/jpeg"
    assert irfile.dumps(back) == irfile.dumps(asset)
