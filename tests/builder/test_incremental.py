"""Incremental, cached and reproducible builds on real sources (DESIGN.md s.5)."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mini_sources
from helpers import ROOT, SOURCES, tree_hashes, twin
from pipeline.bench.builds import nudge_source

# what reads the scene: an edit that changes it reruns these too (not viewer:libs)
AFTER_SCENE = {"viewer", "tiles"}


def explain(sources: Path, out: Path, *extra) -> dict[str, dict]:
    proc = twin("build", "--sources", sources, "--out", out, "--json", *extra, timeout=3000)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {e["task"]: e for e in json.loads(proc.stdout)["tasks"]}


def ran(tasks: dict[str, dict]) -> set[str]:
    return {name for name, e in tasks.items() if e["ran"]}


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    root = tmp_path_factory.mktemp("incr")
    sources = mini_sources.make(root / "sources")
    return sources, root


def test_noop_edit_and_parameter_change(mini):
    sources, root = mini
    out = root / "build"
    first = explain(sources, out)
    assert ran(first) == set(first)
    assert {e["reason"] for e in first.values()} == {"new"}

    assert ran(explain(sources, out)) == set()  # no-op

    nudge_source(sources / "assets" / "kiosk" / "kiosk.stl", 0.005)  # a real edit of one asset
    edit = explain(sources, out)
    assert ran(edit) == {"source:kiosk", "geometry:kiosk", "asset:kiosk", "placed:kiosk", "scene"} | AFTER_SCENE
    stl = "input <sources>/assets/kiosk/kiosk.stl"  # named inside the sources (they may move)
    assert edit["source:kiosk"]["changed"] == [stl]
    assert edit["geometry:kiosk"]["changed"] == ["dependency source:kiosk"]
    assert edit["asset:kiosk"]["changed"] == [stl, "dependency geometry:kiosk"]
    assert edit["placed:kiosk"]["changed"] == ["dependency asset:kiosk"]
    assert edit["scene"]["changed"] == ["dependency placed:kiosk"]

    # a parameter edit in asset.toml reruns exactly what uses it: an LOD budget, the
    # geometry and what follows, not the source read
    toml = sources / "assets" / "pole" / "asset.toml"
    toml.write_text(toml.read_text().replace("[0.004, 0.02]", "[0.004, 0.03]"))
    param = explain(sources, out)
    assert ran(param) == {"geometry:pole", "asset:pole", "placed:pole", "scene"} | AFTER_SCENE
    assert param["geometry:pole"]["changed"] == ["parameters"]
    assert param["source:pole"]["reason"] == "up to date"
    # ... and of the LOD search, the edited level alone (the finer one is in the memo)
    state = json.loads((out / ".state.json").read_text())
    assert state["tasks"]["geometry:pole"]["result"]["lod_levels"] == {"recalled": 1, "searched": 1}

    # a reader's key (the source's up axis) reruns the read too; undone, the cache
    # has every task of the chain as it was
    before = toml.read_text()
    toml.write_text('up_axis = "Y"\n' + before)
    axis = explain(sources, out)
    assert ran(axis) == {"source:pole", "geometry:pole", "asset:pole", "placed:pole", "scene"} | AFTER_SCENE
    assert axis["source:pole"]["changed"] == ["parameters"]
    toml.write_text(before)
    undone = explain(sources, out)
    assert ran(undone) == set()
    assert {undone[t]["reason"] for t in ("source:pole", "geometry:pole", "asset:pole", "placed:pole", "scene")} == {
        "restored from cache"}

    toml.write_text("mass_kg = 175.0\n" + toml.read_text())
    metadata = explain(sources, out)
    assert ran(metadata) == {"asset:pole", "placed:pole", "scene"} | AFTER_SCENE  # the mass is in model.sdf
    assert metadata["geometry:pole"]["reason"] == "up to date"
    sdf = (out / "models" / "pole" / "model.sdf").read_text()
    masses = [float(m) for m in re.findall(r"<mass>([^<]+)</mass>", sdf)]
    assert masses and sum(masses) == pytest.approx(175.0)
    # the package rerun links every COLLADA document its last run made (none changed)
    state = json.loads((out / ".state.json").read_text())
    documents = state["tasks"]["asset:pole"]["result"]["collada_documents"]
    assert documents["made"] == 0 and documents["linked"] > 0

    # a description: the package again, and its view, the same, stops there (what the
    # scene and the tiles read of a package is unchanged); the page shows the text
    toml.write_text('description = "a pole, described again"\n' + toml.read_text())
    described = explain(sources, out)
    assert ran(described) == {"asset:pole", "placed:pole", "viewer"}
    assert described["scene"]["reason"] == "up to date" and described["scene"]["cut_off_after"] == ["placed:pole"]

    # the source saved again with the same geometry (a comment added): read again, and
    # the LOD search, keyed on what the read made, does not run (the package does: its
    # manifest records the file's hash)
    obj = sources / "assets" / "pole" / "pole.obj"
    obj.write_text(obj.read_text() + "# saved again\n")
    resaved = explain(sources, out)
    # ... and the view of it, which is the same: neither the scene nor the tiles run
    assert ran(resaved) == {"source:pole", "asset:pole", "placed:pole", "viewer"}
    assert resaved["geometry:pole"]["reason"] == "up to date"
    assert resaved["geometry:pole"]["cut_off_after"] == ["source:pole"]
    assert "cut_off_after" not in resaved["geometry:kiosk"]  # its source did not run
    manifest = json.loads((out / "models" / "pole" / "manifest.json").read_text())
    assert manifest["source"]["sha256"] == hashlib.sha256(obj.read_bytes()).hexdigest()

    # after all these edits, what the memos gave (LOD levels, findings, COLLADA
    # documents) is what a clean build of the same sources makes
    explain(sources, root / "clean")
    assert tree_hashes(out) == tree_hashes(root / "clean")


def test_two_clean_builds_are_byte_identical(mini_build, tmp_path):
    sources, b = mini_build  # a clean build of them with --jobs 2, made once per run
    a, c = tmp_path / "a", tmp_path / "c"
    explain(sources, a, "--jobs", "1")
    explain(sources, c, "--executor", "in-process")  # tasks in the twin process itself
    ha, hb, hc = tree_hashes(a), tree_hashes(b), tree_hashes(c)
    assert ha and ha == hb == hc


def test_shared_cache_rebuilds_nothing_into_an_empty_folder(mini, tmp_path):
    sources, _ = mini
    cache = tmp_path / "cache"
    explain(sources, tmp_path / "one", "--cache", cache)
    again = explain(sources, tmp_path / "two", "--cache", cache)
    assert ran(again) == set()
    assert tree_hashes(tmp_path / "one") == tree_hashes(tmp_path / "two")


def test_failed_asset_leaves_the_previous_build(mini_copy):
    src, out = mini_copy  # the run's mini build, copied
    explain(src, out)
    before = tree_hashes(out)
    (src / "assets" / "pole" / "pole.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    proc = twin("build", "--sources", src, "--out", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "pole" in proc.stderr
    assert tree_hashes(out) == before


@pytest.mark.slow
def test_sample_one_asset_edit_reexports_only_its_chain(sample_build, tmp_path):
    """What .ci/run shows: the sample built, one asset's source edited, rebuilt. The
    first build restores every task from the session's sample build's cache (built
    from a copy of sources/ beside it, so the keys match), as a checkout's does."""
    sources = tmp_path / "sources"
    shutil.copytree(SOURCES, sources, ignore=shutil.ignore_patterns("authoring"))
    out = tmp_path / "build"
    first = explain(sources, out, "--cache", sample_build / ".cache")
    assert ran(first) == set() and tree_hashes(out) == tree_hashes(sample_build, *_OUTPUTS)
    nudge_source(sources / "assets" / "junction_box" / "junction_box.stl", 0.005)
    # A cache of its own: the shared one would then hold the edited asset, and a
    # restored task is not a run one.
    edit = explain(sources, out, "--cache", tmp_path / "edit-cache")
    assert ran(edit) == {"source:junction_box", "geometry:junction_box", "asset:junction_box", "placed:junction_box",
                         "scene"} | AFTER_SCENE


# what a build makes (the shared sample build also holds what tests wrote beside it)
_OUTPUTS = ("models", "scene", "tiles", "viewer")


def test_floorplan_memo_is_shared_by_the_planner_and_the_scene_tasks(tmp_path, monkeypatch):
    """The planner is handed the sources folder as the user typed it (often relative),
    the scene tasks an absolute one: both find the one memo entry, so an edit build
    parses the DXF at most once, not once in the plan and again in the scene task."""
    from pipeline.builder import tasks
    from pipeline.ingest import floorplan
    from pipeline.scene import assemble

    mini_sources.make(tmp_path / "src")
    monkeypatch.chdir(tmp_path)
    build = tmp_path / "build"
    planned = tasks.load_sources(Path("src"), memo=build / floorplan.MEMO_NAME).floorplan

    def refuse(*args, **kwargs):
        raise AssertionError("the DXF was parsed again")

    monkeypatch.setattr(floorplan, "read_floorplan", refuse)
    _, in_scene, _ = assemble._load((tmp_path / "src").resolve(), build)
    assert in_scene.placements == planned.placements
    assert tasks.load_sources(Path("src"), memo=build / floorplan.MEMO_NAME).floorplan.placements == planned.placements


def test_floorplan_memo_skips_the_dxf_until_it_changes(tmp_path, monkeypatch):
    """A no-op build plans from the memo of the last floor plan read (no DXF parse);
    a new DXF content or a new set of levels reads the drawing again."""
    from pipeline.builder import tasks
    from pipeline.ingest import floorplan

    sources = mini_sources.make(tmp_path / "src")
    memo = tmp_path / "build" / floorplan.MEMO_NAME
    first = tasks.load_sources(sources, memo=memo).floorplan
    assert memo.is_file()

    def refuse(*args, **kwargs):
        raise AssertionError("the DXF was parsed again")

    real = floorplan.read_floorplan
    monkeypatch.setattr(floorplan, "read_floorplan", refuse)
    again = tasks.load_sources(sources, memo=memo).floorplan
    assert again.placements == first.placements and again.ignored == first.ignored
    assert all(np.array_equal(a.outline, b.outline) for a, b in zip(again.platforms, first.platforms))

    moved = [(t, a, lv, x + 1.0, y, z, r) for t, a, lv, x, y, z, r in mini_sources.PLACEMENTS]
    mini_sources.write_plan(sources / "floorplan" / "plan.dxf", moved)
    with pytest.raises(AssertionError, match="parsed again"):
        tasks.load_sources(sources, memo=memo)
    monkeypatch.setattr(floorplan, "read_floorplan", real)
    edited = tasks.load_sources(sources, memo=memo).floorplan
    assert [p.x for p in edited.placements] == [p.x + 1.0 for p in first.placements]


def test_no_op_plan_skips_the_config_checks_it_passed_before(mini_copy):
    """The planner keeps the keys of passed checks in the build folder: planning again
    imports neither jsonschema nor pyproj; edited content is checked again, and a
    broken edit still gets its one clear error."""
    src, out = mini_copy  # the run's mini build, copied
    explain(src, out)
    # site schema, CRS, two assets, the site frame (site_frame)
    assert len(json.loads((out / ".checked.json").read_text())) == 1 + 1 + 2 + 1
    probe = ("import sys; from pathlib import Path; from pipeline.builder.tasks import plan; "
             f"plan(Path({str(src)!r}), Path({str(out)!r})); "
             "print(sorted(m for m in ('jsonschema', 'pyproj') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
    toml = src / "assets" / "pole" / "asset.toml"
    toml.write_text(re.sub(r"^category\s*=.*$", "category = 7", toml.read_text(), flags=re.M))  # not a string
    proc = twin("build", "--sources", src, "--out", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "asset.toml" in proc.stderr and "category" in proc.stderr
    assert len(json.loads((out / ".checked.json").read_text())) == 5  # nothing of the bad file kept


ACTION_MODULES = {"source": "pipeline.builder.source_task", "geometry": "pipeline.builder.geometry_task",
                  "asset": "pipeline.builder.package_task", "placed": "pipeline.builder.placed_task",
                  "scene": "pipeline.builder.scene_task",
                  "viewer": "pipeline.builder.viewer_task", "tiles": "pipeline.builder.tiles_task",
                  "viewer:libs": "pipeline.builder.libs_task"}


def test_each_task_kind_is_keyed_on_its_own_action_and_not_on_the_planner(tmp_path):
    """A task's code version is its action's module and what that imports (an edit
    of it reruns those tasks); the planner and the other kinds' actions are in none
    (an edit of plan() reruns nothing)."""
    from pipeline.engine import code
    from pipeline.builder import tasks

    for module in ACTION_MODULES.values():
        used = set(code.modules_used(module))
        assert module in used and "pipeline.builder.tasks" not in used
        assert not (set(ACTION_MODULES.values()) - {module}) & used
    assert "pipeline.builder.layout" in code.modules_used("pipeline.builder.source_task")
    assert "pipeline.ingest.blend.walk" in code.modules_used("pipeline.builder.source_task")  # through readers
    p = tasks.plan(mini_sources.make(tmp_path / "src"), tmp_path / "build")
    assert {t.action.__module__ for t in p.tasks} == set(ACTION_MODULES.values())
    for t in p.tasks:
        assert t.code == code.code_of(t.action.__module__), t.name


def test_a_task_key_changes_with_the_modules_it_imports_and_no_other(tmp_path):
    """In a copy of the package: an edit of a module a task reaches through its
    imports (directly, transitively, a package's __init__) changes that task's code
    version; an edit of a module it does not reach leaves it as it was."""
    from pipeline.engine import code

    shutil.copytree(ROOT / "pipeline", tmp_path / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    kinds = ("source", "geometry", "asset", "scene", "tiles", "viewer:libs")

    def versions() -> dict[str, str]:
        return {k: code.code_of(ACTION_MODULES[k], root=tmp_path) for k in kinds}

    def edit(module: str) -> set[str]:
        """The kinds whose code version an edit of `module` changes."""
        before = versions()
        path = code.module_file(module, tmp_path)
        path.write_text(path.read_text() + "\n# edited\n")
        after = versions()
        return {k for k in kinds if after[k] != before[k]}

    assert edit("pipeline.ingest.mesh") == {"source"}
    assert edit("pipeline.ingest.blend.walk") == {"source"}  # a package's module, through its __init__
    assert edit("pipeline.geometry.simplify.backends") == {"geometry"}  # lod -> simplify -> backends
    assert edit("pipeline.export.collada") == {"asset", "scene"}  # the terrain's package too
    assert edit("pipeline.viewer.tiles") == {"tiles"}
    assert edit("pipeline.viewer.libs") == {"viewer:libs"}
    assert edit("pipeline.ir") == {"source", "geometry", "asset", "scene", "tiles"}
    assert edit("pipeline.builder.tasks") == set()  # the planner
    assert edit("pipeline.bench.builds") == set()
    assert edit("pipeline.cli") == set()


def test_the_import_scan_finds_every_import_a_full_parse_does():
    """engine.code reads import statements without parsing whole modules: in every
    pipeline module it finds each import statement ast.walk finds."""
    import ast

    from pipeline.engine.code import import_statements

    for path in sorted((ROOT / "pipeline").rglob("*.py")):
        text = path.read_text()
        full = {ast.dump(n) for n in ast.walk(ast.parse(text)) if isinstance(n, (ast.Import, ast.ImportFrom))}
        assert full <= {ast.dump(n) for n in import_statements(text)}, path


# --- the files a reader opens through the source ---------------------------------------------

def _textured_obj(folder: Path, colour=(20, 200, 20)) -> None:
    """An OBJ asset whose .mtl gives one material a red Kd and another an image."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (4, 2), colour).save(folder / "green.png")
    (folder / "m.mtl").write_text("newmtl red\nKd 0.9 0.1 0.1\nnewmtl grass\nKd 1 1 1\nmap_Kd green.png\n")
    (folder / "panel.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 0 0\n"
        "usemtl red\nf 1/1 3/3 2/2\nf 1/1 2/2 5/5\nusemtl grass\nf 2/2 3/3 5/5\nf 1/1 5/5 3/3\n")
    (folder / "asset.toml").write_text('category = "panel"\nsource = "panel.obj"\n')


def _package_images(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / "models" / "panel" / "textures").glob("*"))}


def test_editing_a_file_the_reader_opens_rebuilds_the_asset(mini, tmp_path):
    """The texture and the .mtl an OBJ names are keyed like the OBJ itself: an edit of
    either reruns the asset's chain, undoing it restores the cache's, and a build
    folder that shares the cache but has no state of its own finds them too."""
    from PIL import Image

    sources = tmp_path / "sources"
    shutil.copytree(mini[0], sources)
    folder = sources / "assets" / "panel"
    _textured_obj(folder)
    out, cache = tmp_path / "build", tmp_path / "cache"
    only = ("--only", "panel", "--cache", cache)
    first = explain(sources, out, *only)
    assert ran(first) == {"source:panel", "geometry:panel", "asset:panel"}
    state = json.loads((out / ".state.json").read_text())
    assert sorted(state["tasks"]["source:panel"]["opened"]) == ["green.png", "m.mtl"]
    before = _package_images(out)
    assert ran(explain(sources, out, *only)) == set()

    Image.new("RGB", (4, 2), (200, 20, 20)).save(folder / "green.png")  # the texture repainted
    edit = explain(sources, out, *only)
    assert ran(edit) == {"source:panel", "geometry:panel", "asset:panel"}
    assert edit["source:panel"]["changed"] == ["opened green.png"]
    after = _package_images(out)
    assert after != before and len(after) == 1
    assert np.asarray(Image.open(io.BytesIO(next(iter(after.values()))))).reshape(-1, 3)[0].tolist() == [200, 20, 20]

    mtl = folder / "m.mtl"
    mtl.write_text(mtl.read_text().replace("Kd 0.9 0.1 0.1", "Kd 0.1 0.1 0.9"))  # red becomes blue
    recoloured = explain(sources, out, *only)
    assert recoloured["source:panel"]["changed"] == ["opened m.mtl"] and recoloured["asset:panel"]["ran"]

    _textured_obj(folder)  # everything as it first was: the cache has the chain
    undone = explain(sources, out, *only)
    assert ran(undone) == set() and undone["source:panel"]["reason"] == "restored from cache"
    assert _package_images(out) == before

    elsewhere = explain(sources, tmp_path / "other", *only)  # no state of its own, the same cache
    assert ran(elsewhere) == set()

    (folder / "green.png").unlink()  # gone: the reader says so, and adding it back rebuilds
    gone = explain(sources, out, *only)
    assert gone["source:panel"]["changed"] == ["opened green.png"] and _package_images(out) == {}
    proc = twin("build", "--sources", sources, "--out", out, *only)
    assert "panel: warning: panel.obj: material 'grass': image 'green.png': not found" in proc.stderr, proc.stderr

    _textured_obj(folder)  # back: read again, and the rest of the chain is the cache's
    back = explain(sources, out, *only)
    assert ran(back) == {"source:panel"} and back["source:panel"]["changed"] == ["opened green.png"]
    assert _package_images(out) == before


def test_a_plain_build_ends_with_a_summary_of_what_ran(mini, tmp_path):
    sources, _ = mini
    src = tmp_path / "src"
    shutil.copytree(sources, src)
    out = tmp_path / "build"
    summary = re.compile(r"^built (\d+) of (\d+) tasks(?: \((.+)\))?, (\d+) fresh, in \d+\.\d s$")

    def last_line(proc) -> re.Match:
        assert proc.returncode == 0, proc.stderr[-3000:]
        m = summary.match(proc.stderr.strip().splitlines()[-1])
        assert m, proc.stderr[-1000:]
        return m

    first = last_line(twin("build", "--sources", src, "--out", out))
    total = int(first.group(2))
    assert int(first.group(1)) == total > 5 and int(first.group(4)) == 0
    assert "source:pole" in first.group(3) and "more" in first.group(3)
    noop = last_line(twin("build", "--sources", src, "--out", out))
    assert noop.groups() == ("0", str(total), None, str(total))
    nudge_source(src / "assets" / "pole" / "pole.obj", 0.01)
    proc = twin("build", "--sources", src, "--out", out, "--explain")
    edit = last_line(proc)
    ran_now = sorted(line.split()[1].rstrip(":") for line in proc.stdout.splitlines() if line.startswith("RAN "))
    assert "source:pole" in ran_now and 0 < len(ran_now) < total
    assert int(edit.group(1)) == len(ran_now) and int(edit.group(4)) == total - len(ran_now)
    assert set(edit.group(3).split(" and ")[0].split(", ")) <= set(ran_now)
    # --json: the document alone on stdout, no summary
    proc = twin("build", "--sources", src, "--out", out, "--json")
    assert len(json.loads(proc.stdout)["tasks"]) == total and "built" not in proc.stderr
