"""The wires in the live twin.

Each conductor type strung in the built scene (build/scene/conductors.json) is a group
whose temperature is the render input `render.conductors_<TYPE>.temperature`. It is fed
by a `conductor_thermal` node, `thermal_<TYPE>`, whose current is the settable constant
`load_<TYPE>` (A rms, the phase current the bundle shares) when conductors.toml gives
the type's AC resistances, else by the settable constant `temperature_<TYPE>` (degC).
The air is the constant `ambient` (degC, the built scene's conductor temperature at
the start) and the sun the sun node's irradiance. A `set` of the render input itself
holds the temperature over the thermal node (None lets it go).

Every span of a group takes its group's temperature through the change-of-state
equation from the tension and temperature conductors.json records (as `twin run` does,
runtime.apply_conductors); before its group has a temperature a span is as built.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..geometry import catenary as cat
from ..runtime.nodes import CONDUCTORS_STATE

GROUP_PREFIX = "conductors_"


def group_state(type_name: str) -> str:
    """The render node's state of a conductor type (type names are identifiers)."""
    return GROUP_PREFIX + type_name


def load_record(build: Path) -> dict | None:
    """build/scene/conductors.json, or None for a scene without conductors."""
    path = Path(build) / "scene" / "conductors.json"
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    return record if record.get("spans") else None


def scenario_part(record: dict, sun_id: str | None, render_id: str, elevation_m: float) -> tuple[list, list]:
    """The nodes and edges that drive each group's temperature (see the module's doc)."""
    types = record["types"]
    nodes = [{"id": "ambient", "type": "constant", "params": {"value": float(record["temperature_c"]), "unit": "degC"}}]
    edges = []
    for name in sorted({s["type"] for s in record["spans"]}):
        t, to_render = types[name], f"{render_id}.{group_state(name)}.temperature"
        if "r25_ohm_per_km" not in t:
            nodes.append({"id": f"temperature_{name}", "type": "constant",
                          "params": {"value": float(record["temperature_c"]), "unit": "degC"}})
            edges.append(_edge(f"temperature_{name}.value", to_render, "degC"))
            continue
        thermal = f"thermal_{name}"
        nodes += [{"id": f"load_{name}", "type": "constant", "params": {"value": 0.0, "unit": "A"}},
                  {"id": thermal, "type": "conductor_thermal", "params": {
                      "diameter_m": t["diameter_m"], "r25_ohm_per_km": t["r25_ohm_per_km"],
                      "r75_ohm_per_km": t["r75_ohm_per_km"], "bundle_count": t["bundle_count"],
                      "elevation_m": float(elevation_m)}}]
        edges += [_edge(f"load_{name}.value", f"{thermal}.current", "A"),
                  _edge("ambient.value", f"{thermal}.ambient", "degC"),
                  _edge(f"{thermal}.temperature", to_render, "degC")]
        if sun_id is not None:
            edges.append(_edge(f"{sun_id}.irradiance", f"{thermal}.irradiance", "W/m2"))
    return nodes, edges


def _edge(src: str, dst: str, unit: str) -> dict:
    return {"from": src, "to": dst, "type": "float", "unit": unit}


class LiveWires:
    """The spans of conductors.json, their sag and polyline at their group's temperature."""

    def __init__(self, record: dict):
        self.types, self.spans = record["types"], record["spans"]
        self.groups: dict[str, list[dict]] = {}
        for s in self.spans:
            self.groups.setdefault(s["type"], []).append(s)
        self._tensions: dict[tuple[str, float | None], dict[str, float]] = {}
        self._published: dict[str, float | None] = {}

    def temperatures(self, render_values: dict) -> dict[str, float | None]:
        """Each group's temperature now (None: not yet set, the spans are as built): its
        own render input, else render.conductors.temperature (every span's)."""
        every = render_values.get(CONDUCTORS_STATE, {}).get("temperature")  # a scenario's, as `twin run` reads it
        return {name: render_values.get(group_state(name), {}).get("temperature", every)
                for name in sorted(self.groups)}

    def _tension(self, span: dict, temperature_c: float | None) -> float:
        t = self.types[span["type"]]
        if temperature_c is None:
            return span["tension_n"]
        return cat.change_of_state(np.array(span["from"]["enu"]), np.array(span["to"]["enu"]), span["weight_n_per_m"],
                                   t["ea_n"] * t["bundle_count"], t["alpha_per_k"], span["tension_n"],
                                   span["temperature_c"], float(temperature_c))

    def tensions(self, name: str, temperature_c: float | None) -> dict[str, float]:
        """span id -> horizontal tension (N) of the group's spans at `temperature_c`."""
        key = (name, temperature_c)
        if key not in self._tensions:
            if len(self._tensions) > 64:  # a temperature that follows the sun changes every step
                self._tensions.clear()
            self._tensions[key] = {s["id"]: self._tension(s, temperature_c) for s in self.groups[name]}
        return self._tensions[key]

    def curve(self, span: dict, temperature_c: float | None) -> cat.Catenary:
        H = self.tensions(span["type"], temperature_c)[span["id"]]
        return cat.from_tension(np.array(span["from"]["enu"]), np.array(span["to"]["enu"]), H, span["weight_n_per_m"])

    def sags(self, name: str, temperature_c: float | None) -> dict[str, float]:
        """span id -> sag (m, to the micrometre) of the group's spans at `temperature_c`."""
        return {s["id"]: round(cat.sag(self.curve(s, temperature_c)), 6) for s in self.groups[name]}

    def group_state(self, name: str, temperature_c: float | None) -> dict:
        sags = self.sags(name, temperature_c)
        return {"temperature_c": temperature_c, "largest_sag_m": max(sags.values()), "sag_m": sags}

    def state(self, render_values: dict) -> dict:
        """Every group: its temperature, its largest sag and each span's sag."""
        return {name: self.group_state(name, temp) for name, temp in self.temperatures(render_values).items()}

    def changes(self, render_values: dict) -> dict:
        """The groups whose temperature differs from the one last published (all, first)."""
        out = {}
        for name, temp in self.temperatures(render_values).items():
            if name not in self._published or self._published[name] != temp:
                self._published[name] = temp
                out[name] = self.group_state(name, temp)
        return out

    def polyline(self, span: dict, temperature_c: float | None) -> np.ndarray:
        """The bundle centre's polyline (ENU) with the segment count of the span's LOD."""
        return cat.points(self.curve(span, temperature_c), span["lods"][span["lod"]]["segments"])
