"""The scenario `twin serve` runs without one: the clock, the sun over the site (its
turbidity and the sky's aerosol settable), the camera's zoom, every bound state of the
built scene (render.<STATE>.<variable>, held at its domain's top: full gauges), every
switch (switch_<TAG>, closed) and, with conductors built, each conductor type's load
current and the air's temperature (live.wires) as settable inputs."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from .. import sun as sun_model
from ..runtime import graph
from ..runtime.site import BuiltSite
from .wires import scenario_part

DEFAULT_AEROSOL = 1.0  # Blender's sky default: the dataset samples around it


def switch_node(tag: str) -> str:
    """The node id of a switch's open/closed input (node ids are identifiers)."""
    return "switch_" + "".join(c if c.isalnum() or c == "_" else "_" for c in tag)


def switchgear(site: BuiltSite) -> list[str]:
    """Tags of the placements a `twin dataset` opens and closes (revolute joints,
    category switchgear), sorted."""
    out = []
    for p in site.placements:
        m = site.manifests.get(p["asset"], {})
        if m.get("category") == "switchgear" and any(j["type"] == "revolute" for j in m.get("joints", [])):
            out.append(p["tag"])
    return sorted(out)


def default_scenario(site: BuiltSite, start: dt.datetime, step_s: float = 1.0, seed: int = 0,
                     wires: dict | None = None) -> graph.Scenario:
    """`wires`: the build's conductors.json (live.wires.load_record), or None."""
    lat, lon = site.origin[0], site.origin[1]
    nodes = [
        {"id": "clock", "type": "clock", "period_s": step_s},
        {"id": "sun", "type": "sun", "period_s": step_s,
         "params": {"lat": lat, "lon": lon, "model": "ephemeris", "tau_atm": sun_model.DEFAULT_TAU_ATM}},
        {"id": "tau_atm", "type": "constant", "params": {"value": sun_model.DEFAULT_TAU_ATM, "unit": "1"}},
        {"id": "aerosol", "type": "constant", "params": {"value": DEFAULT_AEROSOL, "unit": "1"}},
        {"id": "camera", "type": "camera", "params": {"zoom": 1.0}},
        {"id": "render", "type": "render", "params": {"sun": "sun"}},
    ]
    nodes += [{"id": switch_node(t), "type": "constant", "params": {"value": False, "type": "bool", "unit": "1"}}
              for t in switchgear(site)]
    edges = [{"from": "tau_atm.value", "to": "sun.tau_atm", "type": "float", "unit": "1"}]
    if wires is not None:
        more_nodes, more_edges = scenario_part(wires, "sun", "render", site.origin[2])
        nodes += more_nodes
        edges += more_edges
    return graph.Scenario(path=Path(site.build) / "scene" / "placements.json", name="live", seed=seed,
                          duration_s=0.0, step_s=step_s, start=start.astimezone(dt.timezone.utc), assets=[],
                          nodes=nodes, edges=edges, description="the built scene's states, settable", zone=site.zone)
