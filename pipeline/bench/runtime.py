"""Runtime benchmarks for `twin bench` (DESIGN.md s.8: speed beside error; not tests).

bench_runtime() -> dict with, each as {median_s, min_s, max_s, repeats}:
- sample_full_step / sample_incremental_step: the sample scene's stateful objects
  (6 reactors x (tank + 2 bushings) + 3 transformer tanks, sun, camera, clock, render
  with the gauges and lamps mapped through their bindings); the incremental step
  follows one ambient-temperature change feeding one reactor's tank;
- graph_<n>: full and incremental step of synthetic graphs of n = 100 / 1,000 /
  10,000 linear nodes (chains of 10 below constants; one constant changed);
- usd_apply_state: one state (every bound visual of the sample: rotation, blend weight,
  variant token, plus the sun) written into an Sdf layer;
- sun: elevation error over a year at the site (hourly every 5th day, daytime; the
  study model's days are local dates in the site's time zone): the study's 90 sin(pi
  tau) model vs astral, astral vs pvlib SPA when pvlib is installed; with the cost of
  one evaluation of each model.
"""

from __future__ import annotations

import datetime as dt
import math
import statistics
import time
from pathlib import Path

import numpy as np

from ..runtime import graph, nodes
from .. import sun

LAT, LON = -12.7, -38.3  # the sun node of the sample graph (its cost does not depend on where)
START = dt.datetime(2025, 3, 20, 12, 0, tzinfo=dt.timezone.utc)


def _timed(fn, repeats: int, setup=None) -> dict:
    times = []
    for _ in range(repeats):
        arg = setup() if setup else None
        t0 = time.perf_counter()
        fn(arg) if setup else fn()
        times.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times), "repeats": repeats}


def _scenario(node_specs, edges, period=1.0) -> graph.Scenario:
    return graph.Scenario(path=Path("<bench>"), name="bench", seed=1, duration_s=3600.0, step_s=1.0, start=START,
                          assets=[], nodes=node_specs, edges=edges)


def _edge(a, b, unit):
    return {"from": a, "to": b, "type": "float", "unit": unit}


def sample_graph(period: float = 5.0) -> tuple[graph.Scenario, list[nodes.Observed]]:
    specs = [{"id": "clock", "type": "clock", "period_s": 1.0},
             {"id": "sun", "type": "sun", "period_s": 1.0, "params": {"lat": LAT, "lon": LON}},
             {"id": "camera", "type": "camera", "params": {"zoom": 45.0}},
             {"id": "render", "type": "render", "params": {}},
             {"id": "ambient", "type": "constant", "params": {"value": 35.0, "unit": "degC"}}]
    edges, observed = [], []
    gauge = {"variable": "oil_level_tank", "effect": "rotate", "target": "pointer", "link": "body",
             "domain": [0, 100], "range": [-2.4, 2.4], "axis": [0, -1, 0], "rest_pose": list(np.eye(4).reshape(16))}
    lamp = {"variable": "oil_level_tank", "effect": "material", "target": "lamp", "link": "body", "domain": [0, 100],
            "materials": ["lamp_red", "lamp_off"], "thresholds": [30.0]}
    glass = [{"variable": f"oil_level_b{i}", "effect": "shape", "target": f"glass_{i}", "link": "body",
              "domain": [0, 100], "range": [0, 1], "shape_key": "full"} for i in (1, 2)]
    for r in range(6):
        s = f"reactor_{r}"
        specs += [{"id": f"{s}_tank", "type": "oil_tank", "period_s": period},
                  {"id": f"{s}_b1", "type": "bushing", "period_s": period, "params": {"phi": 0.5}},
                  {"id": f"{s}_b2", "type": "bushing", "period_s": period,
                   "params": {"phi": 0.5, "delay_s": 1.2, "noise_stream": f"{s}_b1"}}]
        edges += [_edge(f"{s}_tank.level", f"render.{s}.oil_level_tank", "%"),
                  _edge(f"{s}_b1.level", f"render.{s}.oil_level_b1", "%"),
                  _edge(f"{s}_b2.level", f"render.{s}.oil_level_b2", "%")]
        observed.append(nodes.Observed(s, s, "shunt_reactor", {"bindings": [gauge, lamp, *glass]}))
    edges.append(_edge("ambient.value", "reactor_0_tank.T_env", "degC"))
    for t in range(3):
        s = f"transformer_{t}"
        specs.append({"id": f"{s}_tank", "type": "oil_tank", "period_s": period})
        edges.append(_edge(f"{s}_tank.level", f"render.{s}.oil_level_tank", "%"))
        observed.append(nodes.Observed(s, s, "power_transformer", {"bindings": [gauge]}))
    return _scenario(specs, edges), observed


def synthetic_graph(n: int, period: float = 1.0) -> graph.Scenario:
    """n nodes: n/10 constants, each heading a chain of 9 linear nodes."""
    specs, edges = [], []
    for c in range(n // 10):
        specs.append({"id": f"c{c}", "type": "constant", "params": {"value": float(c)}, "period_s": period})
        prev = f"c{c}.value"
        for j in range(9):
            nid = f"n{c}_{j}"
            specs.append({"id": nid, "type": "linear", "params": {"gain": 1.01}, "period_s": period})
            edges.append(_edge(prev, f"{nid}.x", "1"))
            prev = f"{nid}.y"
    return _scenario(specs, edges)


def _bench_sample(repeats: int) -> dict:
    scen, observed = sample_graph(period=1.0)
    full = graph.Engine(graph.Graph(scen))

    def full_step():  # every node runs and every bound visual is mapped
        full.step()
        nodes.visual_states(full.graph.nodes["render"].values, observed)

    scen5, _ = sample_graph(period=5.0)
    inc = graph.Engine(graph.Graph(scen5))
    inc.step()
    mapper = nodes.VisualMapper(observed)
    mapper.states(inc.graph.nodes["render"].values)
    counts = []

    def setup():
        while (inc.k + 1) % 5 == 0:  # keep the periodic nodes out of the measurement
            inc.step()
        inc.set_value("ambient", 20.0 + inc.k % 10)

    def inc_step(_):  # the nodes downstream of the change run; their visuals are mapped
        counts.append(inc.step().count)
        mapper.states(inc.graph.nodes["render"].values)

    return {"nodes": len(scen.nodes), "edges": len(scen.edges),
            "sample_full_step": {**_timed(full_step, repeats), "nodes_run": len(full.graph.nodes)},
            "sample_incremental_step": {**_timed(inc_step, repeats, setup), "nodes_run": statistics.median(counts)}}


def _bench_sizes(sizes, repeats: int) -> dict:
    out = {}
    for n in sizes:
        e = graph.Engine(graph.Graph(synthetic_graph(n)))
        e.step()
        full = _timed(e.step, max(3, repeats // (n // 100 or 1)))
        # Incremental: the same graph with no periods; one constant changes.
        scen = synthetic_graph(n)
        for s in scen.nodes:
            s.pop("period_s")
        inc = graph.Engine(graph.Graph(scen))
        inc.step()
        counts = []
        timing = _timed(lambda _: counts.append(inc.step().count), repeats,
                        lambda: inc.set_value("c0", float(inc.k)))
        out[f"graph_{n}"] = {"full_step": full, "incremental_step": {**timing, "nodes_run": statistics.median(counts)}}
    return out


def _bench_usd(repeats: int) -> dict:
    try:
        from pxr import Gf, Sdf, Vt
    except ImportError:
        return {"skipped": "usd-core not installed"}
    layer = Sdf.Layer.CreateAnonymous(".usda")
    attrs = []
    for r in range(9):
        base = Sdf.Path(f"/Site/Placements/R{r}/body")
        for vis, name, typ in (("pointer", "xformOp:orient:twin", Sdf.ValueTypeNames.Quatd),
                               ("glass_1/skel/anim", "blendShapeWeights", Sdf.ValueTypeNames.FloatArray),
                               ("glass_2/skel/anim", "blendShapeWeights", Sdf.ValueTypeNames.FloatArray)):
            prim = Sdf.CreatePrimInLayer(layer, base.AppendPath(vis))
            attrs.append((Sdf.AttributeSpec(prim, name, typ), typ))
        prim = Sdf.CreatePrimInLayer(layer, Sdf.Path(f"/Site/Placements/R{r}"))
        attrs.append((Sdf.AttributeSpec(prim, "twin:state_oil_level_tank", Sdf.ValueTypeNames.Token), Sdf.ValueTypeNames.Token))
    sun_prim = Sdf.CreatePrimInLayer(layer, Sdf.Path("/Site/Sun"))
    attrs.append((Sdf.AttributeSpec(sun_prim, "xformOp:orient", Sdf.ValueTypeNames.Quatd), Sdf.ValueTypeNames.Quatd))
    attrs.append((Sdf.AttributeSpec(sun_prim, "inputs:intensity", Sdf.ValueTypeNames.Float), Sdf.ValueTypeNames.Float))
    k = [0]

    def apply_state():
        k[0] += 1
        t = float(k[0])
        with Sdf.ChangeBlock():
            for spec, typ in attrs:
                if typ == Sdf.ValueTypeNames.Quatd:
                    v = Gf.Quatd(math.cos(t * 1e-3), 0, -math.sin(t * 1e-3), 0)
                elif typ == Sdf.ValueTypeNames.FloatArray:
                    v = Vt.FloatArray([t % 1.0])
                elif typ == Sdf.ValueTypeNames.Token:
                    v = "s1"
                else:
                    v = 700.0 + t
                layer.SetTimeSample(spec.path, t, v)

    return {"usd_apply_state": {**_timed(apply_state, repeats), "attributes": len(attrs)}}


def _bench_sun(repeats: int, lat: float, lon: float, zone: dt.tzinfo) -> dict:
    utc = dt.timezone.utc
    times = [dt.datetime(2025, 1, 1, tzinfo=utc) + dt.timedelta(days=d, hours=h) for d in range(0, 365, 5) for h in range(24)]
    eph = np.array([sun.ephemeris(lat, lon, t)[0] for t in times])
    local = [t.astimezone(zone) for t in times]
    study = np.array([sun.study_elevation(lat, lon, t) for t in local])
    day = eph > 0
    diff = np.abs(study - eph)[day]
    out = {"samples": int(day.sum()),
           "study_vs_astral_deg": {"max": float(diff.max()), "mean": float(diff.mean()),
                                   "p95": float(np.percentile(diff, 95))},
           "astral_eval": _timed(lambda: sun.ephemeris(lat, lon, times[100]), repeats),
           "study_eval": _timed(lambda: sun.study_elevation(lat, lon, local[100]), repeats)}
    try:
        import pandas as pd
        import pvlib
    except ImportError:
        out["astral_vs_spa_deg"] = {"skipped": "pvlib not installed"}
        return out
    idx = pd.DatetimeIndex(times)
    spa = pvlib.solarposition.spa_python(idx, lat, lon)["elevation"].to_numpy()
    d = np.abs(eph - spa)[spa > 0]
    ds = np.abs(study - spa)[spa > 0]
    out["astral_vs_spa_deg"] = {"max": float(d.max()), "mean": float(d.mean()), "p95": float(np.percentile(d, 95))}
    out["study_vs_spa_deg"] = {"max": float(ds.max()), "mean": float(ds.mean())}
    out["spa_eval"] = _timed(lambda: pvlib.solarposition.spa_python(idx[100:101], lat, lon), max(3, repeats // 10))
    return out


def bench_runtime(site: tuple[float, float, dt.tzinfo], repeats: int = 30, sizes=(100, 1_000, 10_000)) -> dict:
    """site: latitude, longitude and time zone of the sun bench."""
    return {"sample": _bench_sample(repeats), "graphs": _bench_sizes(sizes, repeats),
            "usd": _bench_usd(repeats), "sun": _bench_sun(repeats, *site)}
