"""Runtime state graph: scenario loading errors, schedule, incremental steps, the
study's oil traces (PAPER_NOTES.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helpers import ROOT
from pipeline.errors import UserError
from pipeline.runtime import graph, nodes

OIL_LEAK = ROOT / "sources" / "scenarios" / "oil_leak.toml"

HEAD = """
[scenario]
name = "t"
seed = 7
duration_s = 10.0
step_s = 1.0
start = "2025-03-20T09:00:00-03:00"
"""


def node(id_, type_, period=None, **params):
    p = ", ".join(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in params.items())
    per = f"period_s = {period}\n" if period is not None else ""
    return f'\n[[nodes]]\nid = "{id_}"\ntype = "{type_}"\n{per}params = {{ {p} }}\n'


def edge(src, dst, unit="1", type_="float"):
    return f'\n[[edges]]\nfrom = "{src}"\nto = "{dst}"\ntype = "{type_}"\nunit = "{unit}"\n'


def load(tmp_path, body):
    f = tmp_path / "s.toml"
    f.write_text(HEAD + body)
    return graph.Graph(graph.load_scenario(f))


def run_oil_leak():
    g = graph.Graph(graph.load_scenario(OIL_LEAK))
    e = graph.Engine(g)
    return g, [(r, dict(e.values)) for r in e.run()]


def test_tank_level_is_the_study_trace_at_every_step():
    _, records = run_oil_leak()
    assert len(records) == 61
    for report, values in records:
        t_read = 5.0 * math.floor(report.t / 5.0)  # readings every 5 s, held in between
        expected = min(100, max(25, 100 - 1.0 * t_read)) * (1 + 0.001 * (35.0 - 25))
        assert values[("tank", "level")] == expected


def test_bushing_2_is_bushing_1_shifted_by_1_2_s_noise_included():
    g, records = run_oil_leak()
    b1 = g.nodes["bushing_1"]
    for report, values in records:
        assert values[("bushing_2", "level")] == b1.level_at(5.0 * math.floor(report.t / 5.0) + 1.2)
    # The same on a fine clock, where bushing 1 itself reaches t + 1.2 s.
    ctx = nodes.RunContext(seed=3, start=g.ctx.start, step_s=0.1)
    one = nodes.Bushing("b1", {"phi": 0.3}, ctx)
    two = nodes.Bushing("b2", {"phi": 0.3, "delay_s": 1.2, "noise_stream": "b1"}, ctx)
    for k in range(200):
        assert two.step(k * 0.1, {})["level"] == pytest.approx(one.step(k * 0.1 + 1.2, {})["level"], abs=1e-9)


def test_bushing_noise_is_bounded_and_reproducible_per_seed():
    start = graph.load_scenario(OIL_LEAK).start
    noisy = nodes.Bushing("b", {}, nodes.RunContext(1, start, 1.0))
    clean = nodes.Bushing("b", {"noise": 0.0}, nodes.RunContext(1, start, 1.0))
    times = np.arange(0.0, 300.0, 0.5)
    xi = np.array([noisy.level_at(t) - clean.level_at(t) for t in times])
    inside = np.array([30.0 < clean.level_at(t) < 100.0 for t in times])
    assert np.all(np.abs(xi) <= 2.0)
    assert xi[inside].std() > 0.8  # uniform on [-2, 2] has std 1.15: it is really there
    again = nodes.Bushing("b", {}, nodes.RunContext(1, start, 1.0))
    assert [again.level_at(t) for t in times] == [noisy.level_at(t) for t in times]
    other = nodes.Bushing("b", {}, nodes.RunContext(2, start, 1.0))
    assert [other.level_at(t) for t in times] != [noisy.level_at(t) for t in times]


def test_whole_run_is_reproducible_from_file_and_seed():
    a = [sorted(v.items()) for _, v in run_oil_leak()[1]]
    b = [sorted(v.items()) for _, v in run_oil_leak()[1]]
    assert a == b


def test_schedule_is_topological_and_sorted(tmp_path):
    body = (node("z", "constant", value=1.0) + node("a", "linear") + node("m", "linear") + node("b", "constant", value=2.0)
            + edge("z.value", "a.x") + edge("a.y", "m.x"))
    g = load(tmp_path, body)
    assert g.order == ["b", "z", "a", "m"]


def test_only_downstream_nodes_run_after_one_input_change(tmp_path):
    body = (node("ambient", "constant", value=35.0, unit="degC") + node("tank", "oil_tank", 5.0)
            + node("b1", "bushing", 5.0) + node("render", "render") + node("clock", "clock", 5.0)
            + node("zoom", "constant", value=45.0, unit="x") + node("cam", "camera")
            + edge("ambient.value", "tank.T_env", "degC") + edge("tank.level", "render.r1.oil_level_tank", "%")
            + edge("b1.level", "render.r1.oil_level_b1", "%") + edge("zoom.value", "cam.zoom", "x"))
    e = graph.Engine(load(tmp_path, body))
    assert e.step().count == 7  # t = 0: everything
    assert e.step().count == 0  # t = 1: nothing due, nothing changed
    e.set_value("ambient", 20.0)
    r = e.step()
    assert r.ran == ("ambient", "tank", "render")
    assert e.values[("tank", "level")] == pytest.approx(98.0 * (1 + 0.001 * (20.0 - 25.0)))
    e.set_value("zoom", 45.0)  # re-set to the same value: the camera runs, nothing below it
    assert e.step().ran == ("zoom",)
    e.step()
    assert e.step().count == 4  # t = 5: tank, b1, clock due; render sees changes


def test_camera_zoom_from_the_graph_and_rejected_outside_range(tmp_path):
    body = node("zoom", "constant", value=45.0, unit="x") + node("cam", "camera") + edge("zoom.value", "cam.zoom", "x")
    e = graph.Engine(load(tmp_path, body))
    e.step()
    assert e.values[("cam", "hfov")] == pytest.approx(1.047 / 45)
    e.set_value("zoom", 150.0)
    with pytest.raises(UserError, match="cam.*zoom 150"):
        e.step()
    with pytest.raises(UserError, match=r"nodes\[0\] cam.*zoom"):
        load(tmp_path, node("cam", "camera", zoom=0.5))


@pytest.mark.parametrize("body, message", [
    (node("a", "linear") + node("b", "linear") + node("c", "linear")
     + edge("a.y", "b.x") + edge("b.y", "c.x") + edge("c.y", "a.x"), r"cycle: a -> b -> c -> a"),
    (node("k", "constant", value=1, type="int") + node("a", "linear") + edge("k.value", "a.x", type_="int"),
     r"edges\[0\] k.value -> a.x: type mismatch: edge says int, target port is float"),
    (node("t", "oil_tank") + node("a", "linear") + edge("t.level", "a.x", "%"),
     r"edges\[0\] t.level -> a.x: unit mismatch: edge carries '%', a.x expects '1'"),
    (node("t", "oil_tank") + node("a", "linear", unit_in="%") + edge("t.level", "a.x", "degC"),
     r"unit mismatch: edge says 'degC', t.level gives '%'"),
    (node("t", "oil_tank") + node("a", "linear") + edge("t.levl", "a.x"), r"t.levl -> a.x: node t \(oil_tank\) has no output 'levl'"),
    (node("t", "oil_tank") + edge("t.level", "nowhere.x", "%"), r"t.level -> nowhere.x: unknown node 'nowhere'"),
    (node("t", "oil_tank") + node("c", "camera") + edge("t.level", "c.x", "%"), r"node c \(camera\) has no input 'x'"),
    (node("p", "constant", value=1.0) + node("q", "constant", value=2.0) + node("a", "linear")
     + edge("p.value", "a.x") + edge("q.value", "a.x"), r"edges\[1\] q.value -> a.x: input a.x is already fed by edges\[0\]"),
    (node("a", "linear"), r"node a: required input a.x is not fed"),
    (node("a", "warp_drive"), r"nodes\[0\] a: unknown node type 'warp_drive'"),
    (node("a", "oil_tank", 2.5), r"period_s 2.5 is not a whole multiple"),
    (node("a", "oil_tank", T_envv=3.0), r"unknown parameter\(s\) T_envv"),
])
def test_bad_graphs_raise_one_clear_error(tmp_path, body, message):
    with pytest.raises(UserError, match=message) as info:
        load(tmp_path, body)
    assert str(tmp_path / "s.toml") in str(info.value)


def test_schema_errors_name_the_key(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text(HEAD.replace('start = "2025-03-20T09:00:00-03:00"', 'start = "2025-03-20 09:00"') + node("a", "clock"))
    with pytest.raises(UserError, match="scenario.start"):
        graph.load_scenario(f)


def test_render_mapping_follows_the_binding():
    manifest = {"bindings": [
        {"variable": "oil", "effect": "rotate", "target": "ptr", "link": "base", "domain": [0, 100],
         "range": [0.0, 4.0], "axis": [0, 1, 0], "rest_pose": list(np.eye(4).reshape(16) + 0.0)},
        {"variable": "oil", "effect": "material", "target": "ptr", "link": "base", "domain": [0, 100],
         "materials": ["red", "white"], "thresholds": [25.0]},
    ]}
    ob = nodes.Observed("R1", "reactor", "asset", manifest)
    (vs,) = nodes.visual_states({"reactor": {"oil": 50.0}}, [ob])
    assert vs.material == "white"
    np.testing.assert_allclose(vs.transform[:3, :3], [[math.cos(2), 0, math.sin(2)], [0, 1, 0], [-math.sin(2), 0, math.cos(2)]])
    (vs,) = nodes.visual_states({"reactor": {"oil": 10.0}}, [ob])
    assert vs.material == "red"
    assert nodes.unbound_inputs(["reactor.oil", "reactor.oli", "other.oil"], [ob]) == ["other.oil", "reactor.oli"]


def test_visual_mapper_maps_only_what_changed():
    def gauge(target):
        return {"variable": "oil", "effect": "rotate", "target": target, "link": "base", "domain": [0, 100],
                "range": [0.0, 4.0], "axis": [0, 0, 1]}

    obs = [nodes.Observed(f"R{i}", f"reactor_{i}", "asset", {"bindings": [gauge("ptr")]}) for i in range(3)]
    mapper = nodes.VisualMapper(obs)
    values = {f"reactor_{i}": {"oil": 40.0 + i} for i in range(3)}
    first = mapper.states(values)
    assert mapper.mapped == 3
    values["reactor_1"] = {"oil": 90.0}
    second = mapper.states(values)
    assert mapper.mapped == 1
    assert second[0] is first[0] and second[2] is first[2]
    fresh = nodes.visual_states(values, obs)
    for a, b in zip(second, fresh):
        assert (a.tag, a.visual) == (b.tag, b.visual)
        np.testing.assert_array_equal(a.transform, b.transform)
    mapper.states(values)
    assert mapper.mapped == 0


def test_oil_leak_sun_is_at_the_sample_site_origin():
    site = ROOT / "sources" / "site.toml"
    if not site.is_file():
        pytest.skip("no sources/site.toml")
    from pipeline.config import read_toml

    origin = read_toml(site)["origin"]
    sun = graph.Graph(graph.load_scenario(OIL_LEAK)).nodes["sun"]
    assert (sun.lat, sun.lon) == (origin["lat"], origin["lon"])
