"""The conductors in Cycles: a sub-pixel span seen from above against the ground, in a
site of its own (no placement), through the code a dataset frame and a live render
take (open_scene, shoot): the wire shows in the picture, Cycles' own label pass agrees
with the rasterized labels, and the sag follows the shot's conductor temperature."""

from __future__ import annotations

import datetime as dt
import json
import math

import numpy as np
import pytest

from test_wire_labels import DIAMETER, TYPES, span_record

from pipeline.geometry import catenary as cat
from pipeline.geometry.pinhole import look_at

pytestmark = pytest.mark.blender

SPAN = "G-1.a~G-2.b"
P0, P1 = np.array([-9.0, 20.0, 14.0]), np.array([9.0, 24.0, 12.5])
EYE = np.array([0.0, 0.0, 18.0])
W, H = 160, 120


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """(ctx, {temperature: (rgb, ids, depth, record, cycles' own ids, cycles' own depth, parts)},
    the lowest vertex of the span's mesh per temperature, linear renders with and
    without the wire)."""
    pytest.importorskip("bpy")
    from pipeline.datasets.plan import FramePlan
    from pipeline.datasets.frame import open_scene, shoot
    from pipeline.render.sensor import PhoneCamera
    from pipeline.runtime import camera as camera_model
    from pipeline.runtime.site import BuiltSite, Shot

    build = tmp_path_factory.mktemp("wires") / "build"
    (build / "scene").mkdir(parents=True)
    span = span_record(SPAN, P0, P1, sag=0.3)
    (build / "scene" / "conductors.json").write_text(json.dumps({"temperature_c": 25.0, "types": TYPES,
                                                                  "spans": [span]}))
    site = BuiltSite(build, [], {}, (-12.0, -38.5, 0.0), "2025-03-20")
    ctx = open_scene(site, PhoneCamera(width=W, height=H, samples=16, render_denoise=""), 3, [])
    pose = look_at(EYE, (P0 + P1) / 2 + [0.0, 0.0, 1.0])
    when = dt.datetime(2025, 3, 20, 12, 0, tzinfo=dt.timezone(dt.timedelta(hours=-3)))
    out = {}
    try:
        for temperature in (None, 80.0):
            shot = Shot(when, pose, camera_model.lens(1.0), math.radians(55.0), math.radians(40.0), 700.0,
                        conductor_temperature_c=temperature)
            plan = FramePlan(0, "000000", 7, "test", shot, 1.0, 0.2, {}, {}, [])
            shot = shoot(ctx, plan)
            cycles_ids, cycles_depth, _ = ctx["scene"].render_labels()
            out[temperature] = (shot["rgb"], shot["ids"], shot["depth"], shot["record"], cycles_ids, cycles_depth,
                                shot["parts"])
        with_wire = ctx["scene"].render()  # at 80 deg C, as last shot
        ctx["scene"].wires.objects[SPAN].hide_render = True
        without = ctx["scene"].render()
        ctx["scene"].wires.objects[SPAN].hide_render = False
        lowest = {t: _lowest_vertex(ctx, t) for t in (80.0, None)}
        yield ctx, out, lowest, (with_wire, without)
    finally:
        ctx["scene"].close()


def _lowest_vertex(ctx, temperature) -> float:
    scene = ctx["scene"]
    scene.wires.follow(temperature)
    ob = scene.wires.objects[SPAN]
    z = np.array([v.co.z for v in ob.data.vertices]) + ob.location.z
    return float(z.min())


def test_cycles_centre_hits_lie_on_the_rasterized_wire_and_the_labels_fill_the_gaps(frames):
    ctx, out, _, _ = frames
    iid = ctx["wires"].ids[SPAN]
    assert iid == 1  # no placement: the span is the first instance
    _, ids, depth, record, cycles_ids, cycles_depth, parts = out[None]
    hits, labelled = cycles_ids == iid, ids == iid
    width_px = DIAMETER * (W / 2 / math.tan(1.047 / 2)) / np.linalg.norm((P0 + P1) / 2 - EYE)
    assert width_px < 0.3
    assert hits.sum() >= 3 and (labelled & hits).sum() == hits.sum()  # Cycles' hits are on the raster
    assert labelled.sum() > 3 * hits.sum()  # a thin wire is hit by few pixel centres
    assert not parts[labelled].any()  # a wire is no part
    assert np.allclose(depth[hits], cycles_depth[hits], atol=DIAMETER)  # the same geometry, the same depth
    from scipy import ndimage

    assert ndimage.label(labelled, structure=np.ones((3, 3)))[1] == 1  # one unbroken line
    cols = np.flatnonzero(labelled.any(axis=0))
    assert cols.max() - cols.min() + 1 == len(cols) > 40  # across the view, no gap
    [ann] = [a for a in record["annotations"] if a["instance_id"] == iid]
    assert (ann["span"], ann["from"], ann["to"], ann["area"]) == (SPAN, "G-1.a", "G-2.b", int(labelled.sum()))
    assert record["conductors"] == {"temperature_c": 25.0, "temperature_from": "built scene", "spans": [
        {"instance_id": iid, "span": SPAN, "from": "G-1.a", "to": "G-2.b", "tags": [None, None],
         "pixels": int(labelled.sum())}]}


def test_the_wire_shows_in_the_picture_where_it_is_labelled(frames):
    """The same frame rendered without the wire differs on the wire's labelled pixels
    (almost all of them), and hardly elsewhere (the pixel filter's spread)."""
    ctx, out, _, (with_wire, without) = frames
    labelled = out[80.0][1] == ctx["wires"].ids[SPAN]
    change = np.abs(with_wire - without).sum(axis=-1)
    assert (change[labelled] > 0).mean() > 0.9
    assert change[labelled].sum() > 0.8 * change.sum()
    assert change[labelled].mean() > 100 * change[~labelled].mean()


def test_the_sag_follows_the_shots_conductor_temperature(frames):
    ctx, out, lowest, _ = frames
    span = ctx["wires"].wires.span(SPAN)
    w, t = span["weight_n_per_m"], TYPES["T"]
    hot = cat.change_of_state(P0, P1, w, t["ea_n"], t["alpha_per_k"], span["tension_n"], 25.0, 80.0)
    expected = {80.0: cat.lowest_point(cat.from_tension(P0, P1, hot, w))[2],
                None: cat.lowest_point(cat.from_tension(P0, P1, span["tension_n"], w))[2]}
    radius = DIAMETER / 2
    for temperature, z in expected.items():  # the mesh's lowest vertex: the curve's, a radius down
        assert lowest[temperature] == pytest.approx(z - radius, abs=2e-3)
    assert cat.sag(cat.from_tension(P0, P1, hot, w)) - cat.sag(cat.from_tension(P0, P1, span["tension_n"], w)) > 0.1
    iid = ctx["wires"].ids[SPAN]
    rows = {t: np.nonzero(out[t][1] == iid)[0].mean() for t in out}
    assert rows[80.0] > rows[None]  # lower on the image
    hot_record = out[80.0][3]["conductors"]
    assert (hot_record["temperature_c"], hot_record["temperature_from"]) == (80.0, "state")
