"""The live twin's state: the scenario's graph stepped to the clock, the ports a client
gets and sets, the camera, and the frame plan a render request hands the Blender process.
No sockets here: server.py drives it."""

from __future__ import annotations

import datetime as dt
import math

from .. import sun as sun_model
from ..datasets.plan import FramePlan, visible_tags
from ..render.sensor import frame_seed
from ..render.frames import shot_key
from ..runtime import graph
from ..runtime.nodes import Observed, VisualMapper
from ..runtime.site import BuiltSite, Shot
from .camera import LiveCamera
from .default_scenario import DEFAULT_AEROSOL, switch_node, switchgear
from .ports import PortSpec, check_value, port_table
from .wires import LiveWires, load_record

MAX_CATCH_UP = 1000  # steps run one by one when the clock is ahead; further, the graph jumps


def observed_placements(site: BuiltSite) -> list[Observed]:
    """Placements whose manifest binds state, keyed by STATE (or by TAG without one), as
    `twin dataset` drives them."""
    return [Observed(p["tag"], p.get("state") or p["tag"], p["asset"], site.manifests[p["asset"]])
            for p in site.placements if site.manifests.get(p["asset"], {}).get("bindings")]


class LiveTwin:
    def __init__(self, scenario: graph.Scenario, site: BuiltSite, camera: LiveCamera):
        self.scenario, self.site, self.camera = scenario, site, camera
        self.graph = graph.Graph(scenario)
        self.engine = graph.Engine(self.graph)
        self.observed = observed_placements(site)
        self.mapper = VisualMapper(self.observed)
        self.ports = port_table(self.graph, self.observed)
        self.fed = {e.dst: e.src for e in self.graph.edges}
        self.switches = {switch_node(t): t for t in switchgear(site) if switch_node(t) in self.graph.nodes}
        self.render_id = next((n for n in self.graph.order if self.graph.nodes[n].type_name == "render"), None)
        suns = sorted(n for n in self.graph.nodes if self.graph.nodes[n].type_name == "sun")
        rp = self.graph.nodes[self.render_id].p if self.render_id else {}
        self.sun_id = rp.get("sun") or (suns[0] if len(suns) == 1 else None)
        self.camera_id = next((n for n in self.graph.order if self.graph.nodes[n].type_name == "camera"), None)
        self._spheres = None
        self._published: dict = {}
        record = load_record(site.build)
        self.wires = LiveWires(record) if record is not None else None
        # Held at the start: every bound state fed by no edge, at its domain's top (full).
        for name, spec in self.ports.items():
            if spec.node == self.render_id and (spec.node, spec.port) not in self.fed and spec.range:
                self.engine.hold(spec.node, spec.port, spec.range[1])
        self._sync_zoom()

    # -- time
    def instant(self, k: int | None = None) -> dt.datetime:
        """The simulated instant of step k (the current one by default), on the site's clock."""
        k = self.engine.k if k is None else k
        when = self.scenario.start + dt.timedelta(seconds=k * self.scenario.step_s)
        return when.astimezone(self.scenario.zone) if self.scenario.zone else when

    def step_of(self, instant: dt.datetime) -> int:
        """The last step at or before `instant`; ValueError before the run's start."""
        t = (instant - self.scenario.start).total_seconds()
        if t < 0:
            raise ValueError(f"{instant.isoformat()} is before the run's start, {self.instant(0).isoformat()}")
        return int(math.floor(t / self.scenario.step_s + 1e-9))

    def advance(self, k: int) -> list[tuple[int, dict]]:
        """Step the graph to step k; [(step, changed port values)] for each step run (one
        step after a jump: a seek, or a clock more than MAX_CATCH_UP steps ahead)."""
        if k == self.engine.k and not self.engine.pending:
            return []
        if k < self.engine.k or k - self.engine.k > MAX_CATCH_UP:
            self.engine.seek(k)
        out = []
        while self.engine.k < k or (self.engine.pending and self.engine.k == k):
            if self.engine.k == k:  # a set while paused: the same step again, its changes applied
                self.engine.k -= 1
            report = self.engine.step()
            out.append((report.k, self._changes(report.ran)))
        return out

    # -- ports
    def value(self, spec: PortSpec):
        if spec.kind == "output":
            return self.engine.values.get((spec.node, spec.port))
        held = self.engine.held.get(spec.node, {})
        if spec.port in held:
            return held[spec.port]
        src = self.fed.get((spec.node, spec.port))
        if src is not None:
            return self.engine.values.get(src)
        if spec.node == self.render_id:
            state, _, variable = spec.port.partition(".")
            return self.graph.nodes[spec.node].values.get(state, {}).get(variable)
        return None

    def get(self, names: list[str] | None = None) -> dict:
        if names is None:
            names = list(self.ports)
        unknown = [n for n in names if n not in self.ports]
        if unknown:
            raise KeyError(self._unknown(unknown[0]))
        return {n: self.value(self.ports[n]) for n in names}

    def set(self, values: dict) -> dict:
        """Check every value first (nothing changes if one is bad), then hold inputs and
        set constants; None lets an input go (it reads its edge or default again). The
        changes show at the next step. Returns the typed values."""
        typed = {}
        for name, raw in values.items():
            spec = self.ports.get(name)
            if spec is None:
                raise KeyError(self._unknown(name))
            if not spec.settable:
                raise ValueError(f"{name} is an output of {spec.node}: set one of its inputs, or a constant")
            if spec.node == self.camera_id and spec.port == "zoom":
                raise ValueError(f"{name}: zoom the camera with the camera command")
            if raw is None:  # let go: the input reads its edge (or its default) again
                if spec.kind == "output":
                    raise ValueError(f"{name}: a constant has nothing to return to; set a value")
                typed[name] = None
                continue
            typed[name] = check_value(spec, raw, switch=spec.node in self.switches)
        for name, value in typed.items():
            spec = self.ports[name]
            if value is None:
                self.engine.release(spec.node, spec.port)
            elif spec.kind == "output":
                self.engine.set_value(spec.node, value)
            else:
                self.engine.hold(spec.node, spec.port, value)
        return typed

    def _unknown(self, name: str) -> str:
        node, _, port = name.partition(".")
        if node not in self.graph.nodes:
            return f"unknown node {node!r} in {name!r} (nodes: {', '.join(sorted(self.graph.nodes))})"
        return f"unknown port {name!r} (ports of {node}: " \
               f"{', '.join(s.port for s in self.ports.values() if s.node == node) or 'none'})"

    def _changes(self, ran: tuple[str, ...]) -> dict:
        """The ports of the nodes that ran whose value differs from the last published."""
        ran, changed = set(ran), {}
        for name, spec in self.ports.items():
            if spec.node in ran:
                v = self.value(spec)
                if self._published.get(name, _MISSING) != v:
                    changed[name] = self._published[name] = v
        return changed

    # -- the wires
    def render_values(self) -> dict:
        return self.graph.nodes[self.render_id].values if self.render_id else {}

    def conductors(self) -> dict | None:
        """Each conductor group's temperature and its spans' sag now (None: no conductors)."""
        return None if self.wires is None else self.wires.state(self.render_values())

    def conductor_changes(self) -> dict:
        """The groups whose temperature changed since the last call."""
        return {} if self.wires is None else self.wires.changes(self.render_values())

    # -- camera
    def camera_command(self, req: dict) -> dict:
        self.camera.command(req)
        self._sync_zoom()
        return self.camera.state()

    def _sync_zoom(self) -> None:
        if self.camera_id is not None:
            self.engine.hold(self.camera_id, "zoom", self.camera.zoom)

    # -- what a render shows
    def sun(self) -> tuple[float, float, float, float]:
        """(elevation rad, azimuth rad, direct horizontal irradiance W/m2, turbidity) now."""
        tau = sun_model.DEFAULT_TAU_ATM
        if self.sun_id is not None:
            spec = self.ports.get(f"{self.sun_id}.tau_atm")
            held = self.value(spec) if spec is not None else None
            tau = float(held) if held is not None else float(self.graph.nodes[self.sun_id].tau_atm)
            v = self.engine.values
            return v[(self.sun_id, "elevation")], v[(self.sun_id, "azimuth")], v[(self.sun_id, "irradiance")], tau
        el, az = sun_model.ephemeris(self.site.origin[0], self.site.origin[1], self.instant())
        e = math.radians(el)
        return e, math.radians(az), sun_model.irradiance(e, tau), tau

    def frame_plan(self, width: int, height: int, seed: int | None = None) -> FramePlan:
        """The current state as `twin dataset` describes a frame: the same Shot, visible
        set and seeds for the same camera, instant and state give the same bytes."""
        if self.engine.k < 0:
            raise ValueError("the twin has not stepped yet")
        values = self.graph.nodes[self.render_id].values if self.render_id else {}
        e, az, irr, tau = self.sun()
        levels = {o.tag: dict(values[o.state]) for o in self.observed if o.state in values}
        lens = self.camera.lens()
        shot = Shot(self.instant(), self.camera.pose.copy(), lens, e, az, irr, levels,
                    self.mapper.states(values), self.camera.target)
        if seed is None:  # noise drawn from what the frame shows, with the run's seed
            seed = frame_seed(self.scenario.seed, shot_key(shot)) & 0x7FFFFFFF
        aerosol = self.engine.values.get(("aerosol", "value"), DEFAULT_AEROSOL)
        switches = {tag: "open" if self.engine.values.get((node, "value")) else "closed"
                    for node, tag in self.switches.items()}
        if self._spheres is None:
            self._spheres = self.site.spheres()
        plan = FramePlan(self.engine.k, f"live_{self.engine.k:06d}", int(seed), self.camera.name, shot,
                         float(aerosol), tau, levels, switches)
        plan.visible_tags = visible_tags(self._spheres, shot, width, height)
        return plan


_MISSING = object()
