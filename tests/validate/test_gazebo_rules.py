"""One bad case per GZ rule, judged by validate.gazebo's comparisons on probe reports
(the reports the probe gives for these cases are in test_gazebo_probe.py and
test_gazebo_world.py; here they are made by hand so each rule is seen alone)."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures_assets import box_mesh
from pipeline import ir
from pipeline.export import collada as collada_writer
from pipeline.scene import world_sdf
from pipeline.validate import gazebo
from pipeline.findings import RULES

STEEL = ir.Material("steel")


def _written(tmp_path):
    path = tmp_path / "box.dae"
    path.write_bytes(collada_writer._dae_bytes("box", box_mesh((1, 2, 3), attributes=True), STEEL))
    return path, gazebo.written_summary(path)


def _report(summary: gazebo.MeshSummary, **changes) -> dict:
    """The report the probe gives for a file read exactly (V flipped, as gz-common does)."""
    report = {"ok": True, "triangles": summary.triangles, "corners": summary.corners,
              "min": summary.lo.tolist(), "max": summary.hi.tolist(),
              "corner_sum": summary.corner_sum.tolist(), "corner_sq": summary.corner_sq.tolist(),
              "normals": summary.normals, "normal_sum": summary.normal_sum.tolist(), "uvs": summary.uvs,
              "uv_sum": [summary.uv_sum[0], summary.uvs - summary.uv_sum[1]]}
    report.update(changes)
    return report


def _mesh(tmp_path, **changes):
    path, summary = _written(tmp_path)
    return gazebo.compare_mesh("box", summary, _report(summary, **changes))


FIXTURES = {
    "GZ001": lambda t: gazebo.compare_mesh("box", _written(t)[1], {"ok": False, "signal": 11}),
    "GZ002": lambda t: [f for f in _mesh(t, triangles=6) if f.code == "GZ002"],
    "GZ003": lambda t: _mesh(t, corner_sum=[0.5, 0.0, 0.0]),
    "GZ004": lambda t: _mesh(t, max=[0.5, 1.0, 2.0]),
    "GZ005": lambda t: _mesh(t, uv_sum=[0.0, 0.0]),
    "GZ006": lambda t: gazebo.compare_model_bounds("m", [[0, 0, 0], [1, 1, 1]], [[0, 0, 0], [1, 1, 2]], 1e-4),
    "GZ007": lambda t: gazebo.world_findings("w.sdf", {"errors": ["visual with name[x] already exists."],
                                                       "peak_rss_mb": 10.0, "parse_s": 0.1}),
    "GZ008": lambda t: gazebo.world_findings("w.sdf", {"errors": [], "peak_rss_mb": 6154.0, "parse_s": 37.6}),
    # a slow parse alone (a loaded machine) is no finding: time is the bench's
    "GZ009": lambda t: gazebo.mesh_findings([_written(t)[0]], {}, str),
    "GZ010": lambda t: gazebo.mesh_findings([_broken(t)], {str(_broken(t)): {"ok": True}}, str),
    "GZ011": lambda t: gazebo.physics_findings("w.sdf", {"ok": True, "failed_shapes": 3}),
    "GZ012": lambda t: [world_sdf.at_rest_finding("w.sdf", 3670.0)],
}


def _broken(tmp_path):
    path = tmp_path / "broken.dae"
    path.write_text("<COLLADA><library_geometries><geometry id='g'><mesh><triangles count='1'>"
                    "<input semantic='VERTEX' source='#nowhere' offset='0'/><p>0 1 2</p>"
                    "</triangles></mesh></geometry></library_geometries></COLLADA>")
    return path


@pytest.mark.parametrize("code", sorted(FIXTURES))
def test_each_bad_case_yields_exactly_its_code(code, tmp_path):
    found = FIXTURES[code](tmp_path)
    assert found and {f.code for f in found} == {code}, found
    assert all(f.severity == RULES[code][0] for f in found)


def test_an_exact_reading_yields_nothing(tmp_path):
    path, summary = _written(tmp_path)
    assert gazebo.compare_mesh("box", summary, _report(summary)) == []
    assert gazebo.world_findings("w.sdf", {"errors": [], "peak_rss_mb": 1123.0, "parse_s": 2.0}) == []
    assert gazebo.world_findings("w.sdf", {"errors": [], "peak_rss_mb": 1123.0, "parse_s": 12.1}) == []


def test_a_world_over_its_parse_budget_with_moving_parts_names_the_setting():
    """The 5,000-placement plan's world with its 1,400 joints: the finding says what
    they cost and which site.toml setting keeps the switches at rest."""
    (found,) = gazebo.world_findings("w.sdf", {"errors": [], "peak_rss_mb": 3640.0, "parse_s": 16.2}, joints=1400)
    assert found.code == "GZ008" and "its 1,400 joints (the switches' moving parts) take about 2377 MB" in found.message
    assert '[gazebo] moving_parts = "none", or a list of the tags' in found.message
    (bare,) = gazebo.world_findings("w.sdf", {"errors": [], "peak_rss_mb": 3640.0, "parse_s": 16.2})
    assert "joints" not in bare.message
    assert gazebo.physics_findings("w.sdf", {"ok": True, "failed_shapes": 0}) == []
    assert gazebo.physics_findings("w.sdf", {"ok": True, "failed_shapes": 0, "failed_joints": 0}) == []


def test_a_joint_dartsim_cannot_build_is_a_finding():
    found = gazebo.physics_findings("w.sdf", {"ok": True, "failed_shapes": 0, "failed_joints": 2})
    assert [f.code for f in found] == ["GZ011"] and "2 joints failed" in found[0].message


@pytest.mark.parametrize("indices", ["0 1 -2", "0 1 2.0", "0 1 two", "0,1,2", "0 1 99999999999999999999"])
def test_a_p_that_is_not_vertex_indices_is_a_finding_not_a_summary(indices, tmp_path):
    """A negative index would wrap to the last vertex, and numpy's text reader stops at
    a word it cannot read or saturates a huge number: each is GZ010, never a summary."""
    path, _ = _written(tmp_path)
    text = path.read_text()
    start = text.index("<p>") + len("<p>")
    path.write_text(text[:start] + indices + text[text.index("</p>"):])
    found = gazebo.mesh_findings([path], {str(path): {"ok": True}}, str)
    assert [f.code for f in found] == ["GZ010"], found


def test_a_p_of_whitespace_alone_holds_no_triangles(tmp_path):
    """numpy's text reader reads whitespace alone as one index 0; the summary has none."""
    path, _ = _written(tmp_path)
    text = path.read_text()
    path.write_text(text[:text.index("<p>") + len("<p>")] + " \n  " + text[text.index("</p>"):])
    written = gazebo.written_summary(path)
    assert written.triangles == 0 and written.corners == 0
