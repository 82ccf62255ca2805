"""The full sample substation, end to end (slow; CI runs it): build, validate with the
formats' own validators, run the oil-leak scenario. Builds into the repository's
build/ folder, so a later `make scene` finds the work done."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BUILD = ROOT / "build"

pytestmark = [pytest.mark.slow, pytest.mark.blender]


def twin(*args):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=3600)


@pytest.fixture(scope="module")
def sample():
    proc = twin("build", "--sources", ROOT / "sources", "--out", BUILD)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return BUILD


def test_every_used_asset_has_a_package_within_budget(sample):
    placements = json.loads((sample / "scene" / "placements.json").read_text())
    used = {p["asset"] for p in placements["placements"]}
    assert len(placements["placements"]) == 787
    assert "wave_trap" not in used and not (sample / "models" / "wave_trap").exists()
    for asset in sorted(used):
        m = json.loads((sample / "models" / asset / "manifest.json").read_text())
        assert m["lods"][0]["triangles"] > 0
        assert all(lod["within_budget"] for lod in m["lods"]), (asset, m["lods"])
        for rel in m["outputs"]:
            assert (sample / "models" / asset / rel).is_file()


def test_validation_report_has_no_errors(sample):
    proc = twin("validate", "--sources", ROOT / "sources", "--out", sample)
    report = json.loads((sample / "reports" / "validation.json").read_text())
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    assert report["summary"]["errors"] == 0
    assert (sample / "reports" / "validation.html").is_file()
    assert (sample / "reports" / "junit.xml").is_file()


def test_oil_leak_scenario_runs_on_the_sample(sample):
    proc = twin("run", ROOT / "sources" / "scenarios" / "oil_leak.toml", "--out", sample)
    assert proc.returncode == 0, proc.stderr[-4000:]
    run = sample / "runs" / "oil_leak"
    lines = (run / "states.jsonl").read_text().splitlines()
    assert len(lines) >= 60
    assert (run / "states.usda").is_file()
