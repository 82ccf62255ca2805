"""The files a reader opens through a source (ingest.images.SourceFiles): a Blender
"glTF Separate" export's .bin and images, an OBJ's .mtl and its images, COLLADA images
in and out of the asset's folder, and the caps on an image from every route in."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from pipeline.errors import UserError
from pipeline.ingest.mesh import read_mesh


def cfg(path: Path) -> SimpleNamespace:
    return SimpleNamespace(id="x", category="c", description="", source=Path(path), units=None, up_axis=None,
                           scale=1.0)


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def pixels(texture) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(texture.data)).convert("RGB"))


def warnings_of(asset) -> dict[str, str]:
    return {k.removeprefix("warning."): v for k, v in asset.metadata if k.startswith("warning.")}


def opened_of(asset) -> dict[str, str]:
    return json.loads(dict(asset.metadata).get("opened", "{}"))


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height 1-bit pixels, its data a few bytes: what
    a decompression bomb shows a reader before it decodes."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


def split_png(path: Path) -> None:
    px = np.zeros((4, 8, 3), dtype=np.uint8)
    px[:, :4] = (230, 20, 20)
    px[:, 4:] = (20, 20, 230)
    Image.fromarray(px).save(path)


# --- glTF Separate, as Blender writes it -----------------------------------------------

EXPORT = """
import sys
from pathlib import Path

import bpy

out = Path(sys.argv[1])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_cube_add(size=1.0)
ob = bpy.context.active_object
ob.name = "panel"
image = bpy.data.images.load(sys.argv[2])
mat = bpy.data.materials.new("painted")
mat.use_nodes = True
tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
tex.image = image
mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
ob.data.materials.append(mat)
bpy.ops.export_scene.gltf(filepath=str(out / "panel.gltf"), export_format="GLTF_SEPARATE",
                          export_texture_dir="textures")
"""


@pytest.fixture(scope="module")
def gltf_separate(tmp_path_factory) -> Path:
    """A textured cube exported by Blender's glTF exporter as "glTF Separate":
    panel.gltf, panel.bin and textures/paint.png."""
    pytest.importorskip("bpy")
    folder = tmp_path_factory.mktemp("separate")
    split_png(folder.parent / "paint.png")
    run = subprocess.run([sys.executable, "-c", EXPORT, str(folder), str(folder.parent / "paint.png")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()) == \
        ["panel.bin", "panel.gltf", "textures/paint.png"]
    return folder / "panel.gltf"


def test_a_gltf_separate_export_reads_its_bin_and_its_images(gltf_separate):
    asset = read_mesh(cfg(gltf_separate))
    assert asset.triangle_count() == 12
    (painted,) = [m for m in asset.materials if m.name == "painted"]
    assert painted.base_color[:3] == (1.0, 1.0, 1.0)  # glTF's unset factor: white, the image shows as drawn
    expected = np.asarray(Image.open(gltf_separate.parent / "textures" / "paint.png").convert("RGB"))
    assert np.array_equal(pixels(painted.base_color_texture), expected)
    folder = gltf_separate.parent
    assert opened_of(asset) == {rel: sha256((folder / rel).read_bytes())
                                for rel in ("panel.bin", "textures/paint.png")}
    assert warnings_of(asset) == {}


def test_a_missing_gltf_image_is_a_warning_naming_material_and_path(gltf_separate, tmp_path):
    import shutil

    folder = tmp_path / "asset"
    shutil.copytree(gltf_separate.parent, folder)
    (folder / "textures" / "paint.png").unlink()
    asset = read_mesh(cfg(folder / "panel.gltf"))
    assert asset.material("painted").base_color_texture is None
    (message,) = warnings_of(asset).values()
    assert "panel.gltf" in message and "'painted'" in message and "textures/paint.png" in message
    assert "not found" in message


# --- OBJ and its material library -------------------------------------------------------

def obj_tree(folder: Path, map_kd: str = "green.png") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 2), (20, 200, 20)).save(folder / "green.png")
    (folder / "m.mtl").write_text(f"newmtl red\nKd 0.9 0.1 0.1\nnewmtl grass\nKd 1 1 1\nmap_Kd {map_kd}\n")
    (folder / "t.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                  "vt 1 1\nusemtl red\nf 1/1 2/2 3/3\nusemtl grass\nf 2/2 4/4 3/3\n")
    return folder / "t.obj"


def test_an_obj_reads_its_mtl_colours_and_images(tmp_path):
    obj = obj_tree(tmp_path / "asset")
    asset = read_mesh(cfg(obj))
    red, grass = asset.material("red"), asset.material("grass")
    np.testing.assert_allclose(red.base_color, (0.9, 0.1, 0.1, 1.0), atol=1 / 255)  # the .mtl's Kd, not grey
    assert red.base_color_texture is None
    assert pixels(grass.base_color_texture)[0, 0].tolist() == [20, 200, 20]
    assert sorted(opened_of(asset)) == ["green.png", "m.mtl"]


def test_an_obj_image_linked_out_of_the_folder_stays_refused(tmp_path):
    secret = tmp_path / "secret.png"
    Image.new("RGB", (2, 2), (1, 2, 3)).save(secret)
    obj = obj_tree(tmp_path / "asset", "link.png")
    (obj.parent / "link.png").symlink_to(secret)
    with pytest.raises(UserError, match="m.mtl: map_Kd: 'link.png' leaves the file's folder"):
        read_mesh(cfg(obj))


# --- COLLADA images: as written, the Gazebo layout, and out of the folder ------------------

def textured_collada(init_from: str) -> str:
    """A triangle with texture coordinates whose material 'wood' samples one image."""
    return textwrap.dedent(f"""\
        <?xml version="1.0" encoding="utf-8"?>
        <COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
        <asset><unit meter="1" name="meter"/><up_axis>Z_UP</up_axis></asset>
        <library_images><image id="wood-img"><init_from>{init_from}</init_from></image></library_images>
        <library_effects><effect id="wood-fx"><profile_COMMON>
         <newparam sid="wood-surface"><surface type="2D"><init_from>wood-img</init_from></surface></newparam>
         <newparam sid="wood-sampler"><sampler2D><source>wood-surface</source></sampler2D></newparam>
         <technique sid="common"><lambert><diffuse><texture texture="wood-sampler" texcoord="UV"/></diffuse>
         </lambert></technique></profile_COMMON></effect></library_effects>
        <library_materials><material id="wood" name="wood"><instance_effect url="#wood-fx"/></material>
        </library_materials>
        <library_geometries><geometry id="g"><mesh>
         <source id="p"><float_array id="pa" count="9">0 0 0 1 0 0 0 1 0</float_array><technique_common>
          <accessor source="#pa" count="3" stride="3"><param name="X" type="float"/><param name="Y" type="float"/>
          <param name="Z" type="float"/></accessor></technique_common></source>
         <source id="t"><float_array id="ta" count="6">0 0 1 0 0 1</float_array><technique_common>
          <accessor source="#ta" count="3" stride="2"><param name="S" type="float"/><param name="T" type="float"/>
          </accessor></technique_common></source>
         <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
         <triangles count="1" material="m"><input semantic="VERTEX" source="#v" offset="0"/>
          <input semantic="TEXCOORD" source="#t" offset="0" set="0"/><p>0 1 2</p></triangles>
        </mesh></geometry></library_geometries>
        <library_visual_scenes><visual_scene id="s"><node id="n"><instance_geometry url="#g"><bind_material>
         <technique_common><instance_material symbol="m" target="#wood"><bind_vertex_input semantic="UV"
          input_semantic="TEXCOORD" input_set="0"/></instance_material></technique_common></bind_material>
        </instance_geometry></node></visual_scene></library_visual_scenes>
        <scene><instance_visual_scene url="#s"/></scene>
        </COLLADA>""")


def test_collada_images_resolve_as_written_and_the_gazebo_layout(tmp_path):
    """A SketchUp/Gazebo model's `../materials/textures/wood.png`, with the mesh moved
    beside asset.toml: found inside the asset's folder, as is `textures/wood.png`."""
    folder = tmp_path / "assets" / "pole"
    (folder / "materials" / "textures").mkdir(parents=True)
    Image.new("RGB", (4, 4), (120, 80, 40)).save(folder / "materials" / "textures" / "wood.png")
    for name, init_from in (("gazebo.dae", "../materials/textures/wood.png"),
                            ("written.dae", "materials/textures/wood.png"), ("bare.dae", "wood.png")):
        (folder / name).write_text(textured_collada(init_from))
        asset = read_mesh(cfg(folder / name))
        (material,) = asset.materials
        assert pixels(material.base_color_texture)[0, 0].tolist() == [120, 80, 40], name
        assert list(opened_of(asset)) == ["materials/textures/wood.png"] and warnings_of(asset) == {}, name


@pytest.mark.parametrize("init_from, why", [
    ("file:///etc/passwd", "an absolute path or URL (refused"),
    ("/etc/passwd", "an absolute path or URL (refused"),
    ("../../secret.png", "leaves the asset's folder (refused)"),
    ("link.png", "leaves the asset's folder (refused)"),
    ("missing.png", "not found in the asset's folder"),
])
def test_collada_images_out_of_the_folder_are_refused_with_a_warning(tmp_path, init_from, why):
    secret = tmp_path / "secret.png"
    Image.new("RGB", (2, 2), (1, 2, 3)).save(secret)
    folder = tmp_path / "assets" / "pole"
    folder.mkdir(parents=True)
    (folder / "link.png").symlink_to(secret)
    (folder / "pole.dae").write_text(textured_collada(init_from))
    asset = read_mesh(cfg(folder / "pole.dae"))
    assert all(m.base_color_texture is None for m in asset.materials)
    opened = opened_of(asset)  # nothing read; where a missing image was looked for, inside the folder only
    assert all(h is None for h in opened.values()) and all(".." not in k and not k.startswith("/") for k in opened)
    assert sorted(opened) == (["materials/textures/missing.png", "missing.png", "textures/missing.png"]
                              if init_from == "missing.png" else [])
    (message,) = warnings_of(asset).values()
    assert message.startswith(f"pole.dae: material 'wood': image '{init_from}': {why}"), message


# --- caps on an image, from every route in ----------------------------------------------------

def gltf_with_image(folder: Path, image: dict, extra_buffers: list[bytes] = ()) -> Path:
    """A textured triangle whose material 'skin' samples `image` (a glTF image object)."""
    geometry = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], np.float32).tobytes() + \
        np.array([0, 0, 1, 0, 0, 1], np.float32).tobytes()
    buffers = [{"byteLength": len(geometry), "uri": "data:application/octet-stream;base64,"
                + base64.b64encode(geometry).decode()}]
    buffers += [{"byteLength": len(b), "uri": "data:application/octet-stream;base64," + base64.b64encode(b).decode()}
                for b in extra_buffers]
    views = [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 24}]
    views += [{"buffer": 1 + i, "byteLength": len(b)} for i, b in enumerate(extra_buffers)]
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
           "materials": [{"name": "skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
           "textures": [{"source": 0}], "images": [image],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]},
                         {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}],
           "bufferViews": views, "buffers": buffers}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.gltf").write_text(json.dumps(doc))
    return folder / "m.gltf"


def data_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode()


@pytest.mark.parametrize("size, words", [((30000, 30000), "a decompression bomb (900,000,000 pixels)"),
                                          ((9000, 8192), "9000 x 8192 pixels, over the 67,108,864 pixel limit")])
def test_an_image_over_the_pixel_cap_is_refused_from_every_glTF_route(tmp_path, size, words):
    """data: URI, buffer view and file beside: each one warning naming the file, the
    material and the image; nothing decoded."""
    bomb = png_header_only(*size)
    (tmp_path / "bv").mkdir()
    routes = {
        "data": gltf_with_image(tmp_path / "data", {"name": "bomb", "uri": data_uri(bomb)}),
        "view": gltf_with_image(tmp_path / "view", {"name": "bomb", "bufferView": 2, "mimeType": "image/png"},
                                [bomb]),
        "file": gltf_with_image(tmp_path / "file", {"uri": "bomb.png"}),
    }
    (tmp_path / "file" / "bomb.png").write_bytes(bomb)
    for route, path in routes.items():
        asset = read_mesh(cfg(path))
        assert asset.material("skin").base_color_texture is None, route
        (message,) = warnings_of(asset).values()
        assert message.startswith("m.gltf: material 'skin': image ") and words in message, (route, message)
        assert ("bomb.png" if route == "file" else "bomb (") in message, message


def test_an_image_over_the_byte_cap_is_refused_from_files_and_data(tmp_path, monkeypatch):
    monkeypatch.setattr("pipeline.ingest.images.MAX_IMAGE_BYTES", 1000)
    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (32, 32, 3), dtype=np.uint8)).save(buf, "PNG")
    big = buf.getvalue()
    assert len(big) > 1000
    inline = read_mesh(cfg(gltf_with_image(tmp_path / "data", {"uri": data_uri(big)})))
    obj = obj_tree(tmp_path / "obj", "big.png")
    (obj.parent / "big.png").write_bytes(big)
    beside = read_mesh(cfg(obj))
    dae = tmp_path / "dae" / "pole.dae"
    dae.parent.mkdir()
    dae.write_text(textured_collada("big.png"))
    (dae.parent / "big.png").write_bytes(big)
    collada = read_mesh(cfg(dae))
    for asset, who in ((inline, "material 'skin'"), (beside, "material 'grass'"), (collada, "material 'wood'")):
        (message,) = warnings_of(asset).values()
        assert who in message and "over the 1,000 bytes limit for an image" in message, message


# --- a .blend's external images ------------------------------------------------------------

BLEND_WITH_EXTERNAL_IMAGE = """
import sys
from pathlib import Path

import bpy

target = Path(sys.argv[1])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_cube_add(size=1.0)
ob = bpy.context.active_object
image = bpy.data.images.load(str(target.parent / "textures" / "paint.png"))
image.name = "paint"
mat = bpy.data.materials.new("painted")
mat.use_nodes = True
tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
tex.image = image
mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
ob.data.materials.append(mat)
bpy.ops.wm.save_as_mainfile(filepath=str(target), relative_remap=True)
print(image.filepath)
"""


def test_a_blend_records_the_external_image_it_reads_and_refuses_a_bomb(tmp_path):
    pytest.importorskip("bpy")
    from pipeline.ingest.blend import read_blend_path

    (tmp_path / "textures").mkdir()
    split_png(tmp_path / "textures" / "paint.png")
    run = subprocess.run([sys.executable, "-c", BLEND_WITH_EXTERNAL_IMAGE, str(tmp_path / "box.blend")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and "//textures/paint.png" in run.stdout, run.stderr[-2000:]
    asset = read_blend_path(tmp_path / "box.blend", "box", "test")
    assert np.array_equal(pixels(asset.material("painted").base_color_texture),
                          np.asarray(Image.open(tmp_path / "textures" / "paint.png").convert("RGB")))
    assert opened_of(asset) == {"textures/paint.png": sha256((tmp_path / "textures" / "paint.png").read_bytes())}
    (tmp_path / "textures" / "paint.png").write_bytes(png_header_only(30000, 30000))
    with pytest.raises(UserError, match=r"box.blend: image 'paint': a decompression bomb \(900,000,000 pixels\)"):
        read_blend_path(tmp_path / "box.blend", "box", "test")


def test_the_planners_size_refusal_covers_the_readers_that_check_size(tmp_path):
    """ingest.size.CHECKED_SUFFIXES names the suffixes whose readers refuse a file by its
    size (read_mesh, read_cad): the planner refuses those before it hashes them, and
    leaves a .blend, which has no size limit, to its reader."""
    from pipeline.ingest import size
    from pipeline.ingest.cad import read_cad
    from pipeline.ingest.mesh import read_mesh
    from pipeline.ingest.readers import READERS

    checked = {s for s, reader in READERS.items() if reader in (read_mesh, read_cad)}
    assert checked == set(size.CHECKED_SUFFIXES)
    for name in ("big.STL", "big.step", "big.blend"):
        path = tmp_path / name
        with open(path, "wb") as f:
            f.truncate(size.MAX_BYTES + 1)
        refused = size.refusal(path)
        if name.endswith(".blend"):
            assert refused is None
        else:
            assert refused is not None and "over the 512 MB limit" in refused.message and refused.file == str(path)
    (tmp_path / "fine.obj").write_text("v 0 0 0\n")
    assert size.refusal(tmp_path / "fine.obj") is None


def test_twin_info_refuses_an_oversized_source_without_hashing_it(tmp_path, monkeypatch):
    """`twin info` compares a source's hash with its built manifest's; a source over the
    readers' limit is refused by its size first, never read."""
    import mini_sources
    from pipeline import info
    from pipeline.ingest import size

    sources = mini_sources.make(tmp_path / "src")
    stl = sources / "assets" / "kiosk" / "kiosk.stl"
    with open(stl, "r+b") as f:
        f.truncate(size.MAX_BYTES + 1)  # sparse
    manifest = tmp_path / "build" / "models" / "kiosk" / "manifest.json"
    manifest.parent.mkdir(parents=True)
    manifest.write_text(json.dumps({"source": {"sha256": "0" * 64}, "lods": [{"triangles": 12}]}))
    hashed = []
    monkeypatch.setattr(info, "sha256_file", lambda p: hashed.append(p) or "1" * 64)
    report = info.gather(sources, tmp_path / "build")
    assert [p for p in report.problems if "kiosk.stl" in p and "over the 512 MB limit" in p]
    assert str(stl) not in map(str, hashed)
