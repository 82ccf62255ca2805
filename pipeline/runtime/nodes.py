"""Node types of the runtime state graph (DESIGN.md s.6, PAPER_NOTES.md).

A node is a small class: it declares its ports (type and unit), takes its parameters
once, and maps (t, inputs) -> outputs deterministically. Its only randomness comes from
`self.rng` (seeded from the scenario seed and the node id) or from seeded functions of
time (`seeded_uniform`), so a run is reproducible from the scenario file and its seed.

Units are plain strings compared exactly ("%", "degC", "rad", "W/m2", "m", "s", "m3",
"x" for zoom, "1" for dimensionless); "*" on an input accepts any unit.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import math
import re
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from . import camera, thermal
from .. import sun


@dataclass(frozen=True)
class Port:
    type: str = "float"
    unit: str = "1"
    required: bool = True


@dataclass(frozen=True)
class RunContext:
    """What every node may know about the run besides its inputs."""

    seed: int
    start: dt.datetime  # aware instant of t = 0
    step_s: float
    zone: dt.tzinfo | None = None  # of local dates (the site's); None: start's own offset

    def local(self, t: float) -> dt.datetime:
        """The instant t s after the start, on the site's clock."""
        when = self.start + dt.timedelta(seconds=float(t))
        return when if self.zone is None else when.astimezone(self.zone)


def stable_hash(text: str) -> int:
    """A 64-bit integer of a string, identical on every platform and run (unlike hash())."""
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "little")


def node_rng(seed: int, node_id: str) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), stable_hash(node_id)])))


def seeded_uniform(seed: int, stream: str, t: float, low: float, high: float) -> float:
    """A uniform draw in [low, high) that is a pure function of (seed, stream, t).

    Counter-based (BLAKE2b of seed, stream and t in whole milliseconds; 53 bits make
    the double), so any node can evaluate the same noise at any time, e.g. a signal
    delayed by 1.2 s reproduces its source's noise exactly. Times closer than 1 ms
    share a draw. A hash, not a generator object per draw: this runs in every step.
    """
    counter = int(round(float(t) * 1000.0))
    digest = hashlib.blake2b(f"{int(seed)}|{stream}|{counter}".encode("utf-8"), digest_size=8).digest()
    u = (int.from_bytes(digest, "little") >> 11) * 2.0**-53
    return low + (high - low) * u


class Node:
    """Base class. Subclasses set `type_name`, `inputs`, `outputs`, `params` (name ->
    default; None = required) and implement `step`."""

    type_name: ClassVar[str] = ""
    inputs: ClassVar[dict[str, Port]] = {}
    outputs: ClassVar[dict[str, Port]] = {}
    params: ClassVar[dict[str, object]] = {}

    def __init__(self, node_id: str, params: dict, ctx: RunContext):
        unknown = sorted(set(params) - set(self.params))
        if unknown:
            raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for a {self.type_name} node "
                             f"(known: {', '.join(sorted(self.params)) or 'none'})")
        missing = sorted(k for k, v in self.params.items() if v is None and k not in params)
        if missing:
            raise ValueError(f"missing parameter(s) {', '.join(missing)} for a {self.type_name} node")
        self.id = node_id
        self.ctx = ctx
        self.p = {**self.params, **params}
        self.rng = node_rng(ctx.seed, node_id)

    # Port look-ups are methods so that a node may have instance-specific ports.
    def input_port(self, name: str) -> Port | None:
        return self.inputs.get(name)

    def input_names(self) -> list[str]:
        return sorted(self.inputs)

    def output_port(self, name: str) -> Port | None:
        return self.outputs.get(name)

    def output_ports(self) -> dict[str, Port]:
        return dict(self.outputs)

    def required_inputs(self) -> list[str]:
        return sorted(k for k, p in self.inputs.items() if p.required)

    def step(self, t: float, inputs: dict) -> dict:
        raise NotImplementedError


def _float(p: dict, key: str) -> float:
    v = p[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"parameter {key} must be a finite number, got {v!r}")
    return float(v)


class Clock(Node):
    """Scenario time: t in s since the start, and the UTC instant as Unix seconds."""

    type_name = "clock"
    outputs = {"t": Port("float", "s"), "epoch": Port("float", "s")}

    def step(self, t, inputs):
        return {"t": float(t), "epoch": self.ctx.start.timestamp() + float(t)}


class Constant(Node):
    """An externally settable value (an operator input, an ambient temperature)."""

    type_name = "constant"
    params = {"value": None, "unit": "1", "type": "float"}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        if self.p["type"] not in ("float", "int", "bool"):
            raise ValueError(f"type must be float, int or bool, got {self.p['type']!r}")
        self.value = self.p["value"]

    def output_port(self, name):
        return self.output_ports().get(name)

    def output_ports(self):
        return {"value": Port(self.p["type"], str(self.p["unit"]))}

    def step(self, t, inputs):
        return {"value": self.value}


class Linear(Node):
    """y = gain x + offset: a sensor calibration or unit conversion between nodes
    (e.g. gain 100 to turn a 0..1 fraction into %). Its input is required."""

    type_name = "linear"
    params = {"gain": 1.0, "offset": 0.0, "unit_in": "1", "unit_out": "1"}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        self.gain, self.offset = _float(self.p, "gain"), _float(self.p, "offset")

    def input_port(self, name):
        return Port("float", str(self.p["unit_in"])) if name == "x" else None

    def required_inputs(self):
        return ["x"]

    def input_names(self):
        return ["x"]

    def output_port(self, name):
        return self.output_ports().get(name)

    def output_ports(self):
        return {"y": Port("float", str(self.p["unit_out"]))}

    def step(self, t, inputs):
        return {"y": self.gain * float(inputs["x"]) + self.offset}


class OilTank(Node):
    """Main-tank oil of the shunt reactor.

    level: the study's trace min(hi, max(lo, l0 - rate t)) * (1 + k (T_env - T_ref)), %.
    volume: V0 (1 + beta (T_oil - T0)) - leak t, m3 (the study's volume model with a
    constant leak rate dV_loss(t) = leak_m3_s t). T_oil = T_env + oil_rise_K.
    T_env comes from the optional input `T_env` when wired, else from the parameter.
    """

    type_name = "oil_tank"
    inputs = {"T_env": Port("float", "degC", required=False)}
    outputs = {"level": Port("float", "%"), "volume": Port("float", "m3"), "T_oil": Port("float", "degC")}
    params = {"T_env": 35.0, "l0": 100.0, "rate_pct_s": 1.0, "lo": 25.0, "hi": 100.0, "k_T": 0.001,
              "T_ref": 25.0, "V0": 15.0, "beta": 7.0e-4, "T0": 20.0, "leak_m3_s": 0.0, "oil_rise_K": 0.0}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        self.c = {k: _float(self.p, k) for k in self.params}

    def level_at(self, t: float, t_env: float) -> float:
        c = self.c
        return min(c["hi"], max(c["lo"], c["l0"] - c["rate_pct_s"] * t)) * (1.0 + c["k_T"] * (t_env - c["T_ref"]))

    def step(self, t, inputs):
        c = self.c
        t_env = float(inputs.get("T_env", c["T_env"]))
        t_oil = t_env + c["oil_rise_K"]
        volume = c["V0"] * (1.0 + c["beta"] * (t_oil - c["T0"])) - c["leak_m3_s"] * t
        return {"level": self.level_at(t, t_env), "volume": volume, "T_oil": t_oil}


class Bushing(Node):
    """Oil level of a bushing's sight glass (%), the study's trace:

    i(t) = i0 + di sin(wi t), v(t) = v0 + dv cos(wv t),
    base(t) = 50 + 0.08 i(t) + 0.005 (v(t) - v0),
    level(t) = clip(base(t) + A sin(w t + phi) + xi(t), 30, 100), xi uniform [-2, 2].

    `delay_s` evaluates the whole trace, noise included, at t + delay_s: with the same
    `noise_stream` (default: the node id) bushing 2 = bushing 1 shifted by 1.2 s exactly.
    """

    type_name = "bushing"
    outputs = {"level": Port("float", "%")}
    params = {"phi": 0.0, "delay_s": 0.0, "noise": 2.0, "noise_stream": "", "amplitude": 25.0, "omega": 0.25,
              "i0": 200.0, "di": 50.0, "wi": 0.3, "v0": 13800.0, "dv": 500.0, "wv": 0.4, "lo": 30.0, "hi": 100.0}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        self.c = {k: _float(self.p, k) for k in self.params if k != "noise_stream"}
        self.stream = str(self.p["noise_stream"] or node_id)

    def level_at(self, t: float) -> float:
        """The trace at absolute scenario time t (no delay applied)."""
        c = self.c
        i = c["i0"] + c["di"] * math.sin(c["wi"] * t)
        v = c["v0"] + c["dv"] * math.cos(c["wv"] * t)
        base = 50.0 + 0.08 * i + 0.005 * (v - c["v0"])
        xi = seeded_uniform(self.ctx.seed, self.stream, t, -c["noise"], c["noise"]) if c["noise"] else 0.0
        return min(c["hi"], max(c["lo"], base + c["amplitude"] * math.sin(c["omega"] * t + c["phi"]) + xi))

    def step(self, t, inputs):
        return {"level": self.level_at(t + self.c["delay_s"])}


class Sun(Node):
    """Sun elevation/azimuth (rad) and direct horizontal irradiance (W/m2); see sun.py.

    model: "ephemeris" (astral NOAA, geometric unless refraction = true) or "study"
    (90 sin(pi tau), whose day is the local date in the site's time zone). Time is
    the scenario start plus t.
    """

    type_name = "sun"
    inputs = {"tau_atm": Port("float", "1", required=False)}  # the sky's turbidity, when wired or set
    outputs = {"elevation": Port("float", "rad"), "azimuth": Port("float", "rad"),
               "irradiance": Port("float", "W/m2")}
    params = {"lat": None, "lon": None, "model": "ephemeris", "refraction": False,
              "tau_atm": sun.DEFAULT_TAU_ATM, "G0": sun.G0}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        self.lat, self.lon = _float(self.p, "lat"), _float(self.p, "lon")
        if not -90.0 <= self.lat <= 90.0 or not -180.0 <= self.lon <= 180.0:
            raise ValueError(f"lat/lon out of range: {self.lat}, {self.lon}")
        if self.p["model"] not in ("ephemeris", "study"):
            raise ValueError(f"model must be 'ephemeris' or 'study', got {self.p['model']!r}")
        self.tau_atm, self.g0 = _float(self.p, "tau_atm"), _float(self.p, "G0")

    def step(self, t, inputs):
        when = self.ctx.local(t)
        elev, az = sun.ephemeris(self.lat, self.lon, when, bool(self.p["refraction"]))
        if self.p["model"] == "study":
            elev = sun.study_elevation(self.lat, self.lon, when)
        e = math.radians(elev)
        tau = float(inputs.get("tau_atm", self.tau_atm))
        return {"elevation": e, "azimuth": math.radians(az), "irradiance": sun.irradiance(e, tau, self.g0)}


class Camera(Node):
    """Zoom -> horizontal FOV and clip planes (camera.py). The zoom is the optional
    input `zoom` when wired, else the parameter; outside [1, 100] is an error."""

    type_name = "camera"
    inputs = {"zoom": Port("float", "x", required=False)}
    outputs = {"zoom": Port("float", "x"), "hfov": Port("float", "rad"), "near": Port("float", "m"),
               "far": Port("float", "m"), "optical": Port("bool", "1")}
    params = {"zoom": 1.0, "fov_base": camera.FOV_BASE}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        camera.lens(_float(self.p, "zoom"), _float(self.p, "fov_base"))  # reject a bad zoom at load

    def step(self, t, inputs):
        lens = camera.lens(inputs.get("zoom", self.p["zoom"]), float(self.p["fov_base"]))
        return {"zoom": lens.zoom, "hfov": lens.hfov, "near": lens.near, "far": lens.far, "optical": lens.optical}


_RENDER_PORT = re.compile(r"^([A-Za-z0-9_][A-Za-z0-9_-]*)\.([A-Za-z_][A-Za-z0-9_]*)$")


class Render(Node):
    """The render node: observes `<STATE>.<variable>` inputs (any unit) and keeps their
    latest values; `mapping.visual_states` turns them into transforms, materials and
    shape weights through the placements' manifest bindings. A placement whose floor
    plan STATE is "reactor_A1" is driven by edges to render.reactor_A1.<variable>.
    `sun` names the sun node the appliers light the scene with (default: the only one).
    """

    type_name = "render"
    params = {"sun": "", "sun_intensity_scale": 1.0}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        self.values: dict[str, dict[str, float]] = {}

    def input_port(self, name):
        return Port("float", "*") if _RENDER_PORT.match(name) else None

    def input_names(self):
        return ["<STATE>.<variable>"]

    def step(self, t, inputs):
        for name, value in inputs.items():
            state, variable = _RENDER_PORT.match(name).groups()
            self.values.setdefault(state, {})[variable] = float(value)
        return {}


class ConductorThermal(Node):
    """A conductor's steady-state temperature (degC) from its phase current (A, shared
    by the bundle's subconductors), IEEE 738 style (runtime.thermal). Ambient air,
    wind and irradiance come from their inputs when wired (irradiance from a sun
    node), else from the params. Feeding render.conductors.temperature makes every
    span's sag follow (runtime.apply_conductors)."""

    type_name = "conductor_thermal"
    inputs = {"current": Port("float", "A"), "ambient": Port("float", "degC", required=False),
              "wind": Port("float", "m/s", required=False), "irradiance": Port("float", "W/m2", required=False)}
    outputs = {"temperature": Port("float", "degC")}
    params = {"diameter_m": None, "r25_ohm_per_km": None, "r75_ohm_per_km": None, "bundle_count": 1,
              "ambient_c": 30.0, "wind_m_s": 0.6, "irradiance_w_m2": 0.0, "emissivity": 0.5, "absorptivity": 0.5,
              "elevation_m": 0.0}

    def __init__(self, node_id, params, ctx):
        super().__init__(node_id, params, ctx)
        for key in ("diameter_m", "r25_ohm_per_km", "r75_ohm_per_km", "ambient_c", "wind_m_s", "emissivity",
                    "absorptivity", "elevation_m", "irradiance_w_m2"):
            _float(self.p, key)
        if int(self.p["bundle_count"]) < 1:
            raise ValueError("bundle_count must be at least 1")

    def step(self, t, inputs):
        p = self.p
        return {"temperature": thermal.temperature(
            abs(float(inputs["current"])) / int(p["bundle_count"]), float(inputs.get("ambient", p["ambient_c"])),
            diameter_m=float(p["diameter_m"]), r25_ohm_per_km=float(p["r25_ohm_per_km"]),
            r75_ohm_per_km=float(p["r75_ohm_per_km"]), wind_m_s=float(inputs.get("wind", p["wind_m_s"])),
            irradiance_w_m2=float(inputs.get("irradiance", p["irradiance_w_m2"])), emissivity=float(p["emissivity"]),
            absorptivity=float(p["absorptivity"]), elevation_m=float(p["elevation_m"]))}


NODE_TYPES: dict[str, type[Node]] = {cls.type_name: cls for cls in (Clock, Constant, Linear, OilTank, Bushing, Sun, Camera,
                                                                    Render, ConductorThermal)}
CONDUCTORS_STATE = "conductors"  # render.conductors.temperature drives every span's sag


# --- the render node's mapping M_k ----------------------------------------------------


@dataclass(frozen=True)
class Observed:
    """A placement the render node drives: floor-plan TAG and STATE, its asset's
    manifest.json (as plain data) and package folder."""

    tag: str
    state: str
    asset: str
    manifest: dict
    package: object = None  # pathlib.Path of build/models/<asset>/ when known


@dataclass(frozen=True)
class BindingOutput:
    binding: dict  # the manifest's binding record
    value: float  # the state value (e.g. oil level in %)
    output: float | int  # M_k(value): angle, distance, factor, weight, or material index


@dataclass(frozen=True, eq=False)
class VisualState:
    """One bound visual at one instant.

    rest, transform: (4, 4) float64 in the link frame; transform = rest @ delta_1 @ ...
    in binding order (rotation about / translation along / scale along the binding axis,
    expressed in the visual's frame). material: the selected material, or None when no
    material binding drives this visual. shape_weights: shape key -> weight.
    """

    tag: str
    link: str
    visual: str
    rest: np.ndarray
    transform: np.ndarray
    material: str | None
    shape_weights: dict
    outputs: tuple[BindingOutput, ...]


def state_binding(record: dict):
    """ir.StateBinding of a manifest binding record."""
    from .. import ir

    return ir.StateBinding(
        variable=record["variable"], effect=record["effect"], target=record["target"],
        domain=tuple(record["domain"]), range=tuple(record.get("range") or (0.0, 1.0)),
        axis=tuple(record.get("axis") or (0.0, 0.0, 1.0)), shape_key=record.get("shape_key"),
        materials=tuple(record.get("materials") or ()), thresholds=tuple(record.get("thresholds") or ()))


@dataclass(frozen=True)
class _Compiled:
    """A manifest binding record, parsed once: the StateBinding, the visual's rest pose
    (4, 4), and for a rotation the cross-product matrix K of the unit axis and K @ K."""

    record: dict
    binding: object
    rest: np.ndarray
    k: np.ndarray
    k2: np.ndarray


_COMPILED: dict[int, _Compiled] = {}  # id(record) -> its parse (holding the record, so the id stays its own)


def _compiled(record: dict) -> _Compiled:
    """state_binding and friends, built once per manifest record: visual_states runs in
    every step."""
    hit = _COMPILED.get(id(record))
    if hit is None or hit.record is not record:
        b = state_binding(record)
        a = np.asarray(b.axis, dtype=np.float64)
        n = np.linalg.norm(a)
        a = a / n if n > 0 else np.array([0.0, 0.0, 1.0])
        k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        rest = np.array(record.get("rest_pose") or np.eye(4).reshape(16), dtype=np.float64).reshape(4, 4)
        hit = _COMPILED[id(record)] = _Compiled(record, b, rest, k, k @ k)
    return hit


_I3 = np.eye(3)


def delta_matrix(effect: str, axis, output: float) -> np.ndarray:
    """(4, 4) float64 change of a visual's pose for a rotate/translate/scale output."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    a = a / n if n > 0 else np.array([0.0, 0.0, 1.0])
    m = np.eye(4)
    if effect == "rotate":
        # Rodrigues: R = I + sin(x) K + (1 - cos(x)) K^2, K the cross-product matrix of a.
        k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        m[:3, :3] = np.eye(3) + math.sin(output) * k + (1.0 - math.cos(output)) * (k @ k)
    elif effect == "translate":
        m[:3, 3] = a * output
    elif effect == "scale":
        # Stretch along the axis only (an oil column grows in height, not in width).
        m[:3, :3] = np.eye(3) + (float(output) - 1.0) * np.outer(a, a)
    return m


def visual_states(values: dict[str, dict[str, float]], observed: list[Observed]) -> list[VisualState]:
    """Map the render node's values through every observed placement's bindings.

    values: STATE -> variable -> value. Visuals whose variables are not fed are left
    out (they keep their rest look). Sorted by (tag, link, visual).
    """
    return VisualMapper(observed).states(values)


class VisualMapper:
    """`visual_states` for a run: the bindings are grouped per visual once, and a
    visual whose fed values did not change since the last call keeps its state, so
    a step that moves one gauge maps one gauge (DESIGN.md s.6: only the affected
    subgraph is recomputed, the render node's mapping included)."""

    def __init__(self, observed: list[Observed]):
        self.groups = []  # (observed, link, visual, records), sorted by (tag, link, visual)
        for ob in sorted(observed, key=lambda o: o.tag):
            by_visual: dict[tuple[str, str], list[dict]] = {}
            for rec in ob.manifest.get("bindings", []):
                if rec.get("link"):
                    by_visual.setdefault((rec["link"], rec["target"]), []).append(rec)
            self.groups += [(ob, link, visual, recs) for (link, visual), recs in sorted(by_visual.items())]
        self._last: dict[int, tuple[tuple, VisualState]] = {}  # group index -> (inputs, state)
        self.mapped = 0  # visuals mapped anew by the last call

    def states(self, values: dict[str, dict[str, float]]) -> list[VisualState]:
        out, self.mapped = [], 0
        for i, (ob, link, visual, recs) in enumerate(self.groups):
            fed = values.get(ob.state, {})
            recs = [r for r in recs if r["variable"] in fed]
            if not recs:
                continue
            inputs = tuple((r["variable"], fed[r["variable"]]) for r in recs)
            last = self._last.get(i)
            if last is None or last[0] != inputs:
                last = self._last[i] = (inputs, _map_visual(ob.tag, link, visual, recs, fed))
                self.mapped += 1
            out.append(last[1])
        return out


def _map_visual(tag: str, link: str, visual: str, recs: list[dict], fed: dict[str, float]) -> VisualState:
    rest = _compiled(recs[0]).rest
    m, material, weights, outs = rest.copy(), None, {}, []
    for rec in recs:
        c = _compiled(rec)
        b = c.binding
        value = fed[b.variable]
        y = b.output(value)
        outs.append(BindingOutput(rec, value, y))
        if b.effect == "material":
            material = b.materials[y] if b.materials else None
        elif b.effect == "shape":
            weights[b.shape_key or ""] = float(y)
        elif b.effect == "rotate":  # delta_matrix's Rodrigues, with K precomputed
            m[:3, :3] = m[:3, :3] @ (_I3 + math.sin(y) * c.k + (1.0 - math.cos(y)) * c.k2)
        else:
            m = m @ delta_matrix(b.effect, b.axis, float(y))
    return VisualState(tag, link, visual, rest, m, material, weights, tuple(outs))


def unbound_inputs(values_ports: list[str], observed: list[Observed]) -> list[str]:
    """Render inputs `STATE.variable` that no observed placement binds (likely typos)."""
    bound = {(o.state, r["variable"]) for o in observed for r in o.manifest.get("bindings", [])}
    bad = []
    for port in values_ports:
        m = _RENDER_PORT.match(port)
        if m and (m.group(1), m.group(2)) == (CONDUCTORS_STATE, "temperature"):
            continue  # the spans' temperature, not a placement's binding
        if m and (m.group(1), m.group(2)) not in bound:
            bad.append(port)
    return sorted(bad)
