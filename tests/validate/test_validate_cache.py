"""validate.cache: a package judged before as it is now takes its verdicts from
build/.validate/, and only then. Uses test_report's hand-made build (the articulated
package with a LOD variant, the PKG004 crate)."""

from __future__ import annotations

import json

from test_report import make_build
from pipeline.validate import cache, external, report

ARM_DAE = "models/test_arm/meshes"


def _rows(data: dict, validator: str, target_prefix: str) -> list[dict]:
    return [r for a in data["assets"] for r in a["external"]
            if r["validator"] == validator and r["target"].startswith(target_prefix)]


def test_an_unchanged_build_is_judged_from_the_cache_with_the_same_report(tmp_path, monkeypatch):
    root = make_build(tmp_path)
    first, timings = report.build_report(root, root)
    assert timings["cached_packages"] == 0
    schema_runs = []
    real = external.collada_schema
    monkeypatch.setattr(external, "collada_schema", lambda p: schema_runs.append(p) or real(p))
    second, timings = report.build_report(root, root)
    assert timings["cached_packages"] == len(first["assets"]) and schema_runs == []
    assert report.to_json(second) == report.to_json(first)


def test_a_cached_ok_is_not_reused_after_the_file_changes(tmp_path):
    root = make_build(tmp_path)
    before = report.build_report(root, root)[0]
    passed = _rows(before, "pycollada ColladaValidator", ARM_DAE)
    assert passed and all(r["status"] == "passed" for r in passed)
    # well-formed XML the COLLADA schema refuses: an element it does not know
    dae = root / passed[0]["target"]
    dae.write_text(dae.read_text().replace("<asset>", "<not_collada/><asset>", 1))
    after, timings = report.build_report(root, root)
    assert timings["cached_packages"] == len(before["assets"]) - 1  # only the edited package is judged again
    row = next(r for r in _rows(after, "pycollada ColladaValidator", ARM_DAE) if r["target"] == passed[0]["target"])
    assert row["status"] == "failed" and any("not_collada" in m for m in row["messages"])
    assert after["summary"]["errors"] > before["summary"]["errors"]


def test_same_bytes_in_two_files_are_schema_checked_once_and_reported_for_both(tmp_path, monkeypatch):
    root = make_build(tmp_path)
    meshes = sorted((root / ARM_DAE).glob("*.dae"))
    twin = meshes[0].with_name("zz_copy.dae")
    twin.write_bytes(meshes[0].read_bytes())
    runs = []
    real = external.collada_schema
    monkeypatch.setattr(external, "collada_schema", lambda p: runs.append(p) or real(p))
    data = report.build_report(root, root)[0]
    arm_runs = [p for p in runs if "test_arm" in str(p)]
    assert len(arm_runs) == len({m.read_bytes() for m in meshes}) == len(meshes)
    rows = {r["target"]: r for r in _rows(data, "pycollada ColladaValidator", ARM_DAE)}
    first = f"{ARM_DAE}/{meshes[0].name}"
    assert rows[f"{ARM_DAE}/zz_copy.dae"]["status"] == rows[first]["status"] == "passed"


def test_the_cache_is_never_trusted_across_validator_versions(tmp_path):
    root = make_build(tmp_path)
    report.build_report(root, root)
    stored = json.loads((root / cache.FOLDER / cache.FILE).read_text())
    assert stored["entries"] and stored["versions"]["code"]
    older = dict(stored["versions"], sdformat="libsdformat12.so.12.2.0:0000")
    folders = [root / "models" / "test_arm", root / "models" / "test_arm__lod1"]
    now = cache.ResultCache(root, stored["versions"])
    assert now.get(now.key("test_arm", folders)) is not None
    other = cache.ResultCache(root, older)
    assert other.get(other.key("test_arm", folders)) is None


def test_a_skipped_validator_is_not_kept(tmp_path, monkeypatch):
    root = make_build(tmp_path)
    monkeypatch.setattr(external, "gltf_validator",
                        lambda paths, **kw: [external._skipped("gltf-validator", p, "no node", "hint") for p in paths])
    skipped = report.build_report(root, root)[0]
    with_glb = {a["id"] for a in skipped["assets"] if any(r["validator"] == "gltf-validator" for r in a["external"])}
    monkeypatch.undo()
    again = report.build_report(root, root)
    assert with_glb and again[1]["cached_packages"] == len(skipped["assets"]) - len(with_glb)
    assert all(r["status"] != "skipped" for r in _rows(again[0], "gltf-validator", "models/"))
