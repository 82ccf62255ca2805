"""The web viewer and the 3D Tiles (pipeline.viewer): the build's viewer tasks on the
mini sources, the tileset's frame, bounds, errors and contents, the site's clock and
sun table, `twin view`, and both pages in Debian's Chromium (headless, WebGL through
SwiftShader, driven by tools/viewer_check.mjs): the scene drawn with every placement,
the sun and the state mapping against the runtime's, the tiles on the globe at the
site. In CI (CI=1) a missing browser or node module fails these tests."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import zoneinfo
from pathlib import Path

import numpy as np
import pytest

import mini_sources
from pipeline import config
from pipeline import glb
from pipeline.geometry.transform import matrix_from_quaternion
from pipeline.viewer import check, libs, sun_table, tiles

from helpers import SOURCES, tree_hashes, twin, unavailable


@pytest.fixture(scope="session")
def mini(mini_build):
    """The mini sources built once per run: (sources, build)."""
    return mini_build


# --- the build's tasks --------------------------------------------------------------


def test_the_build_writes_the_pages_the_libraries_and_the_tiles(mini):
    _, out = mini
    for rel in ("viewer/index.html", "viewer/globe.html", "viewer/app/viewer.js", "viewer/app/globe.js",
                "viewer/data/twin.json", "viewer/data/sun.bin", "tiles/tileset.json", "tiles/terrain.glb"):
        assert (out / rel).is_file(), rel
    for name in libs.FILES:
        if libs.manifests()[name] is not None:
            assert not (out / libs.LIB / name / "MISSING.txt").exists()
    assert (out / libs.LIB / "three" / "build" / "three.module.js").is_file()
    assert (out / libs.LIB / "cesium" / "Cesium.js").is_file()
    # the import map and Cesium's base URL name files the build copied
    page = (out / "viewer" / "index.html").read_text()
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', page, re.S).group(1))["imports"]
    assert (out / "viewer" / imports["three"]).is_file()
    assert (out / "viewer" / imports["three/addons/"] / "loaders" / "GLTFLoader.js").is_file()
    data = json.loads((out / "viewer" / "data" / "twin.json").read_text())
    assert data["scene"] == "../scene/mini.glb" and (out / "viewer" / data["scene"]).is_file()
    assert (out / "viewer" / data["tiles"]).is_file() and (out / "viewer" / data["placements"]).is_file()
    assert data["timezone"] == "America/Bahia" and data["clock"]["zone"] == "America/Bahia"
    assert [p["name"] for p in data["inspection_points"]] == ["eye"]
    assert set(data["assets"]) == {"kiosk", "pole"}
    for a, m in data["assets"].items():
        manifest = json.loads((out / "models" / a / "manifest.json").read_text())
        assert m["errors_m"] == [lod["error_m"] for lod in manifest["lods"]][: len(m["errors_m"])]
        assert m["bounds"] == manifest["bounds"]


def test_noop_rebuild_runs_nothing_and_builds_are_byte_identical(mini, mini_copy, tmp_path):
    _, built = mini
    sources, out = mini_copy  # the shared build copied: other tests read it meanwhile
    again = json.loads(twin("build", "--sources", sources, "--out", out, "--json").stdout)
    assert {t["task"] for t in again["tasks"] if t["ran"]} == set()
    other = tmp_path / "other"
    proc = twin("build", "--sources", sources, "--out", other, "--json", "--jobs", "1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert tree_hashes(out, "viewer", "tiles") == tree_hashes(other, "viewer", "tiles")
    assert tree_hashes(built, "viewer", "tiles") == tree_hashes(other, "viewer", "tiles")


def test_the_libraries_task_runs_only_for_new_libraries(mini_copy):
    src, out = mini_copy  # built once: the shared build copied
    (src / "site.toml").write_text((src / "site.toml").read_text() + "\n# edited\n")
    edit = json.loads(twin("build", "--sources", src, "--out", out, "--json").stdout)
    ran = {t["task"] for t in edit["tasks"] if t["ran"]}
    assert "viewer" in ran and "tiles" in ran and "viewer:libs" not in ran


def test_a_missing_library_is_a_note_on_the_page_not_a_failed_build(tmp_path):
    out = libs.copy(tmp_path, modules=tmp_path / "no_node_modules")
    assert out == {"libraries": {"cesium": None, "three": None}}
    note = (tmp_path / libs.LIB / "three" / "MISSING.txt").read_text()
    assert "install-tools" in note


# --- the tileset ----------------------------------------------------------------


@pytest.fixture(scope="module")
def tileset(mini):
    _, out = mini
    return json.loads((out / "tiles" / "tileset.json").read_text())


def _tiles(node, depth=0):
    yield node, depth
    for c in node.get("children", []):
        yield from _tiles(c, depth + 1)


def _drawn_points(path: Path) -> tuple[np.ndarray, list[str]]:
    """ENU points a tile content draws (every instance of every mesh) and its tags."""
    doc, binary = glb.read(path)
    ext = path.parent

    def buffer(i):
        b = doc["buffers"][i]
        return binary if "uri" not in b else (ext / b["uri"]).read_bytes()

    def acc(index):
        a = doc["accessors"][index]
        view = doc["bufferViews"][a["bufferView"]]
        data = buffer(view["buffer"])
        sub = dict(doc, bufferViews=[{**view, "buffer": 0}], accessors=[{**a, "bufferView": 0}])
        return glb.accessor(sub, data, 0)

    points, tags = [], []
    (root,) = doc["scenes"][0]["nodes"]
    centre = np.array(doc["nodes"][root].get("translation", [0, 0, 0]))
    for ni in doc["nodes"][root].get("children", []):
        node = doc["nodes"][ni]
        inst = node["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]
        t, r, s = (acc(inst[k]).astype(np.float64) for k in ("TRANSLATION", "ROTATION", "SCALE"))
        tags += node["extras"]["tags"]
        for prim in doc["meshes"][node["mesh"]]["primitives"]:
            pos = acc(prim["attributes"]["POSITION"]).astype(np.float64)
            for k in range(len(t)):
                m = matrix_from_quaternion(glb.from_gltf_rotation(r[k]))[:3, :3] * s[k]
                points.append(glb.points_to_z_up(pos @ m.T + t[k] + centre))  # ENU
    return np.concatenate(points), tags


def test_tileset_is_3d_tiles_1_1_at_the_site_in_ecef(mini, tileset):
    sources, out = mini
    from pyproj import Transformer

    record = json.loads((out / "scene" / "placements.json").read_text())
    o = record["origin"]
    assert tileset["asset"]["version"] == "1.1"
    m = np.array(tileset["root"]["transform"]).reshape(4, 4).T
    to_ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    assert np.allclose(m[:3, 3], to_ecef.transform(o["longitude_deg"], o["latitude_deg"], o["height_m"]), atol=1e-6)
    assert np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-12)
    # every placement through the root transform lands where pyproj puts its plan point
    from pipeline.georef import Georeferencer

    site = config.load_site(sources / "site.toml")
    georef = Georeferencer(site, (o["latitude_deg"], o["longitude_deg"], o["height_m"]))
    for p in record["placements"]:
        h = site.level(p["level"]).elevation + p["plan"][2]
        lat, lon, hh = georef.to_llh(np.array([p["plan"][:2]]), np.array([h]))[0]
        truth = np.array(to_ecef.transform(lon, lat, hh))
        assert np.linalg.norm(m @ np.r_[p["enu"], 1.0] - np.r_[truth, 1.0]) < 2e-6, p["tag"]


def test_every_level_shows_every_placement_once_with_its_measured_error(mini, tileset):
    _, out = mini
    record = json.loads((out / "scene" / "placements.json").read_text())
    manifests = {a: json.loads((out / "models" / a / "manifest.json").read_text()) for a in ("kiosk", "pole")}
    asset_of = {p["tag"]: p["asset"] for p in record["placements"]}
    terrain, equipment = tileset["root"]["children"]
    assert terrain["content"]["uri"] == "terrain.glb" and tileset["root"]["refine"] == "ADD"
    levels: dict[int, list[str]] = {}
    for node, depth in _tiles(equipment):
        _, tags = _drawn_points(out / "tiles" / node["content"]["uri"])
        level = int(Path(node["content"]["uri"]).stem.split("_")[0])
        levels.setdefault(level, []).extend(tags)
        errors = [tiles.levels_of(manifests[asset_of[t]]) for t in tags]
        assert node["geometricError"] == pytest.approx(max(e[min(level, len(e) - 1)] for e in errors), abs=0)
        for child in node.get("children", []):
            assert child["geometricError"] <= node["geometricError"]
            assert node["refine"] == "REPLACE"
        if level == 0:
            assert node["geometricError"] == 0.0 and "children" not in node
    assert sorted(levels) == list(range(max(levels) + 1))
    for level, tags in levels.items():
        assert sorted(tags) == sorted(asset_of), level


def test_bounding_volumes_hold_what_is_drawn_and_no_more(mini, tileset):
    _, out = mini

    def box(volume):
        c, h = np.array(volume["box"][:3]), np.array(volume["box"][3:])
        half = np.abs(h.reshape(3, 3)).sum(axis=0)
        return c - half, c + half

    def check(node):
        pts, _ = _drawn_points(out / "tiles" / node["content"]["uri"])
        lo, hi = box(node["content"]["boundingVolume"])
        assert (pts >= lo - 1e-4).all() and (pts <= hi + 1e-4).all()
        assert np.allclose(pts.min(axis=0), lo, atol=2e-3) and np.allclose(pts.max(axis=0), hi, atol=2e-3)
        tlo, thi = box(node["boundingVolume"])
        assert (tlo <= lo + 1e-9).all() and (thi >= hi - 1e-9).all()
        for c in node.get("children", []):
            clo, chi = box(c["boundingVolume"])
            assert (tlo <= clo + 1e-9).all() and (thi >= chi - 1e-9).all()
            check(c)

    check(tileset["root"]["children"][1])


def test_tile_contents_pass_the_gltf_validator_and_share_their_meshes(mini, tileset):
    from pipeline.validate import external

    _, out = mini
    files = sorted((out / "tiles" / "content").glob("*.glb")) + [out / "tiles" / "terrain.glb"]
    results = external.gltf_validator(files)
    if os.environ.get("CI") and any(r.status == "skipped" for r in results):
        pytest.fail("gltf-validator missing in CI")
    assert all(r.status in ("passed", "skipped") for r in results), [r.messages for r in results if r.status == "failed"]
    meshes = sorted(p.name for p in (out / "tiles" / "meshes").iterdir())
    assert meshes == sorted(f"{a}.lod{k}.bin" for a in ("kiosk", "pole") for k in range(len(tiles.levels_of(
        json.loads((out / "models" / a / "manifest.json").read_text())))))
    for f in files[:-1]:
        doc, _ = glb.read(f)
        assert "EXT_mesh_gpu_instancing" in doc["extensionsUsed"]
        assert all(b.get("uri", "").startswith("../meshes/") for b in doc["buffers"][1:])


def test_cells_cut_to_the_target_and_keep_every_member():
    rng = np.random.default_rng(7)
    en = np.r_[rng.uniform(0, 300, size=(200, 2)), np.zeros((30, 2))]  # 30 on one point
    root = tiles.tree(en, 3, {0: 10.0, 1: 40.0, 2: 120.0})
    for node, depth in _tiles_obj(root):
        if node.children:
            assert sorted(np.concatenate([c.members for c in node.children])) == sorted(node.members)
    assert sum(len(n.members) for n, _ in _tiles_obj(root) if n.level == 0) == len(en)


def _tiles_obj(node, depth=0):
    yield node, depth
    for c in node.children:
        yield from _tiles_obj(c, depth + 1)


# --- the clock and the sun table ---------------------------------------------------


def test_clock_offsets_follow_zoneinfo_to_the_second():
    zone = zoneinfo.ZoneInfo("Europe/Berlin")
    start, count = sun_table.span(2025)
    end = start + dt.timedelta(seconds=(count - 1) * sun_table.STEP_S)
    offs = sun_table.offsets(zone, start, end)
    assert [o[0] for o in offs[1:]] == [int(dt.datetime(2025, 3, 30, 1, tzinfo=dt.timezone.utc).timestamp()),
                                        int(dt.datetime(2025, 10, 26, 1, tzinfo=dt.timezone.utc).timestamp())]
    assert [o[1] for o in offs] == [3600, 7200, 3600] and [o[2] for o in offs] == ["CET", "CEST", "CET"]
    assert len(sun_table.offsets(zoneinfo.ZoneInfo("America/Bahia"), start, end)) == 1


def test_sun_table_is_the_runtime_ephemeris_at_its_samples():
    from pipeline import sun

    lat, lon = -12.7, -38.3
    start, count = sun_table.span(2025)
    table = np.frombuffer(sun_table.table_bytes(lat, lon, 2025), "<f4").reshape(-1, 3)
    assert len(table) == count
    for k in (0, 1234, count - 1):
        e, a = sun.ephemeris(lat, lon, start + dt.timedelta(seconds=k * sun_table.STEP_S))
        assert np.allclose(table[k], sun.direction_enu(np.radians(e), np.radians(a)), atol=1e-7)


# --- twin view -------------------------------------------------------------------


def test_twin_view_serves_the_build_on_loopback_and_prints_the_address(mini):
    import urllib.request

    _, out = mini
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "view", "--out", str(out), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        url = re.search(r"(http://127\.0\.0\.1:\d+/)viewer/index\.html", line).group(1)
        with urllib.request.urlopen(url + "viewer/index.html", timeout=30) as r:
            assert b"twinViewerReady" in r.read()
        for rel, kind in (("viewer/app/viewer.js", "text/javascript"), ("scene/mini.glb", "model/gltf-binary"),
                          ("tiles/tileset.json", "application/json")):
            with urllib.request.urlopen(url + rel, timeout=30) as r:
                assert r.headers["Content-Type"].startswith(kind), rel
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_twin_view_without_a_built_viewer_is_one_clear_error(tmp_path):
    proc = twin("view", "--out", tmp_path, "--port", "0", timeout=60)
    assert proc.returncode == 1 and "twin build" in proc.stderr and "Traceback" not in proc.stderr


# --- in the browser ----------------------------------------------------------------


def check_page(build: Path, page: str, shot: Path, script: str | None = None, size=(640, 400)) -> dict:
    """pipeline.viewer.check on build/viewer/<page>; skipped without a browser (failed in CI).
    SwiftShader draws every pixel on the CPU: a small page is as good a check, and quicker."""
    lacking = check.missing()
    if lacking:
        unavailable(f"missing {', '.join(lacking)}: {check.HINT}")
    return check.run(build, page, screenshot=shot, size=size, script=script)


def not_blank(png: Path) -> dict:
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"), dtype=np.float64)
    colours = len(np.unique((img // 16).reshape(-1, 3), axis=0))
    return {"std": float(img.std()), "colours": colours}


# Run in the page once it is ready: the clock, the sun and the state mapping, on
# inputs the test gives (JSON spliced in), returned for comparison with Python.
PAGE_SCRIPT = """(async () => {
  const v = window.twinViewer, app = v.app, input = %s;
  const sun = input.instants.map((u) => v.sunAt(app.twin.sun, app.sunTable, u));
  const walls = input.walls.map((w) => v.wallToUtc(input.clock, w));
  const mapped = input.cases.map(([bindings, fed]) => {
    const m = v.mapVisual(bindings, fed);
    const rest = (bindings[0].rest_pose || [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]);
    return m && {material: m.material, weights: m.weights, delta: m.delta.clone().transpose().toArray(), rest};
  });
  const local = app.setLocalTime(input.local[0], input.local[1]);
  const stats = window.twinViewerStats;
  return {sun, walls, mapped, local, irradiance: v.irradiance(app.twin.sun, 0.5), lod: stats.lod};
})()"""


def _cases() -> list:
    """Binding sets of each effect and values inside, at and beyond their domains."""
    axis = [0.3, -0.2, 0.9]
    rest = [0.0, -1.0, 0.0, 0.5, 1.0, 0.0, 0.0, -1.2, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 1.0]
    rot = {"variable": "level", "effect": "rotate", "target": "needle", "link": "base", "domain": [0.0, 100.0],
           "range": [-2.356, 2.356], "axis": axis, "rest_pose": rest}
    move = {**rot, "effect": "translate", "variable": "stroke", "range": [0.0, 0.4], "axis": [0, 0, 1]}
    grow = {**rot, "effect": "scale", "variable": "fill", "range": [0.2, 1.0], "axis": [0, 1, 1]}
    shape = {**rot, "effect": "shape", "variable": "oil", "range": [0.0, 1.0], "shape_key": "full", "axis": None}
    lamp = {**rot, "effect": "material", "variable": "alarm", "materials": ["lamp_alarm", "lamp_off"],
            "thresholds": [25.0], "axis": None}
    out = []
    for fed in ({"level": 37.5, "stroke": 10.0, "fill": 150.0, "oil": -5.0, "alarm": 25.0},
                {"level": 100.0, "stroke": 0.0, "fill": 50.0, "oil": 64.2, "alarm": 24.9}, {"level": -3.0}):
        out.append([[rot, move, grow], fed])
        out.append([[shape], fed])
        out.append([[lamp], fed])
    return out


@pytest.fixture(scope="module")
def viewer_page(mini, tmp_path_factory):
    _, out = mini
    shot = tmp_path_factory.mktemp("shots") / "viewer.png"
    zone = zoneinfo.ZoneInfo("Europe/Berlin")
    start, count = sun_table.span(2025)
    clock = {"zone": zone.key, "offsets": sun_table.offsets(zone, start, start + dt.timedelta(days=370))}
    data = json.loads((out / "viewer" / "data" / "twin.json").read_text())
    rng = np.random.default_rng(3)
    first, last = data["sun"]["start_utc_s"], data["sun"]["start_utc_s"] + (data["sun"]["count"] - 1) * 1800
    # whole seconds: astral reads an instant's whole seconds (the runtime's steps are)
    instants = [int(u) for u in rng.integers(first + 2 * 86400, last - 2 * 86400, 60)]
    walls = [dt.datetime(2025, 3, 30, 2, 30), dt.datetime(2025, 10, 26, 2, 30), dt.datetime(2025, 7, 1, 12, 0)]
    inputs = {"instants": instants, "clock": clock, "cases": _cases(), "local": ["2025-06-21", "07:15"],
              "walls": [w.replace(tzinfo=dt.timezone.utc).timestamp() for w in walls]}
    result = check_page(out, "index.html", shot, PAGE_SCRIPT % json.dumps(inputs))
    return result, shot, inputs, walls, data


def test_viewer_draws_every_placement_without_errors(viewer_page, mini):
    result, shot, *_ = viewer_page
    assert result["ready"], result
    assert result["page_errors"] == [] and result["stats"]["errors"] == []
    assert result["stats"]["instances"] == result["stats"]["placements"] == len(mini_sources.PLACEMENTS)
    assert result["stats"]["draw_calls"] > 0 and result["stats"]["triangles"] > 0
    assert result["stats"]["first_frame_ms"] > 0 and "SwiftShader" in result["webgl"]
    # a software rasterizer draws the page without multisampling (static/renderer.js)
    assert result["stats"]["renderer"] == result["webgl"] and result["stats"]["antialias"] is False
    look = not_blank(shot)
    assert look["std"] > 20 and look["colours"] > 20, look


def test_viewer_sun_is_the_runtime_ephemeris(viewer_page):
    from pipeline import sun

    result, _, inputs, _, data = viewer_page
    lat, lon = data["sun"]["latitude_deg"], data["sun"]["longitude_deg"]
    worst = 0.0
    for u, got in zip(inputs["instants"], result["eval"]["sun"]):
        e, a = sun.ephemeris(lat, lon, dt.datetime.fromtimestamp(u, dt.timezone.utc))
        d = sun.direction_enu(np.radians(e), np.radians(a))
        worst = max(worst, np.degrees(np.arccos(min(1.0, float(np.dot(d, got["dir"]))))))
        assert got["elevation_deg"] == pytest.approx(e, abs=1e-3)
    assert worst < 1e-3, worst
    assert result["eval"]["irradiance"] == pytest.approx(sun.irradiance(0.5), rel=1e-12)
    # the page's local time: 07:15 on the site's clock, as config.local_time reads it
    when = config.local_time(dt.datetime(2025, 6, 21, 7, 15), zoneinfo.ZoneInfo(data["timezone"]))
    assert result["eval"]["local"]["utc"] == when.timestamp()


def test_viewer_clock_agrees_with_zoneinfo_in_gaps_and_folds(viewer_page):
    result, _, inputs, walls, _ = viewer_page
    zone = zoneinfo.ZoneInfo("Europe/Berlin")
    for wall, got in zip(walls, result["eval"]["walls"]):
        try:
            expected = [config.local_time(wall, zone).timestamp()]
        except ValueError as e:
            if "does not exist" in str(e):
                expected = []
            else:  # shown twice: both instants, the earlier first
                expected = [wall.replace(tzinfo=zone, fold=f).timestamp() for f in (0, 1)]
        assert [g["utc"] for g in got] == expected, wall


def test_viewer_state_mapping_is_the_runtimes(viewer_page):
    from pipeline.runtime import nodes

    result, _, inputs, _, _ = viewer_page
    for (bindings, fed), got in zip(inputs["cases"], result["eval"]["mapped"]):
        fed_here = {k: v for k, v in fed.items() if any(b["variable"] == k for b in bindings)}
        if not fed_here:
            assert got is None
            continue
        ob = nodes.Observed("T", "S", "a", {"bindings": bindings})
        (state,) = nodes.visual_states({"S": fed}, [ob])
        rest = np.array(got["rest"]).reshape(4, 4)
        assert np.allclose(rest @ np.array(got["delta"]).reshape(4, 4), state.transform, atol=1e-12)
        assert got["material"] == state.material
        assert got["weights"] == pytest.approx(state.shape_weights, abs=1e-15)


@pytest.mark.browser
def test_a_page_without_its_scene_fails_and_says_why(mini, tmp_path):
    _, out = mini
    broken = tmp_path / "build"
    shutil.copytree(out / "viewer", broken / "viewer")
    shutil.copytree(out / "scene", broken / "scene")
    (broken / "scene" / "mini.glb").write_bytes(b"glTF")  # truncated
    result = check_page(broken, "index.html", tmp_path / "broken.png")
    assert not result["ready"] and result["stats"]["errors"]
    # and without three.js: the note says how to install it
    shutil.rmtree(broken / "viewer" / "lib" / "three")
    (broken / "viewer" / "lib" / "three").mkdir()
    (broken / "viewer" / "lib" / "three" / "MISSING.txt").write_text("three was not installed: bash .ci/install-tools\n")
    result = check_page(broken, "index.html", tmp_path / "nolib.png")
    assert not result["ready"] and any("install-tools" in e for e in result["stats"]["errors"])


def test_only_a_software_rasterizer_loses_multisampling_and_fog():
    """The pages' probe (static/renderer.js) in node, on renderer names browsers report:
    the browser tests see SwiftShader alone, this is the GPU side of the decision."""
    node = shutil.which("node")
    if node is None:
        unavailable(f"node missing: {check.HINT}")
    names = {
        "ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero) (0x0000C0DE)), SwiftShader driver)": True,
        "llvmpipe (LLVM 15.0.6, 256 bits)": True,
        "Mesa softpipe": True,
        "Google SwiftShader": True,
        "ANGLE (NVIDIA, NVIDIA GeForce RTX 3060 (0x00002504) Direct3D11 vs_5_0 ps_5_0, D3D11)": False,
        "Mesa Intel(R) UHD Graphics 620 (KBL GT2)": False,
        "ANGLE (Apple, ANGLE Metal Renderer: Apple M2, Unspecified Version)": False,
        "AMD Radeon RX 6800 XT (radeonsi, navi21, LLVM 15.0.6, DRM 3.49, 6.1.0)": False,
    }
    module = (Path(check.__file__).parent / "static" / "renderer.js").as_uri()
    script = (f"import {{isSoftwareRenderer}} from {json.dumps(module)};"
              f"console.log(JSON.stringify({json.dumps(list(names))}.map(isSoftwareRenderer)))")
    proc = subprocess.run([node, "--input-type=module", "-e", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert dict(zip(names, json.loads(proc.stdout))) == names


@pytest.mark.browser
def test_tiles_on_the_globe_land_at_the_site(mini, tmp_path_factory):
    sources, out = mini
    shot = tmp_path_factory.mktemp("shots") / "globe.png"
    result = check_page(out, "globe.html", shot, size=(960, 600))
    assert result["ready"], result
    assert result["page_errors"] == [] and result["stats"]["errors"] == []
    stats = result["stats"]
    # a software rasterizer draws the globe without fog (static/renderer.js)
    assert stats["renderer"] == result["webgl"] and "SwiftShader" in stats["renderer"] and stats["fog"] is False
    record = json.loads((out / "scene" / "placements.json").read_text())
    o = record["origin"]
    from pipeline.georef import Georeferencer

    site = config.load_site(sources / "site.toml")
    georef = Georeferencer(site, (o["latitude_deg"], o["longitude_deg"], o["height_m"]))
    by_tag = {p["tag"]: p for p in record["placements"]}
    for tag, lat, lon, h in stats["placements"]:
        p = by_tag[tag]
        truth = georef.to_llh(np.array([p["plan"][:2]]), np.array([site.level(p["level"]).elevation + p["plan"][2]]))[0]
        assert abs(lat - truth[0]) < 1e-8 and abs(lon - truth[1]) < 1e-8 and abs(h - truth[2]) < 1e-3, tag
    # what was drawn: depths picked on the tiles, all on the site
    picked = np.array(stats["picked"])
    assert len(picked) >= 5, stats
    llh = georef.to_llh(np.array([p["plan"][:2] for p in record["placements"]]), np.full(len(record["placements"]), 48.0))
    margin = 60.0 / 111_000  # degrees: the terrain's skirt and slopes reach beyond the placements
    assert (picked[:, 0] > llh[:, 0].min() - margin).all() and (picked[:, 0] < llh[:, 0].max() + margin).all()
    assert (picked[:, 1] > llh[:, 1].min() - margin).all() and (picked[:, 1] < llh[:, 1].max() + margin).all()
    assert (picked[:, 2] > 40.0).all() and (picked[:, 2] < 65.0).all()
    assert abs(stats["centre"][0] - o["latitude_deg"]) < 0.002 and abs(stats["centre"][1] - o["longitude_deg"]) < 0.002
    assert not_blank(shot)["std"] > 10


# --- the sample (slow) ----------------------------------------------------------------


@pytest.fixture(scope="module")
def sample(sample_build, tmp_path_factory):
    """The session's sample build with the oil-leak scenario run beside it: the build's
    outputs hard-linked into a folder of its own (no copy of the bytes; `twin view`
    serves regular files of the build and refuses a symlink out of it), with its own
    runs/ (the shared build stays as built: writes replace files, never edit them)."""
    out = tmp_path_factory.mktemp("sample") / "build"
    out.mkdir()
    for sub in sample_build.iterdir():
        if sub.name != "runs":
            if sub.is_dir():
                shutil.copytree(sub, out / sub.name, copy_function=os.link, symlinks=True)
            else:
                os.link(sub, out / sub.name)
    proc = twin("run", SOURCES / "scenarios" / "oil_leak.toml", "--out", out)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


SAMPLE_SCRIPT = """(async () => {
  const app = window.twinViewer.app;
  const sel = document.getElementById("run");
  sel.value = "oil_leak";
  sel.dispatchEvent(new Event("change"));
  const steps = %s, out = {};
  for (const k of steps) {
    app.showRunStep("oil_leak", k);
    const applied = app.applyState("RE-A1", app.fed.get("reactor_A1"));
    await new Promise((r) => setTimeout(r, 300));  // a variant's material loads asynchronously
    const lamp = app.byTag.get("RE-A1").bound.get("alarm_lamp");
    out[k] = {applied, fed: app.fed.get("reactor_A1"),
              lamp: lamp.members.map((m) => m.meshes.map((x) => x.material.name))};
  }
  app.goToInspection("RE-A1_gauges");
  app.render();
  const c = app.renderer.domElement.getBoundingClientRect();
  const hit = app.pickAt(c.left + c.width / 2, c.top + c.height / 2);
  app.select(hit && hit.tag);
  app.render();
  return {steps: out, hit};
})()"""


@pytest.mark.browser
@pytest.mark.slow
def test_sample_in_the_viewer_plays_the_run_as_the_runtime_maps_it(sample):
    from pipeline.runtime import graph, nodes, run

    steps = [0, 30, 60]
    shot = Path(os.environ.get("TWIN_VIEWER_SHOTS", sample)) / "viewer_sample.png"
    result = check_page(sample, "index.html", shot, SAMPLE_SCRIPT % json.dumps(steps))
    assert result["ready"], result
    assert result["page_errors"] == [] and result["stats"]["errors"] == []
    assert result["stats"]["instances"] == result["stats"]["placements"] == 853
    assert result["stats"]["runs"] == ["oil_leak"]
    scenario = graph.load_scenario(SOURCES / "scenarios" / "oil_leak.toml", run.scene_zone(sample))
    observed = [o for o in run.load_observed(sample) if o.tag == "RE-A1"]
    data, _ = run.simulate(scenario, observed)
    for k in steps:
        got = result["eval"]["steps"][str(k)]
        states = {s.visual: s for s in data.frames[k]}
        assert set(got["applied"]) == set(states)
        for visual, s in states.items():
            assert np.allclose(np.array(got["applied"][visual]["transform"]).reshape(4, 4), s.transform, atol=1e-9)
            assert got["applied"][visual]["material"] == s.material
            assert got["applied"][visual]["weights"] == pytest.approx(s.shape_weights, abs=1e-9)
        lamp = states["alarm_lamp"].material
        assert all(name == lamp for level in got["lamp"] for name in level), (k, got["lamp"])
    assert result["eval"]["hit"] == {"tag": "RE-A1"}
    assert not_blank(shot)["std"] > 20


@pytest.mark.browser
@pytest.mark.slow
def test_sample_tiles_land_at_the_site_on_the_globe(sample):
    shot = Path(os.environ.get("TWIN_VIEWER_SHOTS", sample)) / "globe_sample.png"
    result = check_page(sample, "globe.html", shot, size=(800, 500))  # the site under 20 or more of its 40 px picks
    assert result["ready"], result
    record = json.loads((sample / "scene" / "placements.json").read_text())
    o = record["origin"]
    stats = result["stats"]
    assert len(stats["placements"]) == 853 and len(stats["picked"]) >= 20
    picked = np.array(stats["picked"])
    # the site is about 300 m across: every drawn point within 400 m of the origin
    north = (picked[:, 0] - o["latitude_deg"]) * 110_600
    east = (picked[:, 1] - o["longitude_deg"]) * 111_320 * np.cos(np.radians(o["latitude_deg"]))
    assert (np.hypot(north, east) < 400).all() and (picked[:, 2] > 40).all() and (picked[:, 2] < 90).all()
    assert not_blank(shot)["std"] > 10


def test_tiles_store_each_image_once_for_every_level(tmp_path):
    """A textured model at two levels: one image file that both levels' tiles name
    (not a copy in each level's mesh binary), its bytes the package's, and the tile
    that draws it passes the glTF validator with the image beside it."""
    import io

    from PIL import Image

    from fixtures_assets import box_mesh
    from pipeline import ir
    from pipeline.export import names
    from pipeline.export.package import write_package
    from pipeline.validate import external

    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(buf, "PNG")
    albedo = ir.Texture("albedo", buf.getvalue())
    painted = ir.Material("painted", base_color_texture=albedo)
    coarse = box_mesh((1, 0.2, 2), (0, 0, 1), attributes=True)
    link = ir.Link("base", visuals=(ir.Visual("panel", "painted", (box_mesh((1, 0.2, 2), (0, 0, 1), attributes=True),
                                                                   coarse)),))
    asset = ir.Asset("cabinet", "control", (link,), materials=(painted,))
    write_package(asset, tmp_path / "models")
    glb_path = tmp_path / "models" / "cabinet" / names.gltf_file("cabinet")
    manifest = {"lods": [{"level": 0, "error_m": 0.0}, {"level": 1, "error_m": 0.01}], "lod_models": ["c1"],
                "outputs": {names.gltf_file("cabinet"): hashlib.sha256(glb_path.read_bytes()).hexdigest()}}
    out = tmp_path / "tiles"
    (out / "meshes").mkdir(parents=True)
    (out / "images").mkdir()
    packs = tiles.packs_of(out, tmp_path / "models", {"cabinet": manifest})
    assert sorted(packs) == [("cabinet", 0), ("cabinet", 1)]
    (image,) = sorted((out / "images").iterdir())
    assert image.read_bytes() == albedo.data
    for pack in packs.values():
        assert pack.image_files == [f"images/{image.name}"]
        assert albedo.data not in (out / tiles.pack_file(pack)).read_bytes()
    (out / "content").mkdir()
    poses = np.eye(4)[None]
    for level in (0, 1):
        tiles.content_glb(out / "content" / f"{level}.glb", [(packs[("cabinet", level)], poses, ["C-1"])],
                          np.zeros(3))
    results = external.gltf_validator(sorted((out / "content").glob("*.glb")))
    if os.environ.get("CI") and any(r.status == "skipped" for r in results):
        pytest.fail("gltf-validator missing in CI")
    assert all(r.status in ("passed", "skipped") for r in results), [r.messages for r in results]
