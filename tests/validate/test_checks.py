"""The rule table, one bad/ fixture per rule (exactly its code), clean/ fixtures
(no finding, compared with the kept expected report), and hardened XML parsing."""

from __future__ import annotations

import importlib.util
import re
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fixtures_assets import box_mesh
from helpers import DATA, TESTS
from pipeline import ir
from pipeline.findings import RULES, Finding, finding, mesh_findings
from pipeline.validate.checks import check_asset, check_package


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BAD = _load(DATA / "bad" / "assets.py", "bad_assets")
CLEAN = _load(DATA / "clean" / "assets.py", "clean_assets")
PKG_CODES = sorted(p.name for p in (DATA / "bad").glob("PKG*"))
PLACE_CODES = sorted(p.name for p in (DATA / "bad").glob("PLACE*"))
GZ_CODES = sorted(_load(Path(__file__).with_name("test_gazebo_rules.py"), "gazebo_rules").FIXTURES)
# the conductor rules' bad cases are spans built in tests/scene/test_clearance.py, each
# asserted there by its code
WIRE_CODES = sorted(set(re.findall(r'"(WIRE\d{3})"', (TESTS / "scene" / "test_clearance.py").read_text())))


def test_every_rule_has_exactly_one_bad_fixture():
    fixtures = sorted([*BAD.FIXTURES, *PKG_CODES, *PLACE_CODES, *GZ_CODES, *WIRE_CODES])
    assert fixtures == sorted(RULES)


def test_rule_table_is_well_formed():
    for code, (severity, group, description) in RULES.items():
        assert severity in ("error", "warning", "info")
        assert code.startswith({"geometry": "GEOM", "hierarchy": "HIER", "placement": "PLACE",
                                "package": "PKG", "gazebo": "GZ", "conductor": "WIRE"}[group])
        assert description
    assert finding("GEOM003", "a/b/c", "x") == Finding("GEOM003", "warning", "a/b/c", "x")


@pytest.mark.parametrize("code", sorted(BAD.FIXTURES))
def test_bad_asset_yields_exactly_its_code(code):
    asset, kwargs = BAD.FIXTURES[code]()
    found = check_asset(asset, **kwargs)
    assert {f.code for f in found} == {code}, found
    assert all(f.severity == RULES[code][0] for f in found)
    assert all(f.site.startswith(asset.id) for f in found)


@pytest.mark.parametrize("code", sorted(BAD.FIXTURES))
def test_findings_recalled_from_the_memo_are_the_findings_checked(code, tmp_path):
    """The per-mesh memo (shared by the geometry and package tasks) gives back what a
    check finds, at the site it is asked for; a damaged entry is checked again."""
    from pipeline.engine.memo import ArrayMemo

    asset, kwargs = BAD.FIXTURES[code]()
    memo = ArrayMemo(tmp_path, "checks-v1")
    first = check_asset(asset, **kwargs, memo=memo)
    assert first == check_asset(asset, **kwargs)
    meshes = sum(len(v.lods) for _, v in asset.visuals()) + sum(len(link.collisions) for link in asset.links)
    assert memo.hits + memo.puts == meshes and memo.puts > 0  # a repeated mesh is a hit already
    for entry in (tmp_path / "memo").rglob("*.npz"):  # damaged entries: checked again
        entry.write_bytes(b"not a zip")
    assert check_asset(asset, **kwargs, memo=memo) == first
    again = ArrayMemo(tmp_path, "checks-v1")
    assert check_asset(asset, **kwargs, memo=again) == first
    assert (again.hits, again.puts) == (meshes, 0)


def test_memo_findings_take_the_site_they_are_asked_for(tmp_path):
    from pipeline.engine.memo import ArrayMemo

    box = box_mesh()
    inward = ir.Mesh(box.vertices, box.faces[:, ::-1])  # every face turned over: GEOM005
    memo = ArrayMemo(tmp_path, "ns")
    assert [x.site for x in mesh_findings(inward, "a/one", memo=memo)] == ["a/one"]
    recalled = mesh_findings(inward, "b/two", memo=memo)
    assert memo.hits == 1 and recalled == mesh_findings(inward, "b/two")
    assert mesh_findings(inward, "c", collision=True, memo=memo) == mesh_findings(inward, "c", collision=True)
    assert memo.puts == 2  # a collision mesh is its own entry (it is also checked for holes)


@pytest.mark.parametrize("code", PKG_CODES)
def test_bad_package_yields_exactly_its_code(code):
    found = check_package(DATA / "bad" / code / "crate")
    assert {f.code for f in found} == {code}, found


def _clean_report() -> dict:
    report = {f"asset:{name}": [f.as_dict() for f in check_asset(build(), 400000)]
              for name, build in sorted(CLEAN.FIXTURES.items())}
    for pkg in sorted((DATA / "clean" / "packages").iterdir()):
        report[f"package:{pkg.name}"] = [f.as_dict() for f in check_package(pkg)]
    return report


def test_clean_fixtures_match_the_kept_report():
    expected = json.loads((DATA / "clean" / "expected_findings.json").read_text())
    report = _clean_report()
    assert report == expected
    assert all(v == [] for v in report.values())  # what is kept is: nothing wrong


def test_findings_are_sorted_and_deterministic():
    asset, _ = BAD.FIXTURES["HIER003"]()
    first, second = check_asset(asset), check_asset(asset)
    assert first == second
    assert first == sorted(first, key=lambda f: (f.site, f.code, f.message))


def test_several_problems_are_all_reported():
    """One asset, three independent problems: all three codes, nothing stops early."""
    asset, _ = BAD.FIXTURES["GEOM005"]()
    bad_link = ir.Link("b.1", visuals=(ir.Visual("v", "paint", (box_mesh(),)),))
    asset = asset.with_(links=(*asset.links, bad_link),
                        joints=(ir.Joint("j", "revolute", "body", "b.1", axis=(0, 0, 0)),))
    assert {f.code for f in check_asset(asset)} == {"GEOM005", "HIER005", "HIER006"}


def test_nan_in_shape_key_and_pose_are_reported():
    box = box_mesh()
    key = ir.ShapeKey("full", np.where(np.arange(8)[:, None] == 2, np.inf, box.vertices))
    link = ir.Link("body", visuals=(ir.Visual("v", "m", (ir.Mesh(box.vertices, box.faces, shape_keys=(key,)),)),))
    bad_pose = np.eye(4)
    bad_pose[0, 3] = np.nan
    lid = ir.Link("lid", pose=bad_pose, visuals=(ir.Visual("w", "m", (box,)),))
    asset = ir.Asset("x", "t", (link, lid), joints=(ir.Joint("j", "fixed", "body", "lid"),))
    sites = {(f.code, f.site) for f in check_asset(asset)}
    assert ("GEOM001", "x/body/v") in sites and ("GEOM001", "x/lid") in sites


def test_tiny_asset_is_a_unit_mistake():
    tiny = box_mesh((0.001, 0.001, 0.001))
    asset = ir.Asset("mm", "t", (ir.Link("l", visuals=(ir.Visual("v", "m", (tiny,)),)),))
    assert [f.code for f in check_asset(asset)] == ["GEOM010"]


def _copy_clean(tmp_path: Path) -> Path:
    dest = tmp_path / "models" / "crate"
    shutil.copytree(DATA / "clean" / "packages" / "crate", dest)
    return dest


def test_lod_variant_may_use_its_base_meshes(tmp_path):
    pkg = _copy_clean(tmp_path)
    variant = pkg.parent / "crate__lod1"
    variant.mkdir()
    for name in ("model.config", "model.sdf"):
        shutil.copy(pkg / name, variant / name)
    assert check_package(variant) == []
    other = pkg.parent / "other__lod1"
    shutil.copytree(variant, other)
    assert {f.code for f in check_package(other)} == {"PKG003"}


def test_symlink_out_of_the_package_is_refused(tmp_path):
    pkg = _copy_clean(tmp_path)
    outside = tmp_path / "elsewhere.dae"
    shutil.copy(pkg / "meshes" / "body__shell__lod0.dae", outside)
    (pkg / "meshes" / "body__shell__lod0.dae").unlink()
    (pkg / "meshes" / "body__shell__lod0.dae").symlink_to(outside)
    codes = {f.code for f in check_package(pkg)}
    assert "PKG003" in codes and "PKG004" not in codes  # never hashed nor parsed through the link


def test_entities_in_model_sdf_are_never_expanded(tmp_path):
    """A billion-laughs DOCTYPE in model.sdf: refused at once, nothing expanded."""
    pkg = _copy_clean(tmp_path)
    lol = "".join(f'<!ENTITY l{i} "{("&l%d;" % (i - 1)) * 10 if i else "lol"}">' for i in range(9))
    text = (pkg / "model.sdf").read_text().replace("<sdf ", f"<!DOCTYPE sdf [{lol}]>\n<sdf ", 1)
    (pkg / "model.sdf").write_text(text.replace("<model ", "<model_x>&l8;</model_x><model ", 1))
    found = check_package(pkg)
    # PKG004: the edit changed model.sdf's hash, as it should
    assert sorted((f.code, f.site) for f in found) == [("PKG004", "crate/model.sdf"), ("PKG005", "crate/model.sdf")]
    assert all(len(f.message) < 500 for f in found)


def test_xxe_secret_never_reaches_a_finding():
    found = check_package(DATA / "bad" / "PKG005" / "crate")
    secret = (DATA / "bad" / "PKG005" / "xxe_secret.txt").read_text().strip()
    assert found and all(secret not in f.message for f in found)


def test_manifest_path_escaping_the_package(tmp_path):
    pkg = _copy_clean(tmp_path)
    data = json.loads((pkg / "manifest.json").read_text())
    data["outputs"]["../../etc/passwd"] = "0" * 64
    (pkg / "manifest.json").write_text(json.dumps(data))
    found = check_package(pkg)
    assert [(f.code, f.site) for f in found] == [("PKG003", "crate/../../etc/passwd")]


def test_unparseable_manifest(tmp_path):
    pkg = _copy_clean(tmp_path)
    (pkg / "manifest.json").write_text("{not json")
    assert [f.code for f in check_package(pkg)] == ["PKG006"]


if __name__ == "__main__":  # regenerate the kept clean report
    (DATA / "clean" / "expected_findings.json").write_text(json.dumps(_clean_report(), indent=1, sort_keys=True) + "\n")
