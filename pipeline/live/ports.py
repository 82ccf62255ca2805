"""Every port of the live twin's graph, with its type, unit and range, and the checks a
value set from outside passes, as an edge's would: the type of the port, its unit (a
value may say its unit: {"value": 40, "unit": "%"}), its range."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..runtime import camera as camera_model
from ..runtime.graph import Graph
from ..runtime.nodes import Observed

SKY_RANGE = (0.0, 10.0)  # turbidity and Blender's aerosol density: both meaningful in [0, 10]
SWITCH_WORDS = {"open": True, "closed": False}


@dataclass(frozen=True)
class PortSpec:
    name: str  # "node.port"
    node: str
    port: str
    kind: str  # "output" | "input"
    type: str  # float | int | bool
    unit: str
    settable: bool
    range: tuple[float, float] | None = None

    def describe(self) -> dict:
        out = {"name": self.name, "kind": self.kind, "type": self.type, "unit": self.unit, "settable": self.settable}
        if self.range is not None:
            out["range"] = list(self.range)
        return out


def bound_variables(observed: list[Observed]) -> dict[str, tuple[float, float]]:
    """"<STATE>.<variable>" -> the domain its bindings map (the union over placements)."""
    out: dict[str, tuple[float, float]] = {}
    for ob in observed:
        for rec in ob.manifest.get("bindings", []):
            lo, hi = (float(v) for v in rec["domain"])
            key = f"{ob.state}.{rec['variable']}"
            old = out.get(key)
            out[key] = (min(lo, hi), max(lo, hi)) if old is None else (min(old[0], lo, hi), max(old[1], lo, hi))
    return out


def _binding_unit(domain: tuple[float, float]) -> str:
    # Manifests record a binding's domain, not its unit: a 0-100 domain is a percentage
    # (every bound variable of the sample is an oil level in %).
    return "%" if domain == (0.0, 100.0) else "1"


def port_table(g: Graph, observed: list[Observed]) -> dict[str, PortSpec]:
    """All ports, sorted by name: every node's outputs (a constant's settable), every
    declared input (settable: held from outside over its edge or default), and the
    render node's bound inputs <STATE>.<variable> with their bindings' domain."""
    fed = {e.dst: e for e in g.edges}
    bound = bound_variables(observed)
    specs: dict[str, PortSpec] = {}
    for node_id in g.order:
        node = g.nodes[node_id]
        if node.type_name == "render":
            names = sorted(set(bound) | {e.dst[1] for e in g.feeds[node_id]})
            for port in names:
                domain = bound.get(port)
                edge = fed.get((node_id, port))
                unit = edge.unit if edge is not None else _binding_unit(domain) if domain else "*"
                specs[f"{node_id}.{port}"] = PortSpec(f"{node_id}.{port}", node_id, port, "input", "float", unit,
                                                      True, domain)
            continue
        for port in node.input_names():
            p = node.input_port(port)
            rng = camera_model_range() if node.type_name == "camera" and port == "zoom" else \
                SKY_RANGE if port == "tau_atm" else None
            specs[f"{node_id}.{port}"] = PortSpec(f"{node_id}.{port}", node_id, port, "input", p.type, p.unit, True, rng)
        for port, p in sorted(node.output_ports().items()):
            specs[f"{node_id}.{port}"] = PortSpec(f"{node_id}.{port}", node_id, port, "output", p.type, p.unit,
                                                  node.type_name == "constant")
    # A constant takes the range of what it feeds (an oil level's domain, the sky's).
    for node_id, node in g.nodes.items():
        if node.type_name != "constant":
            continue
        ranges = [specs[f"{e.dst[0]}.{e.dst[1]}"].range for e in g.consumers[node_id]]
        ranges = [r for r in ranges if r is not None] or ([SKY_RANGE] if node_id == "aerosol" else [])
        if ranges:
            rng = (max(r[0] for r in ranges), min(r[1] for r in ranges))
            name = f"{node_id}.value"
            specs[name] = PortSpec(**{**specs[name].__dict__, "range": rng})
    return dict(sorted(specs.items()))


def camera_model_range() -> tuple[float, float]:
    return (camera_model.ZOOM_MIN, camera_model.ZOOM_MAX)


def check_value(spec: PortSpec, raw, switch: bool = False):
    """The value a `set` gives `spec`, typed; ValueError naming the port and the fault."""
    value, unit = raw, None
    if isinstance(raw, dict):
        extra = sorted(set(raw) - {"value", "unit"})
        if "value" not in raw or extra:
            raise ValueError(f"{spec.name}: give a value or {{\"value\": ..., \"unit\": ...}}"
                             + (f" (unknown key {', '.join(extra)})" if extra else ""))
        value, unit = raw["value"], raw.get("unit")
    if unit is not None and spec.unit != "*" and unit != spec.unit:
        raise ValueError(f"{spec.name}: unit mismatch: the value is in {unit!r}, the port takes {spec.unit!r}")
    if spec.type == "bool":
        if switch and isinstance(value, str) and value in SWITCH_WORDS:
            return SWITCH_WORDS[value]
        if not isinstance(value, bool):
            words = " or \"open\"/\"closed\"" if switch else ""
            raise ValueError(f"{spec.name}: expected a bool{words}, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{spec.name}: expected a {spec.type} in {spec.unit}, got {value!r}")
    if spec.type == "int":
        if not float(value).is_integer():
            raise ValueError(f"{spec.name}: expected an int, got {value!r}")
        value = int(value)
    else:
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"{spec.name}: expected a finite float, got {value!r}")
    if spec.range is not None and not spec.range[0] <= value <= spec.range[1]:
        raise ValueError(f"{spec.name}: {value!r} is out of range [{spec.range[0]:g}, {spec.range[1]:g}] {spec.unit}")
    return value
