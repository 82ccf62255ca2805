"""pipeline.glb (the GLB container, buffers, accessors, the axis change) and the one
quaternion convention of geometry.transform, with its glTF and USD boundaries."""

from __future__ import annotations

import ast
import math
import struct

import numpy as np
import pytest

from helpers import ROOT
from pipeline import glb
from pipeline.geometry import transform as T


def _doc() -> dict:
    return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"name": "ä"}]}


# ---------------------------------------------------------------- the container

def test_round_trip_through_a_file(tmp_path):
    doc, binary = _doc(), bytes(range(7))
    path = tmp_path / "a" / "x.glb"
    written = glb.write(path, doc, binary)
    assert written == path.stat().st_size
    back, data = glb.read(path)
    assert back == doc
    assert data == binary + b"\0"  # the chunk is padded to 4 bytes with zeros
    assert glb.pack(back, data) == path.read_bytes()  # the same document, the same bytes


def test_layout_header_chunks_and_padding():
    data = glb.pack(_doc(), b"\1\2\3\4\5")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, json_kind = struct.unpack_from("<II", data, 12)
    assert json_kind == glb.JSON_CHUNK and json_len % 4 == 0
    text = data[20:20 + json_len]
    assert text.rstrip(b" ") == text.strip() and text.decode("utf-8").rstrip(" ").endswith("}")
    assert "ä" in text.decode("utf-8")  # UTF-8 as is, not escaped
    bin_len, bin_kind = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_kind == glb.BIN_CHUNK and bin_len == 8
    assert data[28 + json_len:] == b"\1\2\3\4\5\0\0\0"
    assert len(data) % 4 == 0


def test_no_binary_no_bin_chunk():
    data = glb.pack(_doc())
    json_len = struct.unpack_from("<I", data, 12)[0]
    assert len(data) == 20 + json_len
    assert glb.parse(data) == (_doc(), b"")


def test_unknown_chunks_are_skipped():
    data = bytearray(glb.pack(_doc(), b"abcd"))
    data += struct.pack("<II", 3, 0x12345678) + b"xyz\0"  # 3 bytes and their padding
    struct.pack_into("<I", data, 8, len(data))
    assert glb.parse(bytes(data)) == (_doc(), b"abcd")


def _broken() -> dict[str, bytes]:
    good = glb.pack(_doc(), b"abcdefgh")
    wrong_version = bytearray(good)
    struct.pack_into("<I", wrong_version, 4, 1)
    long_chunk = bytearray(good)
    struct.pack_into("<I", long_chunk, 12, 4096)
    not_json = struct.pack("<4sII", b"glTF", 2, 24) + struct.pack("<II", 4, glb.JSON_CHUNK) + b"{no}"
    only_bin = struct.pack("<4sII", b"glTF", 2, 24) + struct.pack("<II", 4, glb.BIN_CHUNK) + b"abcd"
    return {"empty": b"", "magic only": b"glTF", "wrong magic": b"PK\3\4" + good[4:],
            "version 1": bytes(wrong_version), "cut short": good[:-5], "chunk past the end": bytes(long_chunk),
            "JSON chunk not JSON": not_json, "no JSON chunk": only_bin}


@pytest.mark.parametrize("case", sorted(_broken()))
def test_a_malformed_file_gives_one_error_naming_it(tmp_path, case):
    path = tmp_path / "broken.glb"
    path.write_bytes(_broken()[case])
    with pytest.raises(glb.GlbError) as caught:
        glb.read(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and caught.value.file == path
    assert caught.value.reason and "\n" not in message


def test_the_ingest_reader_says_what_is_wrong(tmp_path):
    from pipeline.ingest.gltf_file import GltfError, read

    path = tmp_path / "cut.glb"
    path.write_bytes(glb.pack(_doc(), b"abcdefgh")[:-3])
    with pytest.raises(GltfError, match="truncated GLB"):
        read(path)


# ---------------------------------------------------------------- buffers and accessors

def test_every_view_starts_on_a_4_byte_boundary():
    buffer = glb.Buffer()
    odd = np.array([1, 2, 3], dtype=np.uint16)  # 6 bytes
    a = buffer.add_accessor(odd, "SCALAR", glb.ELEMENT_ARRAY_BUFFER)
    b = buffer.add_accessor(np.arange(6, dtype=np.float32).reshape(2, 3), "VEC3", glb.ARRAY_BUFFER, bounds=True)
    c = buffer.add_view(b"xyz")
    d = buffer.add_accessor(np.array([7, 8], dtype=np.uint32), "SCALAR")
    assert [v["byteOffset"] for v in buffer.views] == [0, 8, 32, 36]
    assert all(v["byteOffset"] % 4 == 0 for v in buffer.views)
    assert buffer.views[a]["target"] == glb.ELEMENT_ARRAY_BUFFER and "target" not in buffer.views[c]
    assert buffer.accessors[b]["min"] == [0.0, 1.0, 2.0] and buffer.accessors[b]["max"] == [3.0, 4.0, 5.0]
    assert [x["componentType"] for x in buffer.accessors] == [glb.UNSIGNED_SHORT, glb.FLOAT, glb.UNSIGNED_INT]
    doc = {"bufferViews": buffer.views, "accessors": buffer.accessors}
    binary = bytes(buffer.binary)
    assert glb.accessor(doc, binary, a).ravel().tolist() == [1, 2, 3]
    assert glb.accessor(doc, binary, b).tolist() == [[0, 1, 2], [3, 4, 5]]
    assert glb.accessor(doc, binary, d).ravel().tolist() == [7, 8]
    assert glb.padded_length(binary) % 4 == 0


def test_a_buffer_without_an_index_leaves_it_to_the_caller():
    buffer = glb.Buffer(buffer=None)
    buffer.add_view(b"abcd")
    assert buffer.views == [{"byteOffset": 0, "byteLength": 4}]


def test_strided_and_sparse_accessors_read_back():
    rows = np.arange(12, dtype=np.float32).reshape(4, 3)
    interleaved = np.concatenate([rows, -rows], axis=1)  # stride 24, the first 12 bytes ours
    sparse_idx = np.array([1, 3], dtype=np.uint16).tobytes() + b"\0" * 4
    sparse_val = np.array([[9, 9, 9], [8, 8, 8]], dtype=np.float32).tobytes()
    binary = interleaved.tobytes() + sparse_idx + sparse_val
    doc = {"bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 96, "byteStride": 24},
                           {"buffer": 0, "byteOffset": 96, "byteLength": 4},
                           {"buffer": 0, "byteOffset": 104, "byteLength": 24}],
           "accessors": [{"bufferView": 0, "componentType": glb.FLOAT, "count": 4, "type": "VEC3"},
                         {"bufferView": 0, "componentType": glb.FLOAT, "count": 4, "type": "VEC3",
                          "sparse": {"count": 2, "indices": {"bufferView": 1, "componentType": glb.UNSIGNED_SHORT},
                                     "values": {"bufferView": 2}}}]}
    assert np.array_equal(glb.accessor(doc, binary, 0), rows)
    expected = rows.copy()
    expected[[1, 3]] = [[9, 9, 9], [8, 8, 8]]
    assert np.array_equal(glb.accessor(doc, binary, 1), expected)
    doc["bufferViews"][0]["byteLength"] = 50
    with pytest.raises(glb.GlbError, match="reads past its end"):
        glb.accessor(doc, binary, 0)


# ---------------------------------------------------------------- the frame

def test_the_axis_change_takes_z_up_to_y_up():
    assert np.array_equal(glb.points_to_y_up([[0.0, 0.0, 1.0]]), [[0.0, 1.0, 0.0]])
    assert np.array_equal(glb.points_to_y_up([[0.0, 1.0, 0.0]]), [[0.0, 0.0, -1.0]])
    assert np.linalg.det(glb.Z_TO_Y) == pytest.approx(1.0)  # a rotation: winding kept
    m = T.xyz_rpy_to_matrix((1.0, 2.0, 3.0), (0.1, -0.2, 0.3))
    y_up = glb.to_y_up(m)
    assert np.allclose(y_up[:3, 3], glb.points_to_y_up(m[:3, 3]))
    assert np.allclose(glb.to_z_up(y_up), m, atol=1e-15)
    p = np.array([[4.0, -5.0, 6.0]])
    assert np.allclose(glb.points_to_z_up(glb.points_to_y_up(p)), p)


def test_one_definition_of_the_container_and_the_axis_change():
    """Only pipeline/glb.py spells out GLB bytes or the Z-up to Y-up matrix."""
    markers = ("0x46546C67", "0x4E4F534A", "0x004E4942", 'b"glTF"', "[0, 0, 1, 0], [0, -1, 0, 0]",
               "[0.0, 0.0, 1.0], [0.0, -1.0, 0.0]", "[0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]")
    offenders = []
    for path in sorted((ROOT / "pipeline").rglob("*.py")):
        if path == ROOT / "pipeline" / "glb.py":
            continue
        text = path.read_text()
        offenders += [f"{path.relative_to(ROOT)}: {m}" for m in markers if m in text]
    assert offenders == []


def test_geometry_does_not_import_the_glb_module():
    for path in sorted((ROOT / "pipeline" / "geometry").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                named = [node.module or ""] + [f"{node.module or ''}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                named = [a.name for a in node.names]
            else:
                continue
            assert not any(n.endswith("glb") or ".glb." in n for n in named), path


# ---------------------------------------------------------------- quaternions

def _rotations() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3], [-1, -1, -1]], dtype=np.float64)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    near = [math.pi, math.pi - 1e-9, math.pi - 1e-5, -math.pi + 1e-7, 1e-12, 0.0, math.pi / 2]
    special = [Rotation.from_rotvec(a * angle).as_matrix() for a in axes for angle in near]
    return np.concatenate([np.array(special), Rotation.random(500, random_state=3).as_matrix()])


def test_quaternion_round_trips_including_near_180_degrees():
    r = _rotations()
    q = T.quaternions_from_matrices(r)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert np.all(q[:, 0] >= 0.0)
    assert np.abs(T.matrices_from_quaternions(q) - r).max() < 1e-12
    # one at a time gives the same bits as the batch
    assert np.array_equal(np.array([T.quaternion_from_matrix(m) for m in r]), q)


def test_both_signs_are_the_same_rotation():
    q = T.quaternions_from_matrices(_rotations())
    assert np.abs(T.matrices_from_quaternions(-q) - T.matrices_from_quaternions(q)).max() < 1e-15
    # exactly 180 degrees: w = 0, and either sign of the axis names the rotation
    half_turn = T.quaternion_from_matrix(T.rotation_x(math.pi))
    assert half_turn[0] == pytest.approx(0.0, abs=1e-16) and abs(half_turn[1]) == pytest.approx(1.0)
    assert np.allclose(T.matrix_from_quaternion(-half_turn)[:3, :3], T.rotation_x(math.pi), atol=1e-15)


def test_the_scalar_comes_first():
    angle = 0.8
    q = T.quaternion_from_matrix(T.rotation_z(angle))
    assert np.allclose(q, [math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])
    assert np.allclose(T.quaternion_from_axis_angle([0, 0, 2], angle), q)
    assert np.allclose(T.quaternion_from_axis_angle([0, 0, 0], angle), q)  # no axis: Z


def test_continuous_quaternions_stay_on_one_hemisphere():
    angles = np.linspace(0.0, 4 * math.pi, 41)
    q = T.quaternions_from_matrices(np.array([T.rotation_y(a) for a in angles]))
    assert np.any(np.sum(q[1:] * q[:-1], axis=1) < 0)  # w >= 0 jumps hemispheres past 180 degrees
    c = T.continuous_quaternions(q)
    assert np.all(np.sum(c[1:] * c[:-1], axis=1) > 0)
    assert np.allclose(np.abs(c), np.abs(q))


# ---------------------------------------------------------------- the format boundaries

def test_gltf_stores_x_y_z_w():
    q = T.quaternion_from_axis_angle([0.0, 1.0, 0.0], 1.0)  # (w, x, y, z)
    stored = glb.to_gltf_rotation(q)
    assert stored.tolist() == [q[1], q[2], q[3], q[0]]
    assert np.array_equal(glb.from_gltf_rotation(stored), q)
    batch = T.quaternions_from_matrices(_rotations())
    assert np.array_equal(glb.from_gltf_rotation(glb.to_gltf_rotation(batch)), batch)
    node = {"rotation": [float(c) for c in stored], "translation": [1.0, 2.0, 3.0], "scale": [2.0, 2.0, 2.0]}
    expected = T.matrix_from_quaternion(q, (1.0, 2.0, 3.0)) @ np.diag([2.0, 2.0, 2.0, 1.0])
    assert np.allclose(glb.node_matrix(node), expected, atol=1e-15)


def test_instance_transforms_rebuild_the_matrices():
    r = _rotations()[:40]
    scales = np.linspace(0.5, 3.0, 3 * len(r)).reshape(-1, 3)
    m = np.tile(np.eye(4), (len(r), 1, 1))
    m[:, :3, :3] = r * scales[:, None, :]
    m[:, :3, 3] = np.arange(3 * len(r)).reshape(-1, 3)
    t, q, s = glb.instance_transforms(m)
    assert t.dtype == q.dtype == s.dtype == np.float32
    rebuilt = T.matrices_from_quaternions(glb.from_gltf_rotation(q)) * s[:, None, :].astype(np.float64)
    assert np.abs(rebuilt - m[:, :3, :3]).max() < 1e-5 and np.allclose(t, m[:, :3, 3])


def test_the_model_writer_stores_rotations_in_gltf_order(tmp_path):
    from pipeline import ir
    from pipeline.export import gltf, names

    pose = T.xyz_rpy_to_matrix((0.5, 0.0, 0.0), (0.0, 0.0, 2.5))  # a yaw in the Z-up IR
    box = ir.Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64), np.array([[0, 1, 2]]))
    asset = ir.Asset(id="rot", category="test", materials=(ir.Material("m"),),
                     links=(ir.Link("base", visuals=(ir.Visual("v", "m", (box,), pose=pose),)),))
    gltf.write(asset, tmp_path)
    doc, _ = glb.read(tmp_path / names.gltf_file("rot"))
    (node,) = [n for n in doc["nodes"] if n.get("name") == "v"]
    # a yaw about IR Z is a turn about glTF's Y: only y and w are nonzero
    x, y, z, w = node["rotation"]
    assert x == 0.0 and z == 0.0 and w == pytest.approx(math.cos(1.25)) and y == pytest.approx(math.sin(1.25))
    assert np.allclose(glb.to_z_up(glb.node_matrix(node)), pose, atol=1e-12)


def test_usd_takes_the_real_part_first():
    Gf = pytest.importorskip("pxr.Gf")
    from pipeline.runtime.apply_usd import _quat

    axis, angle = np.array([1.0, -2.0, 0.5]), 2.9
    ours = T.quaternion_from_axis_angle(axis, angle)
    usd = _quat(Gf, axis, angle)
    assert usd.GetReal() == ours[0] and list(usd.GetImaginary()) == list(ours[1:])
    reference = Gf.Rotation(Gf.Vec3d(*axis), math.degrees(angle)).GetQuat()
    assert np.allclose([reference.GetReal(), *reference.GetImaginary()], ours, atol=1e-12)
    m = Gf.Matrix4d().SetRotate(usd)  # USD's row-vector matrices: the transpose of ours
    assert np.allclose(np.array(m)[:3, :3].T, T.matrix_from_quaternion(ours)[:3, :3], atol=1e-12)


# ---------------------------------------------------------------- nodes

def test_scene_nodes_only_drops_the_lower_lods_and_keeps_what_the_scene_draws(mini_build, tmp_path):
    """A built package without MSFT_lod's out-of-scene levels (what the renderer
    imports): the same mesh nodes at the same matrices, in the same order, no node
    outside the scene, and a file the Khronos validator accepts."""
    from pipeline.validate.external import gltf_validator

    _, out = mini_build
    packages = sorted(p for p in (out / "models").glob("*/*.glb") if "__lod" not in p.parent.name)
    lodded = 0
    for path in packages:
        doc, binary = glb.read(path)
        kept = glb.scene_nodes_only(doc)
        assert [(kept["nodes"][i]["mesh"], m.tolist()) for i, m in glb.visual_nodes(kept)] == \
            [(doc["nodes"][i]["mesh"], m.tolist()) for i, m in glb.visual_nodes(doc)]
        drawn = {i for i, _ in glb.visual_nodes(kept)}
        assert all("mesh" not in n or i in drawn for i, n in enumerate(kept["nodes"]))
        assert not any("MSFT_lod" in n.get("extensions", {}) for n in kept["nodes"])
        assert "MSFT_lod" not in kept.get("extensionsUsed", [])
        if len(kept["nodes"]) < len(doc["nodes"]):
            lodded += 1
            glb.write(tmp_path / path.name, kept, binary)
    assert lodded, "no package of the mini build has lower LODs"
    results = gltf_validator(sorted(tmp_path.glob("*.glb")))
    assert results and all(r.status == "passed" for r in results), [(r.target, r.messages) for r in results]


def test_scene_nodes_only_keeps_a_document_whose_animations_name_nodes():
    doc = {**_doc(), "nodes": [{"name": "a"}, {"name": "lower"}],
           "animations": [{"channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}], "samplers": []}]}
    assert glb.scene_nodes_only(doc) is doc
    plain = {**_doc(), "nodes": [{"name": "b", "children": [2]}, {"name": "lower"}, {"name": "c"}],
             "scenes": [{"nodes": [0]}]}
    assert glb.scene_nodes_only(plain)["nodes"] == [{"name": "b", "children": [1]}, {"name": "c"}]
