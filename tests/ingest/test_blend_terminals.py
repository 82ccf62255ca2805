"""Conductor terminals authored in a .blend: Empties named `terminal.<name>`, read at
their world location in the model frame (through a parent's transform, and through
the scene's unit scale and asset.toml's up axis), merged with asset.toml's
[[terminals]] into the manifest, a name in both an error naming both places, and a
bad name or a terminal that is not an Empty an error naming the object."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from pipeline import ir
from pipeline.builder.package_task import terminals as manifest_terminals
from pipeline.config import load_asset_config
from pipeline.errors import UserError
from pipeline.ingest.blend import read_blend_path

pytestmark = [pytest.mark.blender, pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy")]

AUTHOR = textwrap.dedent('''
    import sys
    import bpy

    def cube(name, location=(0, 0, 0)):
        me = bpy.data.meshes.new(name)
        v = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
        me.from_pydata(v, [], [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)])
        ob = bpy.data.objects.new(name, me)
        ob.location = location
        bpy.context.scene.collection.objects.link(ob)
        return ob

    def empty(name, location, parent=None):
        ob = bpy.data.objects.new(name, None)
        ob.location = location
        bpy.context.scene.collection.objects.link(ob)
        if parent is not None:
            ob.parent = parent
        return ob

    out, kind = sys.argv[-2], sys.argv[-1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    body = cube("body")
    if kind == "good":
        empty("terminal.pad_a", (-1.25, 0.0, 3.5))
        arm = empty("arm", (2.0, 0.0, 1.0))
        arm.rotation_euler = (0.0, 0.0, 1.5707963267948966)
        empty("terminal.pad_b", (0.5, 0.0, 2.0), parent=arm)  # world: (2, 0.5, 3)
    elif kind == "mm":
        bpy.context.scene.unit_settings.system = "METRIC"
        bpy.context.scene.unit_settings.scale_length = 0.001
        empty("terminal.top", (0.0, 8000.0, 250.0))  # Y up in asset.toml: 8 m up, 0.25 m towards -Y
    elif kind == "copy":
        empty("terminal.top.001", (0.0, 0.0, 1.0))
    elif kind == "mesh":
        cube("terminal.top", (0.0, 0.0, 3.0))
    bpy.ops.wm.save_as_mainfile(filepath=out)
''')


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    folder = tmp_path_factory.mktemp("terminals")
    script = folder / "author.py"
    script.write_text(AUTHOR)
    out = {}
    for kind in ("good", "mm", "copy", "mesh"):
        path = folder / kind / f"{kind}.blend"
        path.parent.mkdir()
        run = subprocess.run([sys.executable, str(script), str(path), kind], capture_output=True, text=True,
                             timeout=120)
        assert run.returncode == 0, run.stderr[-2000:]
        out[kind] = path
    return out


def test_terminal_empties_are_read_in_the_model_frame(blends):
    asset = read_blend_path(blends["good"], "good", "test")
    got = dict(asset.terminals)
    assert list(got) == ["pad_a", "pad_b"]
    assert np.allclose(got["pad_a"], (-1.25, 0.0, 3.5), atol=1e-6)
    assert np.allclose(got["pad_b"], (2.0, 0.5, 3.0), atol=1e-6)  # through the parent's turn
    assert [v.name for link in asset.links for v in link.visuals] == ["body"]  # an empty is no visual


def test_terminals_follow_the_units_and_up_axis(blends):
    asset = read_blend_path(blends["mm"], "mm", "test", up_axis="Y")
    [(name, xyz)] = asset.terminals
    assert name == "top" and np.allclose(xyz, (0.0, -0.25, 8.0), atol=1e-6)


@pytest.mark.parametrize("kind, words", [("copy", ["terminal.top.001", "'top.001'", ".001"]),
                                         ("mesh", ["terminal.top", "is an Empty", "mesh"])])
def test_a_bad_terminal_names_the_object(blends, kind, words):
    with pytest.raises(UserError) as e:
        read_blend_path(blends[kind], kind, "test")
    text = str(e.value)
    assert str(blends[kind]) in text and all(w in text for w in words), text


def _config(tmp_path, terminals: str):
    folder = tmp_path / "kiosk"
    folder.mkdir(parents=True)
    (folder / "kiosk.blend").write_bytes(b"")
    (folder / "asset.toml").write_text('category = "kiosk"\nsource = "kiosk.blend"\n' + terminals)
    return load_asset_config(folder / "asset.toml")


def _asset(*terminals) -> ir.Asset:
    return ir.Asset("kiosk", "kiosk", (ir.Link("base"),), terminals=terminals)


def test_the_manifest_has_both_sources_terminals(tmp_path):
    cfg = _config(tmp_path, '[[terminals]]\nname = "earth"\nposition = [0.0, 0.4, 0.2]\n')
    got = manifest_terminals(cfg, _asset(("pad_a", (-0.3, 0.0, 1.5000000476837158))))
    assert got == [{"name": "earth", "position": [0.0, 0.4, 0.2]}, {"name": "pad_a", "position": [-0.3, 0.0, 1.5]}]
    assert manifest_terminals(_config(tmp_path / "2", ""), _asset()) == []


def test_a_name_in_both_sources_is_one_error_naming_both(tmp_path):
    cfg = _config(tmp_path, '[[terminals]]\nname = "pad_a"\nposition = [-0.3, 0.0, 1.5]\n'
                            '[[terminals]]\nname = "pad_b"\nposition = [0.3, 0.0, 1.5]\n')
    with pytest.raises(UserError) as e:
        manifest_terminals(cfg, _asset(("pad_a", (-0.3, 0.0, 1.5)), ("pad_b", (0.3, 0.0, 1.6))))
    text = str(e.value)
    assert str(cfg.path) in text and "kiosk.blend" in text
    assert "'pad_a'" in text and "'pad_b'" in text and "terminal.pad_b at [0.3, 0.0, 1.6]" in text
