"""What a rebuild reruns: nothing when the sources folder moves (keys name inputs
relative to the sources, not by where they sit), and not the terrain when only the
placements of the floor plan change (its key is what it is made of)."""

from __future__ import annotations

import json
import shutil

import ezdxf

import mini_sources
from test_incremental import explain, ran, tree_hashes


def test_a_moved_sources_folder_reruns_nothing(tmp_path):
    first = mini_sources.make(tmp_path / "checkout-1" / "sources")
    out, cache = tmp_path / "build", tmp_path / "cache"
    explain(first, out, "--cache", cache)
    made = tree_hashes(out)
    between = _intermediates(out)

    # the same bytes in another folder, at another depth, the first one gone
    moved = tmp_path / "elsewhere" / "deeper" / "site-sources"
    shutil.copytree(first, moved)
    shutil.rmtree(first)
    again = explain(moved, out, "--cache", cache)
    assert ran(again) == set()
    assert {e["reason"] for e in again.values()} == {"up to date"}
    assert all(e["changed"] == [] for e in again.values())
    assert tree_hashes(out) == made
    hashed = json.loads((out / ".state.json").read_text())["hashes"]
    assert hashed and not [p for p in hashed if str(first) in p]  # the old folder's files are forgotten

    # a CI runner: another checkout, another build folder, the cache shared
    ci = explain(moved, tmp_path / "runner" / "out", "--cache", cache)
    assert ran(ci) == set()
    assert {e["reason"] for e in ci.values()} == {"restored from cache"}
    assert tree_hashes(tmp_path / "runner" / "out") == made

    # made again from the moved folder, without the cache: the same bytes, the files the
    # tasks hand on too (a source read again there cuts off, it does not rerun the chain)
    explain(moved, tmp_path / "fresh")
    assert tree_hashes(tmp_path / "fresh") == made
    assert _intermediates(tmp_path / "fresh") == between


def _intermediates(out) -> dict[str, bytes]:
    """What the source and geometry tasks hand on (.source/, .ir/)."""
    return {str(p.relative_to(out)): p.read_bytes() for folder in (".source", ".ir")
            for p in sorted((out / folder).rglob("*")) if p.is_file()}


def _edit_plan(path, edit) -> None:
    doc = ezdxf.readfile(path)
    edit(doc.modelspace())
    doc.saveas(path)


def _insert(msp, tag: str):
    return next(e for e in msp.query("INSERT") if any(a.dxf.text == tag for a in e.attribs))


def test_the_terrain_reruns_only_when_what_it_is_made_of_changes(mini_copy, tmp_path):
    sources, out = mini_copy  # the run's mini build, copied
    plan = sources / "floorplan" / "plan.dxf"
    terrain = {p: h for p, h in tree_hashes(out).items() if p.startswith("models/mini_terrain/")}
    assert terrain

    # one INSERT moved (a real edit of the drawing, saved by ezdxf): the scene, not the terrain
    _edit_plan(plan, lambda msp: _insert(msp, "K-2").dxf.set("insert", (9.5, 1.0, 0.0)))
    moved = explain(sources, out)
    assert moved["terrain"]["reason"] == "up to date"
    assert "scene" in ran(moved) and "terrain" not in ran(moved)
    assert {p: h for p, h in tree_hashes(out).items() if p.startswith("models/mini_terrain/")} == terrain

    # an inspection point edited in site.toml: the terrain does not use it either
    site = sources / "site.toml"
    site.write_text(site.read_text().replace("position = [4.0, -6.0, 1.6]", "position = [5.0, -6.0, 1.6]"))
    assert explain(sources, out)["terrain"]["reason"] == "up to date"

    # a platform outline moved: the terrain is made again
    def widen(msp):
        outline = next(e for e in msp.query("LWPOLYLINE") if e.dxf.layer == "PLATFORM_L1")
        outline.set_points([(x - 1.0 if x < 0 else x, y) for x, y, *_ in outline.get_points()])

    _edit_plan(plan, widen)
    widened = explain(sources, out)
    assert "terrain" in ran(widened) and widened["terrain"]["changed"] == ["parameters"]

    # ... and a level's elevation too; what the terrain became is what a clean build makes
    site.write_text(site.read_text().replace("elevation = 51.0", "elevation = 51.5"))
    assert "terrain" in ran(explain(sources, out))
    explain(sources, tmp_path / "clean")
    assert tree_hashes(out) == tree_hashes(tmp_path / "clean")


def test_the_gazebo_worlds_moving_parts_rerun_the_scene_side_only(mini_copy):
    """site.toml [gazebo] moving_parts is read by the scene alone (and by what reads
    site.toml after it: the viewer and the tiles); no asset, view or terrain reruns,
    placements.json records the choice for the live twin, and a bad value or a pattern
    that selects no switch stops the build with one line naming the file and the key."""
    from helpers import twin

    sources, out = mini_copy  # the run's mini build, copied
    site = sources / "site.toml"
    record = json.loads((out / "scene" / "placements.json").read_text())
    # "auto": the world with every switch moving, well within sdformat's parse budget
    assert record["gazebo"]["moving_parts"] == "all" and record["gazebo"]["chosen_by"] == "auto"
    assert 0 < record["gazebo"]["parse_estimate_mb"] < 1536
    original = site.read_text()

    site.write_text(original + '\n[gazebo]\nmoving_parts = "none"\n')
    frozen = explain(sources, out)
    assert "scene" in ran(frozen) and ran(frozen) <= {"scene", "viewer", "tiles"}
    assert json.loads((out / "scene" / "placements.json").read_text())["gazebo"] == {"moving_parts": "none"}

    site.write_text(original + '\n[gazebo]\nmoving_parts = "some"\n')
    before = tree_hashes(out)
    failed = twin("build", "--sources", sources, "--out", out)
    assert failed.returncode == 1 and failed.stderr.strip().splitlines()[-1] == (
        f"error: {site}: gazebo.moving_parts: 'some' is not one of ['auto', 'all', 'none']")
    assert tree_hashes(out) == before  # the previous build left as it was
    # a tag pattern that selects no switch (the mini site has none) is a mistake, said as one
    site.write_text(original + '\n[gazebo]\nmoving_parts = ["Q1-*"]\n')
    failed = twin("build", "--sources", sources, "--out", out)
    assert failed.returncode == 1 and f"error: {site}: gazebo.moving_parts: 'Q1-*' matches no placement with " \
        "moving parts (0 placements have them: none)" in failed.stderr.splitlines()
    assert tree_hashes(out) == before
