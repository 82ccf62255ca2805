"""The runtime state graph G = (V, E, L) of a scenario file, and its engine.

V: nodes (nodes.py types), E: edges "node.port" -> "node.port", L: each edge's label
(type, unit, rate_hz, protocol). Loading checks everything and raises one UserError
naming the file and the node or edge: unknown node type, dangling port, type or unit
mismatch, an input fed twice, a required input left unfed, a cycle (its nodes named in
order), a period that is not a whole number of clock steps.

Schedule: Kahn's algorithm taking the ready node with the smallest id first, so the
order depends only on the file. Step k (t = k step_s): a node runs when it is due
(k is a multiple of its period in steps; k = 0 runs everything), when an input it
reads changed value in this step, or when it was set from outside (`Engine.set_value`).
Nodes are visited in schedule order, so a change reaches everything downstream within
the same step and nothing else runs.
"""

from __future__ import annotations

import datetime as dt
import heapq
from dataclasses import dataclass, field
from pathlib import Path

from .. import config
from ..errors import UserError
from .nodes import NODE_TYPES, RunContext, Node


@dataclass(frozen=True)
class Edge:
    index: int
    src: tuple[str, str]
    dst: tuple[str, str]
    type: str
    unit: str
    rate_hz: float | None = None
    protocol: str | None = None

    @property
    def label(self) -> str:
        return f"edges[{self.index}] {'.'.join(self.src)} -> {'.'.join(self.dst)}"


@dataclass
class Scenario:
    path: Path
    name: str
    seed: int
    duration_s: float
    step_s: float
    start: dt.datetime  # the UTC instant of t = 0
    assets: list[str]
    nodes: list[dict]
    edges: list[dict]
    description: str = ""
    raw: dict = field(default_factory=dict, repr=False)
    zone: dt.tzinfo | None = None  # of local dates and times: the site's; None: start's own offset

    @property
    def steps(self) -> int:
        """Number of clock steps after t = 0 (the run has steps + 1 records)."""
        return int(round(self.duration_s / self.step_s))


def load_scenario(path: Path, zone: dt.tzinfo | None = None) -> Scenario:
    """`zone`: the site's time zone (site.toml [site] timezone, as the built scene
    records it). A start without a UTC offset is a wall-clock time in it."""
    path = Path(path)
    data = config.read_toml(path)
    config.validate(data, "scenario", path)
    s = data["scenario"]
    try:
        start = dt.datetime.fromisoformat(s["start"].replace("Z", "+00:00"))
    except ValueError as e:
        raise UserError(path, "scenario.start", f"not an ISO date-time: {e}") from None
    if start.tzinfo is None:
        if zone is None:
            raise UserError(path, "scenario.start", "no UTC offset, and no site time zone to read it in (build the "
                                                    "scene first, or write the offset, e.g. 2025-03-20T06:00:00-03:00)")
        try:
            start = config.local_time(start, zone)
        except ValueError as e:
            raise UserError(path, "scenario.start", str(e)) from None
    return Scenario(path=path, name=s["name"], seed=int(s["seed"]), duration_s=float(s["duration_s"]),
                    step_s=float(s["step_s"]), start=start.astimezone(dt.timezone.utc),
                    assets=list(s.get("assets", [])), nodes=data["nodes"], edges=data.get("edges", []),
                    description=s.get("description", ""), raw=data, zone=zone or start.tzinfo)


def _split(ref: str) -> tuple[str, str]:
    node, _, port = ref.partition(".")
    return node, port


class Graph:
    """Checked nodes and edges and their schedule. `order`: node ids, topological."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        f = scenario.path
        self.ctx = RunContext(seed=scenario.seed, start=scenario.start, step_s=scenario.step_s, zone=scenario.zone)
        self.nodes: dict[str, Node] = {}
        self.period_steps: dict[str, int | None] = {}
        for i, spec in enumerate(scenario.nodes):
            where = f"nodes[{i}] {spec['id']}"
            if spec["id"] in self.nodes:
                raise UserError(f, where, f"duplicate node id {spec['id']!r}")
            cls = NODE_TYPES.get(spec["type"])
            if cls is None:
                raise UserError(f, where, f"unknown node type {spec['type']!r} (known: {', '.join(sorted(NODE_TYPES))})")
            try:
                self.nodes[spec["id"]] = cls(spec["id"], dict(spec.get("params", {})), self.ctx)
            except (ValueError, TypeError) as e:
                raise UserError(f, where, str(e)) from None
            self.period_steps[spec["id"]] = self._period(spec, where)
        self.edges = [self._edge(i, e) for i, e in enumerate(scenario.edges)]
        self.feeds: dict[str, list[Edge]] = {n: [] for n in self.nodes}  # edges into a node
        self.consumers: dict[str, list[Edge]] = {n: [] for n in self.nodes}  # edges out of a node
        fed: dict[tuple[str, str], Edge] = {}
        for e in self.edges:
            if e.dst in fed:
                raise UserError(f, e.label, f"input {'.'.join(e.dst)} is already fed by {fed[e.dst].label}")
            fed[e.dst] = e
            self.feeds[e.dst[0]].append(e)
            self.consumers[e.src[0]].append(e)
        for node_id in sorted(self.nodes):
            for port in self.nodes[node_id].required_inputs():
                if (node_id, port) not in fed:
                    raise UserError(f, f"node {node_id}", f"required input {node_id}.{port} is not fed by any edge")
        self.order = self._schedule()

    def _period(self, spec: dict, where: str) -> int | None:
        if "period_s" not in spec:
            return None
        ratio = float(spec["period_s"]) / self.scenario.step_s
        steps = round(ratio)
        if steps < 1 or abs(ratio - steps) > 1e-9 * max(1.0, ratio):
            raise UserError(self.scenario.path, where,
                            f"period_s {spec['period_s']} is not a whole multiple of step_s {self.scenario.step_s}")
        return int(steps)

    def _edge(self, i: int, spec: dict) -> Edge:
        f = self.scenario.path
        e = Edge(i, _split(spec["from"]), _split(spec["to"]), spec["type"], spec["unit"],
                 spec.get("rate_hz"), spec.get("protocol"))
        (sn, sp), (dn, dp) = e.src, e.dst
        for node in (sn, dn):
            if node not in self.nodes:
                raise UserError(f, e.label, f"unknown node {node!r}")
        out = self.nodes[sn].output_port(sp)
        if out is None:
            known = ", ".join(sorted(self.nodes[sn].output_ports())) or "none"
            raise UserError(f, e.label, f"node {sn} ({self.nodes[sn].type_name}) has no output {sp!r} (outputs: {known})")
        inp = self.nodes[dn].input_port(dp)
        if inp is None:
            known = ", ".join(self.nodes[dn].input_names()) or "none"
            raise UserError(f, e.label, f"node {dn} ({self.nodes[dn].type_name}) has no input {dp!r} (inputs: {known})")
        for side, port in (("source", out), ("target", inp)):
            if port.type != e.type:
                raise UserError(f, e.label, f"type mismatch: edge says {e.type}, {side} port is {port.type}")
        if out.unit != e.unit:
            raise UserError(f, e.label, f"unit mismatch: edge says {e.unit!r}, {sn}.{sp} gives {out.unit!r}")
        if inp.unit not in ("*", e.unit):
            raise UserError(f, e.label, f"unit mismatch: edge carries {e.unit!r}, {dn}.{dp} expects {inp.unit!r}")
        if sn == dn:
            raise UserError(f, e.label, f"cycle: {sn} -> {sn}")
        return e

    def _schedule(self) -> list[str]:
        succ = {n: sorted({e.dst[0] for e in self.consumers[n]}) for n in self.nodes}
        indeg = {n: len({e.src[0] for e in self.feeds[n]}) for n in self.nodes}
        ready = [n for n in self.nodes if indeg[n] == 0]
        heapq.heapify(ready)
        order = []
        while ready:
            n = heapq.heappop(ready)
            order.append(n)
            for m in succ[n]:
                indeg[m] -= 1
                if indeg[m] == 0:
                    heapq.heappush(ready, m)
        if len(order) < len(self.nodes):
            raise UserError(self.scenario.path, "edges", f"cycle: {' -> '.join(self._a_cycle(set(self.nodes) - set(order)))}")
        return order

    def _a_cycle(self, left: set[str]) -> list[str]:
        """One cycle among the nodes Kahn could not schedule, in edge direction."""
        pred = {n: sorted({e.src[0] for e in self.feeds[n]} & left) for n in left}
        path, seen = [], {}
        n = min(left)
        while n not in seen:  # every left node has a predecessor in `left`
            seen[n] = len(path)
            path.append(n)
            n = pred[n][0]
        cycle = path[seen[n]:][::-1]
        i = cycle.index(min(cycle))  # start at the smallest id: the message is stable
        cycle = cycle[i:] + cycle[:i]
        return cycle + [cycle[0]]


@dataclass(frozen=True)
class StepReport:
    k: int
    t: float
    ran: tuple[str, ...]

    @property
    def count(self) -> int:
        return len(self.ran)


class Engine:
    """Runs a Graph step by step; `values[(node, port)]` holds the latest outputs."""

    def __init__(self, graph: Graph):
        self.graph = graph
        self.k = -1
        self.values: dict[tuple[str, str], object] = {}
        self._forced: set[str] = set()
        # Inputs held from outside (`twin serve`'s set): node -> port -> value, read in
        # place of what the port's edge carries (or its default) until released.
        self.held: dict[str, dict[str, object]] = {}
        # Per node, (input port, source key) pairs, resolved once.
        self._reads = {n: [(e.dst[1], e.src) for e in graph.feeds[n]] for n in graph.nodes}
        self._pos = {n: i for i, n in enumerate(graph.order)}
        self._readers: dict[tuple[str, str], list[int]] = {}  # output -> positions reading it
        for e in graph.edges:
            self._readers.setdefault(e.src, []).append(self._pos[e.dst[0]])
        self._by_period: dict[int, list[int]] = {}
        for n, p in graph.period_steps.items():
            if p is not None:
                self._by_period.setdefault(p, []).append(self._pos[n])

    @property
    def t(self) -> float:
        return self.k * self.graph.scenario.step_s

    def set_value(self, node_id: str, value) -> None:
        """Change a `constant` node's value; it and its downstream run at the next step."""
        node = self.graph.nodes[node_id]
        if not hasattr(node, "value"):
            raise KeyError(f"{node_id} is not a constant node")
        node.value = value
        self._forced.add(node_id)

    def hold(self, node_id: str, port: str, value) -> None:
        """Feed `node_id.port` with `value` from outside; the node runs at the next step."""
        self.held.setdefault(node_id, {})[port] = value
        self._forced.add(node_id)

    def release(self, node_id: str, port: str) -> None:
        """The port reads its edge (or its default) again from the next step on."""
        self.held.get(node_id, {}).pop(port, None)
        self._forced.add(node_id)

    @property
    def pending(self) -> bool:
        """Are nodes forced to run at the next step (a set, a hold, a seek)?"""
        return bool(self._forced)

    def seek(self, k: int) -> None:
        """The next step is k, and every node runs in it: the clock jumped (every node
        type is a function of t, its inputs and its parameters)."""
        self.k = int(k) - 1
        self._forced.update(self.graph.nodes)

    def step(self) -> StepReport:
        self.k += 1
        k, t = self.k, self.t
        g = self.graph
        # Visit only what can run: due and forced nodes, then consumers of changed
        # outputs, in schedule order (a heap of schedule positions): the cost of an
        # incremental step follows the affected subgraph, not the graph's size.
        if k == 0:
            todo = list(range(len(g.order)))
        else:
            todo = [self._pos[n] for n in self._forced]
            for period, members in self._by_period.items():
                if k % period == 0:
                    todo += members
        heapq.heapify(todo)
        queued = set(todo)
        ran = []
        while todo:
            n = g.order[heapq.heappop(todo)]
            inputs = {port: self.values[src] for port, src in self._reads[n] if src in self.values}
            if n in self.held:
                inputs.update(self.held[n])
            try:
                out = g.nodes[n].step(t, inputs)
            except ValueError as e:
                raise UserError(g.scenario.path, f"node {n}", f"at t = {t:g} s: {e}") from None
            ran.append(n)
            for port, value in out.items():
                key = (n, port)
                if key not in self.values or self.values[key] != value:
                    self.values[key] = value
                    for i in self._readers.get(key, ()):
                        if i not in queued:
                            queued.add(i)
                            heapq.heappush(todo, i)
        self._forced.clear()
        return StepReport(k, t, tuple(ran))

    def run(self):
        """Yield a StepReport for t = 0 .. duration."""
        for _ in range(self.graph.scenario.steps + 1 - (self.k + 1)):
            yield self.step()
