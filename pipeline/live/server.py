"""The live twin's loop (asyncio, one thread): the graph steps when the simulated clock
passes a step, every step's changes are published (ZeroMQ PUB, WebSocket, MCAP when
recording), and commands are served meanwhile, each in its own task, so a render (in the
Blender process, awaited on a thread) never holds up the clock or another client.

Nothing from outside stops the clock: a bad request gets an error reply, a vanished
client's reply is counted and dropped, a slow subscriber loses messages (counted), a
failed render is an error reply. SIGINT, SIGTERM or `shutdown` end it, the Blender
process with it."""

from __future__ import annotations

import asyncio
import datetime as dt
import signal
import time
from collections import deque

import numpy as np

from . import protocol
from .clock import SimClock, parse_instant
from .render_worker import RenderError, RenderWorker
from .twin import LiveTwin
from .websocket import WebSocketFeed
from .zmq_io import ZmqSockets

RECHECK_S = 0.25  # the ticker looks at the clock at least this often (paused, or far from a step)


class LiveServer:
    def __init__(self, twin: LiveTwin, clock: SimClock, *, bind: str = "127.0.0.1", port: int = 5555,
                 worker: RenderWorker | None = None, info: dict | None = None, recorder=None,
                 inputs=None, gazebo=None):
        self.twin, self.clock, self.worker, self.recorder = twin, clock, worker, recorder
        self.inputs, self.gazebo = inputs, gazebo  # outside.SignalsIn, outside.GazeboOut
        self.bind, self.port, self.info = bind, port, dict(info or {})
        self.seq = -1
        self.stop = asyncio.Event()
        self.wake = asyncio.Event()
        self.latency_ms: deque[float] = deque(maxlen=10000)  # step due -> published, clock-driven steps
        self.stats = {"steps": 0, "published": 0, "requests": 0, "bad_requests": 0, "undelivered_replies": 0,
                      "renders": 0, "render_failures": 0, "ws_dropped": 0, "record_errors": 0,
                      "gazebo_errors": 0}
        self.last_render_error = self.last_record_error = ""
        self.zmq: ZmqSockets | None = None
        self.ws: WebSocketFeed | None = None
        self.endpoints: dict = {}

    # -- life
    async def run(self, ready=None) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self.stop.set)
        self.zmq = ZmqSockets(self.bind, self.port)
        self.ws = WebSocketFeed(self.hello, self.snapshot)
        try:
            ws_port = await self.ws.start(self.bind, self.port + 2 if self.port else 0)
            self.endpoints = {**self.zmq.endpoints, "websocket": f"ws://{self.bind}:{ws_port}/ws",
                              "page": f"http://{self.bind}:{ws_port}/"}
            fox = [s for s in (self.recorder.sinks if self.recorder else []) if hasattr(s, "port")]
            if fox:
                self.endpoints["foxglove"] = f"ws://{self.bind}:{fox[0].port}"
            if self.worker is not None:
                self.worker.start()  # the scene loads while the twin runs
            self._advance(self._due(), None)
            if ready is not None:
                ready(self.endpoints)
            tasks = [asyncio.create_task(self._ticker()), asyncio.create_task(self._commands())]
            if self.inputs is not None:
                tasks.append(asyncio.create_task(self.inputs.run(self.apply_inputs)))
            await self.stop.wait()
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)
            await self.ws.close()
            self.zmq.close()
            if self.worker is not None:
                await asyncio.to_thread(self.worker.close)
            if self.recorder is not None:
                self.recorder.close()
            if self.gazebo is not None:
                await asyncio.to_thread(self.gazebo.close)

    # -- the clock
    def _due(self) -> int:
        try:
            return self.twin.step_of(self.clock.now())
        except ValueError:
            return -1  # before the run's start: nothing to run yet

    def _advance(self, k: int, due_wall: float | None) -> None:
        if k < 0:
            return
        steps = self.twin.advance(k)
        for kk, values in steps:
            self.stats["steps"] += 1
            self._publish(kk, values)
        if due_wall is not None and steps:
            self.latency_ms.append((time.monotonic() - due_wall) * 1000.0)

    def _publish(self, k: int, values: dict) -> None:
        self.seq += 1
        msg = protocol.published(self.seq, k, self.twin.instant(k), values)
        wires = self.twin.conductor_changes()
        if wires:
            msg["conductors"] = wires
        if self.inputs is not None:
            msg["stale"] = sorted(self.inputs.stale)
        self.zmq.publish(protocol.encode(msg))
        self.ws.publish(msg)
        if self.recorder is not None:
            self._record(self.recorder.state, self.twin, msg)
        if self.gazebo is not None:
            try:
                self.gazebo.push(self.twin)
            except Exception as e:  # noqa: BLE001 - the simulator's trouble, not the twin's
                self.stats["gazebo_errors"] += 1
                self.last_record_error = f"gazebo: {type(e).__name__}: {e}"
        self.stats["published"] += 1

    def _record(self, fn, *args) -> None:
        try:
            fn(*args)
        except Exception as e:  # noqa: BLE001 - a full disk stops the recording, not the twin
            self.stats["record_errors"] += 1
            self.last_record_error = f"{type(e).__name__}: {e}"

    async def _ticker(self) -> None:
        while not self.stop.is_set():
            now_sim, now_wall = self.clock.now(), time.monotonic()
            k = self._due()
            if k > self.twin.engine.k:
                late_s = 0.0 if self.clock.paused else \
                    (now_sim - self.twin.instant(k)).total_seconds() / self.clock.speed
                self._advance(k, now_wall - late_s)
            nxt = self.twin.scenario.start + dt.timedelta(seconds=(max(k, -1) + 1) * self.twin.scenario.step_s)
            delay = min(self.clock.wall_until(nxt), RECHECK_S)
            self.wake.clear()
            try:
                await asyncio.wait_for(self.wake.wait(), delay)
            except asyncio.TimeoutError:
                pass

    # -- commands
    async def _commands(self) -> None:
        while not self.stop.is_set():
            envelope, body = await self.zmq.receive()
            asyncio.create_task(self._serve_one(envelope, body))

    async def _serve_one(self, envelope: list[bytes], body: list[bytes]) -> None:
        self.stats["requests"] += 1
        if len(body) != 1:
            reply, frames = protocol.error(f"a request is one frame of JSON, got {len(body)} frames"), []
        else:
            reply, frames = await self.handle(body[0])
        if not reply.get("ok"):
            self.stats["bad_requests"] += 1
        if not await self.zmq.reply(envelope, [protocol.encode(reply), *frames]):
            self.stats["undelivered_replies"] += 1  # the client is gone; the twin goes on

    async def handle(self, raw: bytes) -> tuple[dict, list[bytes]]:
        """One request's (reply, extra frames); every fault is an error reply."""
        try:
            req = protocol.parse(raw)
            cmd = req["cmd"]
            if cmd == "render":
                return await self._render(req)
            return getattr(self, f"_cmd_{cmd}")(req), []
        except protocol.BadRequest as e:
            return protocol.error(str(e)), []
        except (KeyError, ValueError) as e:
            text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
            return protocol.error(f"{req['cmd']}: {text}"), []
        except Exception as e:  # noqa: BLE001 - a bug answers as an error; the clock goes on
            return protocol.error(f"internal error: {type(e).__name__}: {e}"), []

    def _cmd_hello(self, req) -> dict:
        return {"ok": True, **self.hello()}

    def _cmd_get(self, req) -> dict:
        reply = {"ok": True, "seq": self.seq, "sim_time": self.twin.instant().isoformat(),
                 "values": self.twin.get(req.get("ports"))}
        if req.get("conductors") and self.twin.wires is not None:
            reply["conductors"] = self.twin.conductors()
        if self.inputs is not None:
            reply["stale"] = sorted(self.inputs.stale)
        return reply

    def apply_inputs(self, values: dict) -> None:
        """What the substation's signals changed (SignalsIn), applied as a `set` and
        published at once; with no value, the change of what is stale is published."""
        if values:
            self.twin.set(values)
            before = self.seq
            self._advance(self.twin.engine.k, None)
            if self.seq != before:
                return
        self._publish(self.twin.engine.k, {})

    def _cmd_set(self, req) -> dict:
        typed = self.twin.set(req["values"])
        self._advance(self.twin.engine.k, None)  # published now, not at the next step
        return {"ok": True, "values": typed, "seq": self.seq}

    def _cmd_clock(self, req) -> dict:
        action = req["action"]
        if action == "pause":
            self.clock.pause()
        elif action == "resume":
            self.clock.resume()
        elif action == "speed":
            self.clock.set_speed(req["speed"])
        elif action == "seek":
            when = parse_instant(req["to"], self.twin.scenario.zone)
            k = self.twin.step_of(when)
            self.clock.seek(when.astimezone(self.twin.scenario.zone) if self.twin.scenario.zone else when)
            self.twin.engine.seek(k)
            self._advance(k, None)
        self.wake.set()
        return {"ok": True, "clock": self.clock_state()}

    def _cmd_camera(self, req) -> dict:
        state = self.twin.camera_command(req)
        self._advance(self.twin.engine.k, None)
        return {"ok": True, "camera": state}

    def _cmd_shutdown(self, req) -> dict:
        asyncio.get_running_loop().call_soon(self.stop.set)  # after the reply is sent
        return {"ok": True}

    async def _render(self, req) -> tuple[dict, list[bytes]]:
        if self.worker is None:
            return protocol.error("render: this twin runs without renders (no Blender: pip install bpy)"), []
        cam = self.worker.job.cam
        plan = self.twin.frame_plan(cam.width, cam.height, req.get("seed"))
        mask, depth = bool(req.get("mask")), bool(req.get("depth"))
        try:
            out = await asyncio.to_thread(self.worker.render, plan, mask, depth, req.get("timeout_s", 600.0))
        except RenderError as e:
            self.stats["render_failures"] += 1
            self.last_render_error = str(e)
            return protocol.error(f"render: {e}"), []
        self.stats["renders"] += 1
        frames, kinds = [out["png"]], ["image/png"]
        if mask:
            frames.append(out["mask"]), kinds.append("mask/png")
        if depth:
            frames.append(out["depth"]), kinds.append("depth/npy")
        reply = {"ok": True, "frames": kinds, "sim_time": plan.shot.when.isoformat(), "seed": plan.seed,
                 "camera": plan.camera, "seconds": out["seconds"]}
        if req.get("labels"):
            reply["labels"] = out["record"]
        if self.recorder is not None:
            self._record(self.recorder.image, plan, out["png"])
        return reply, frames

    # -- descriptions
    def clock_state(self) -> dict:
        return {**self.clock.state(), "step_s": self.twin.scenario.step_s, "k": self.twin.engine.k,
                "step_time": self.twin.instant().isoformat()}

    def snapshot(self) -> dict:
        """Every port's value as a published message (a late subscriber's start)."""
        msg = protocol.published(max(self.seq, 0), self.twin.engine.k, self.twin.instant(), self.twin.get())
        if self.twin.wires is not None:
            msg["conductors"] = self.twin.conductors()
        return msg

    def hello(self) -> dict:
        t = self.twin
        g = t.graph
        lat = np.percentile(self.latency_ms, [50, 99]).tolist() if self.latency_ms else None
        stats = {**self.stats, "ws_dropped": self.ws.dropped if self.ws else 0, "seq": self.seq,
                 "step_latency_ms": {"p50": lat[0], "p99": lat[1], "n": len(self.latency_ms)} if lat else None,
                 "last_render_error": self.last_render_error, "last_record_error": self.last_record_error,
                 "render_process": {"pid": self.worker.pid, "load_s": self.worker.load_s,
                                    "starts": self.worker.starts} if self.worker else None,
                 "inputs": self.inputs.status() if self.inputs is not None else None,
                 "gazebo": self.gazebo.status() if self.gazebo is not None else None}
        return {"protocol": protocol.PROTOCOL, "versions": self.info.get("versions", {}),
                "scene": {**self.info.get("scene", {}), "scenario": t.scenario.name, "step_s": t.scenario.step_s,
                          "seed": t.scenario.seed, "bindings": gauges(t), "switches": sorted(t.switches.values())},
                "site": self.info.get("site", {}), "endpoints": self.endpoints,
                "nodes": [{"id": n, "type": g.nodes[n].type_name, "period_s":
                           None if g.period_steps[n] is None else g.period_steps[n] * t.scenario.step_s}
                          for n in g.order],
                "ports": [s.describe() for s in t.ports.values()], "cameras": t.camera.names(),
                "clock": self.clock_state(), "camera": t.camera.state(), "stats": stats}


def gauges(t: LiveTwin) -> list[dict]:
    """The bindings the page draws: port, effect, domain, range (rad for a rotation)."""
    out = []
    if t.render_id is None:
        return out
    for ob in t.observed:
        for rec in ob.manifest.get("bindings", []):
            out.append({"tag": ob.tag, "port": f"{t.render_id}.{ob.state}.{rec['variable']}",
                        "effect": rec["effect"], "target": rec["target"], "domain": rec["domain"],
                        "range": rec.get("range") or [0.0, 1.0]})
    return out
