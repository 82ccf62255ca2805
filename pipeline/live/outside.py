"""The live twin and the world outside it: the substation's signals in (`--inputs`), the
simulator out (`--gazebo WORLD`).

Signals in: the bridges' clients run on threads and processes of their own and fill a
hub; the hub wakes the loop, which applies what changed as a `set` would (typed and
range-checked: a value out of range is a fault of its signal, never of the twin) and
publishes it at once. A stale signal holds its last value and is listed under "stale"
in every published message and `get` reply until it is live again.

Gazebo out: after every published step, what changed of the sun (the world's light
"sun", as the SDF applier writes it), the switches (their joints' positions, as
`twin dataset` poses them) and the bound materials (visual_config, Harmonic) goes to
gz-sim through tools/gzbridge. A gauge pointer or an oil column is a visual without a
joint: gz-sim has no request that moves or morphs one, so those are counted as not
applied, as the SDF applier lists shapes. So are the switches a world was built to
draw at rest, without joints (site.toml [gazebo] moving_parts = "none", or a list of
tag patterns that none of theirs matches), as the build's placements.json records
it: no joint command is sent for them.
"""

from __future__ import annotations

import asyncio

from .. import config, sun as sun_model
from ..bridges.feeds import Feeds
from ..bridges.inputs import read_inputs
from ..datasets.plan import switch_angles
from ..runtime.apply_sdf import sun_fragment


def frozen(moving_parts: str | tuple[str, ...], chosen_by: str | None = None) -> str:
    """Why a switch the world draws at rest is not applied (`chosen_by`: "auto" when the
    build chose the setting itself, placements.json's `gazebo.chosen_by`)."""
    if moving_parts != "none":
        setting = f"{list(moving_parts)} (its tag matches none)"
    elif chosen_by == "auto":
        setting = '"auto", which chose "none": every switch moving would take the world over its parse budget'
    else:
        setting = '"none"'
    return f"switch: the world was built with [gazebo] moving_parts = {setting}, it has no joint to move"


class SignalsIn:
    """An inputs file's clients, feeding the twin through `apply` (LiveServer.apply_inputs)."""

    def __init__(self, path, ports: dict):
        """`ports`: the twin's port table (name -> live.ports.PortSpec)."""
        self.signals = read_inputs(path, {n for n, spec in ports.items() if spec.settable})
        # a signal's numbers go to a bool port (a switch) as 1 = true, 0 = false
        self.bools = {n for n, spec in ports.items() if spec.type == "bool"}
        self.feeds = Feeds(self.signals)
        self.stale: set[str] = {s.target for s in self.signals}  # until their first value
        self.rejected = 0  # values the twin refused (out of range, wrong type)
        self._wake: asyncio.Event | None = None

    async def run(self, apply) -> None:
        """Start the clients; on every change, `apply({target: value})` and remember
        what is stale. Ends when cancelled (the twin's shutdown)."""
        loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        self.feeds.hub.on_change = lambda: loop.call_soon_threadsafe(self._wake.set)
        await asyncio.to_thread(self.feeds.__enter__)
        try:
            while True:
                await self._wake.wait()
                self._wake.clear()
                self._apply(self.feeds.hub.drain(), apply)
        finally:
            self.feeds.hub.on_change = None
            await asyncio.to_thread(self.feeds.__exit__, None, None, None)

    def _apply(self, updates, apply) -> None:
        values = {}
        for u in updates:
            if u.stale:
                self.stale.add(u.target)
            else:
                self.stale.discard(u.target)
                values[u.target] = bool(u.value) if u.target in self.bools and u.value in (0.0, 1.0) else u.value
        if not values and not updates:
            return
        try:
            apply(values)
        except (KeyError, ValueError):  # one bad value must not hold back the others
            for target, value in values.items():
                try:
                    apply({target: value})
                except (KeyError, ValueError) as err:
                    self.rejected += 1
                    signal = next(s for s in self.signals if s.target == target)
                    self.feeds.hub.fault(signal, f"the twin refused {value!r}: {err}")

    def status(self) -> dict:
        return {"signals": self.feeds.hub.status(), "stale": sorted(self.stale), "rejected": self.rejected}


class GazeboOut:
    """What changed of the twin's visible state, pushed to a running gz-sim."""

    def __init__(self, world: str, bridge=None):
        from ..bridges.gazebo import GazeboBridge

        self.world = world
        self.bridge = bridge or GazeboBridge(world)
        self.last: dict = {}
        self.not_applied: set[str] = set()

    def push(self, twin) -> None:
        self._sun(twin)
        self._switches(twin)
        self._materials_and_visuals(twin)
        if twin.wires is not None:
            # the world's conductors are one static model of merged meshes (per sag variant):
            # gz-sim has no request that reshapes a static visual or swaps a model's meshes
            self.not_applied.add("conductors (sag: a static model; the world's SDF carries the sag variants)")

    def _sun(self, twin) -> None:
        e, az, irr, _ = twin.sun()
        light = sun_fragment(e, az, irr, sun_model.G0)
        key = (tuple(light["direction"]), light["intensity"])
        if self.last.get("sun") != key:
            self.last["sun"] = key
            level = light["intensity"]
            self.bridge.sun(light["direction"], level, (level, level, level))

    def _switches(self, twin) -> None:
        moving_parts = twin.site.moving_parts
        for node, tag in sorted(twin.switches.items()):
            if not config.moves_in_gazebo(moving_parts, tag):
                self.not_applied.add(f"{tag} ({frozen(moving_parts, twin.site.moving_parts_by)})")
                continue
            position = "open" if twin.engine.values.get((node, "value")) else "closed"
            if self.last.get(("switch", tag)) == position:
                continue
            self.last[("switch", tag)] = position
            manifest = twin.site.manifests[twin.site.placement(tag)["asset"]]
            for joint, angle in sorted(switch_angles(manifest, position).items()):
                self.bridge.joint(tag, joint, angle)

    def _materials_and_visuals(self, twin) -> None:
        values = twin.graph.nodes[twin.render_id].values if twin.render_id else {}
        for vs in twin.mapper.states(values):
            if vs.material is not None and self.last.get(("material", vs.tag, vs.visual)) != vs.material:
                self.last[("material", vs.tag, vs.visual)] = vs.material
                manifest = twin.site.manifests[twin.site.placement(vs.tag)["asset"]]
                colour = next((m["base_color"] for m in manifest.get("materials", []) if m["name"] == vs.material),
                              None)
                if colour is not None:
                    self.bridge.visual(f"{vs.tag}::{vs.link}::{vs.visual}", colour)
            for out in vs.outputs:
                effect = out.binding["effect"]
                if effect != "material":
                    self.not_applied.add(f"{vs.tag}::{vs.visual} ({effect}: no joint in gz-sim moves it)")

    def status(self) -> dict:
        b = self.bridge
        return {"world": self.world, "sent": dict(b.sent), "failed": dict(b.failed),
                "not_applied": sorted(self.not_applied)}

    def close(self) -> None:
        self.bridge.close()
