"""Image textures through every writer, read back by the formats' own consumers: the
Khronos glTF validator, OpenUSD (UsdValidation and the shader network's file paths),
pycollada's schema, Gazebo's mesh loader (tools/gzprobe) and libsdformat."""

from __future__ import annotations

import io
import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from lxml import etree
from PIL import Image

from fixtures_assets import box_mesh
from helpers import CORPUS
from pipeline import ir
from pipeline.export import names
from pipeline.export.package import write_package
from pipeline.export.textures import texture_file
from pipeline.validate import external, gazebo

SAFE = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)


def _image(fmt: str, size=(8, 4), seed=0) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)).save(buf, fmt)
    return buf.getvalue()


def _textured_asset() -> ir.Asset:
    albedo = ir.Texture("panel_albedo", _image("PNG"))
    normal = ir.Texture("panel_normal", _image("PNG", seed=1))
    orm = ir.Texture("panel_orm", _image("JPEG", seed=2))
    painted = ir.Material("painted", base_color=(0.9, 0.8, 0.7, 1.0), metallic=0.2, roughness=0.6,
                          base_color_texture=albedo, normal_texture=normal, metallic_roughness_texture=orm,
                          occlusion_texture=orm)
    plain = ir.Material("plain", base_color=(0.3, 0.3, 0.3, 1.0))
    link = ir.Link("base", visuals=(ir.Visual("panel", "painted", (box_mesh((1, 0.2, 2), (0, 0, 1), attributes=True),)),
                                    ir.Visual("frame", "plain", (box_mesh((1.2, 0.3, 0.1)),))))
    return ir.Asset("cabinet", "control", (link,), materials=(painted, plain))


@pytest.fixture(scope="module")
def package(tmp_path_factory):
    models = tmp_path_factory.mktemp("models")
    asset = _textured_asset()
    write_package(asset, models)
    return asset, models / asset.id


def test_images_are_written_once_as_found(package):
    asset, folder = package
    for texture in asset.textures().values():
        assert (folder / texture_file(texture)).read_bytes() == texture.data
    assert sorted(p.name for p in (folder / "textures").iterdir()) == ["panel_albedo.png", "panel_normal.png",
                                                                        "panel_orm.jpg"]


def test_gltf_embeds_the_images_and_the_validator_accepts_them(package):
    asset, folder = package
    path = folder / names.gltf_file(asset.id)
    (result,) = external.gltf_validator([path])
    assert result.status == "passed", result.messages
    data = path.read_bytes()
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + json_len])
    blob = data[20 + json_len + 8:]
    images = {img["name"]: img for img in doc["images"]}
    assert len(images) == 3 and images["panel_orm"]["mimeType"] == "image/jpeg"
    for texture in asset.textures().values():
        view = doc["bufferViews"][images[texture.name]["bufferView"]]
        assert blob[view["byteOffset"]:view["byteOffset"] + view["byteLength"]] == texture.data
    painted = next(m for m in doc["materials"] if m["name"] == "painted")
    pbr = painted["pbrMetallicRoughness"]
    source = lambda ref: doc["images"][doc["textures"][ref["index"]]["source"]]["name"]  # noqa: E731
    assert source(pbr["baseColorTexture"]) == "panel_albedo"
    assert source(pbr["metallicRoughnessTexture"]) == source(painted["occlusionTexture"]) == "panel_orm"
    assert source(painted["normalTexture"]) == "panel_normal"
    assert "baseColorTexture" not in next(m for m in doc["materials"] if m["name"] == "plain")["pbrMetallicRoughness"]


def test_usd_shaders_read_the_package_images(package):
    from pxr import Sdf, Usd, UsdShade

    asset, folder = package
    path = folder / names.usd_file(asset.id)
    assert external.usd_validation(path).status == "passed"
    stage = Usd.Stage.Open(str(path))
    files = {}
    for prim in stage.Traverse():
        shader = UsdShade.Shader(prim)
        if shader and shader.GetIdAttr().Get() == "UsdUVTexture":
            asset_path = shader.GetInput("file").Get()
            files[prim.GetName()] = Path(Sdf.ComputeAssetPathRelativeToLayer(stage.GetRootLayer(), asset_path.path))
    assert set(files) == {"base_color_texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture"}
    assert all(f.is_file() for f in files.values())
    surface = UsdShade.Shader(stage.GetPrimAtPath(f"/{asset.id}/Looks/painted/PreviewSurface"))
    (source,) = surface.GetInput("diffuseColor").GetConnectedSources()[0]
    assert source.source.GetPath().name == "base_color_texture"


def test_collada_and_sdf_point_gazebo_at_the_image(package):
    asset, folder = package
    dae = folder / names.mesh_file("base", "panel", 0)
    assert external.collada_schema(dae).status == "passed"
    if not gazebo.available() and not os.environ.get("CI"):
        pytest.skip(gazebo.PROBE_HINT)
    report = gazebo.probe_meshes([dae])[str(dae)]
    (material,) = report["materials"]
    assert Path(material["texture"]).resolve() == (folder / "textures" / "panel_albedo.png").resolve()
    assert report["uvs"] == 36 and gazebo.compare_mesh("panel", gazebo.written_summary(dae), report) == []
    model = etree.parse(str(folder / "model.sdf"), SAFE).getroot()
    metal = model.find(".//visual[@name='panel']/material/pbr/metal")
    assert metal.findtext("albedo_map") == f"model://{asset.id}/textures/panel_albedo.png"
    assert metal.findtext("normal_map") == f"model://{asset.id}/textures/panel_normal.png"
    result = external.ign_sdf(folder / "model.sdf", [folder.parent])
    assert result.status == "passed", result.messages


def test_the_thumbnail_shows_the_texture():
    """A plain white material with a half red, half blue image: the thumbnail has both
    colours where the untextured twin is one grey."""
    from pipeline.export import thumbnail

    pixels = np.zeros((8, 8, 3), dtype=np.uint8)
    pixels[:, :4] = (230, 20, 20)
    pixels[:, 4:] = (20, 20, 230)
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, "PNG")
    split = ir.Texture("split", buf.getvalue())
    mesh = box_mesh((1, 1, 1), attributes=True)

    def image(texture):
        material = ir.Material("m", base_color=(1.0, 1.0, 1.0, 1.0), base_color_texture=texture)
        asset = ir.Asset("t", "x", (ir.Link("l", visuals=(ir.Visual("v", "m", (mesh,)),)),), materials=(material,))
        drawn = thumbnail.render(asset, 64).reshape(-1, 3).astype(int)
        return drawn[(drawn != 255).any(axis=1)]

    textured, plain = image(split), image(None)
    reddish = (textured[:, 0] > textured[:, 2] + 60).mean()
    bluish = (textured[:, 2] > textured[:, 0] + 60).mean()
    assert reddish > 0.2 and bluish > 0.2, (reddish, bluish)
    assert np.abs(plain[:, 0] - plain[:, 2]).max() < 5


# --- real inputs: textures read from the corpus reach the outputs ---------------------

corpus = pytest.mark.skipif(not CORPUS.is_dir(), reason="needs ../shared/corpus")


def _read_tree(tmp_path, asset_id: str, copy, toml: str):
    import shutil

    from pipeline.ingest.readers import read_source
    from pipeline.config import load_asset_config

    folder = tmp_path / "sources" / "assets" / asset_id
    folder.mkdir(parents=True)
    copy(shutil, folder)
    (folder / "asset.toml").write_text(toml)
    return read_source(load_asset_config(folder / "asset.toml"))


@corpus
def test_a_gazebo_model_folder_keeps_its_textures(tmp_path):
    """telephone_pole: COLLADA naming its images by bare name, kept in the model
    folder's materials/textures/ as Gazebo lays them out."""
    pole = CORPUS / "mesh" / "telephone_pole"

    def copy(sh, folder):  # the mesh beside asset.toml, the model's materials/ as they were
        sh.copy(pole / "meshes" / "telephone_pole.dae", folder)
        sh.copytree(pole / "materials", folder / "materials")

    asset = _read_tree(tmp_path, "pole", copy, 'category = "pole"\nsource = "telephone_pole.dae"\n')
    # the file's 100 wood triangles take the 512 px wood image, its 126 metal ones the 64 px metal one
    size_of = {v.mesh.triangle_count: Image.open(io.BytesIO(asset.material(v.material).base_color_texture.data)).size
               for _, v in asset.visuals()}
    assert size_of == {100: (512, 512), 126: (64, 64)}
    wood = Image.open(pole / "materials" / "textures" / "telephone_pole_wood_diffuse.jpg").convert("RGB")
    carried = next(m for m in asset.materials if Image.open(io.BytesIO(m.base_color_texture.data)).size == (512, 512))
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(carried.base_color_texture.data)).convert("RGB")),
                          np.asarray(wood))  # the decoded pixels, losslessly kept as PNG
    assert all(v.mesh.uvs is not None for _, v in asset.visuals())
    models = tmp_path / "models"
    write_package(asset, models)
    (result,) = external.gltf_validator([models / "pole" / names.gltf_file("pole")])
    assert result.status == "passed", result.messages
    assert len(list((models / "pole" / "textures").iterdir())) == 2


@corpus
def test_a_textured_glb_keeps_its_texture(tmp_path):
    truck = CORPUS / "mesh" / "CesiumMilkTruck.glb"
    asset = _read_tree(tmp_path, "truck", lambda sh, f: sh.copy(truck, f / truck.name),
                       'category = "truck"\nsource = "CesiumMilkTruck.glb"\n')
    (texture,) = {m.base_color_texture.name: m.base_color_texture for m in asset.materials if m.base_color_texture}.values()
    assert Image.open(io.BytesIO(texture.data)).size == (2048, 2048)
    painted = [v for _, v in asset.visuals() if asset.material(v.material).base_color_texture is not None]
    assert painted and all(v.mesh.uvs is not None for v in painted)


# --- the scene glTF carries its instances' textures -----------------------------------


def _scene_images(path: Path) -> tuple[dict, list[bytes]]:
    from pipeline import glb

    doc, binary = glb.read(path)
    data = []
    for image in doc.get("images", []):
        view = doc["bufferViews"][image["bufferView"]]
        data.append(binary[view.get("byteOffset", 0): view.get("byteOffset", 0) + view["byteLength"]])
    return doc, data


def _place_in_scene(models: Path, tags_assets: list[tuple[str, str]], out: Path) -> Path:
    from pipeline.scene import scene_gltf
    from pipeline.scene.placements import Placed, yaw_matrix

    placed = [Placed(ir.Placement(tag, asset, "L1", 3.0 * i, 0.0), yaw_matrix(0.3 * i, (3.0 * i, 0.0, 0.0)), 0.3 * i)
              for i, (tag, asset) in enumerate(tags_assets)]
    path = out / "scene.glb"
    scene_gltf.write(path, models=models, placed=placed, terrain_model="ground", origin_llh=(-12.0, -38.0, 40.0),
                     crs="EPSG:31984", site_name="t", sun={"elevation_deg": 40.0, "azimuth_deg": 30.0,
                                                          "illuminance_lux": 90000.0})
    return path


def test_the_scene_glb_carries_each_image_once(tmp_path):
    """Two textured models sharing an albedo image, placed three times: the scene has
    each distinct image once, every material's texture resolves to its model's image,
    and the Khronos validator accepts it (it found UNRESOLVED_REFERENCE before)."""
    cabinet = _textured_asset()
    albedo = cabinet.material("painted").base_color_texture
    other = ir.Material("other", base_color=(1, 1, 1, 1), base_color_texture=albedo,
                        normal_texture=ir.Texture("door_normal", _image("PNG", seed=5)))
    door = ir.Asset("door", "control", (ir.Link("base", visuals=(ir.Visual(
        "leaf", "other", (box_mesh((0.8, 0.05, 2), (0, 0, 1), attributes=True),)),)),), materials=(other,))
    ground = ir.Asset("ground", "terrain", (ir.Link("g", visuals=(ir.Visual(
        "g", "plain", (box_mesh((50, 50, 0.1)),)),)),), materials=(ir.Material("plain"),))
    models = tmp_path / "models"
    for asset in (cabinet, door, ground):
        write_package(asset, models)
    path = _place_in_scene(models, [("C-1", "cabinet"), ("C-2", "cabinet"), ("D-1", "door")], tmp_path)
    (result,) = external.gltf_validator([path])
    assert result.status == "passed", result.messages
    doc, images = _scene_images(path)
    want = {t.data for a in (cabinet, door) for t in a.textures().values()}
    assert len(images) == len(set(images)) == len(want) == 4 and set(images) == want
    for material in doc["materials"]:
        refs: list[dict] = []
        from pipeline import glb

        glb.texture_refs(material, refs)
        for ref in refs:
            assert images[doc["textures"][ref["index"]]["source"]] in want
    painted = next(m for m in doc["materials"] if m["name"] == "painted")
    leaf = next(m for m in doc["materials"] if m["name"] == "other")
    source = lambda m: doc["textures"][m["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]  # noqa: E731
    assert source(painted) == source(leaf) and images[source(painted)] == albedo.data


@corpus
def test_the_corpus_textured_assets_placed_in_a_scene(tmp_path):
    """The corpus's milk truck (.glb) and telephone pole (COLLADA, Gazebo layout) read,
    packaged and placed: the scene glb holds each of their images once and validates."""
    import shutil

    truck = _read_tree(tmp_path / "t", "truck", lambda sh, f: sh.copy(CORPUS / "mesh" / "CesiumMilkTruck.glb", f),
                       'category = "truck"\nsource = "CesiumMilkTruck.glb"\n')
    pole_src = CORPUS / "mesh" / "telephone_pole"
    pole = _read_tree(tmp_path / "p", "pole", lambda sh, f: (sh.copy(pole_src / "meshes" / "telephone_pole.dae", f),
                                                             sh.copytree(pole_src / "materials", f / "materials")),
                      'category = "pole"\nsource = "telephone_pole.dae"\n')
    ground = ir.Asset("ground", "terrain", (ir.Link("g", visuals=(ir.Visual(
        "g", "plain", (box_mesh((50, 50, 0.1)),)),)),), materials=(ir.Material("plain"),))
    models = tmp_path / "models"
    for asset in (truck, pole, ground):
        write_package(asset, models)
    path = _place_in_scene(models, [("T-1", "truck"), ("T-2", "truck"), ("P-1", "pole"), ("P-2", "pole")], tmp_path)
    (result,) = external.gltf_validator([path])
    assert result.status == "passed", result.messages
    _, images = _scene_images(path)
    want = {t.data for a in (truck, pole) for t in a.textures().values()}
    assert len(want) >= 3 and len(images) == len(set(images)) and set(images) == want
    shutil.rmtree(models)
