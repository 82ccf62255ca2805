"""`twin serve`: the live twin put together from a build, its sources, a scenario (or the
default one), the start and speed of the clock, and the sensor renders are made with."""

from __future__ import annotations

import asyncio
import datetime as dt
import json
import platform
import sys
from importlib import metadata
from pathlib import Path

from ..errors import UserError
from ..render.sensor import PhoneCamera
from ..runtime import graph
from ..runtime.run import scene_zone
from ..runtime.site import load_site
from .camera import LiveCamera
from .clock import SimClock, check_speed, parse_instant
from .default_scenario import default_scenario
from .foxglove_io import FoxgloveLive, McapLog, Recorder
from .outside import GazeboOut, SignalsIn
from .render_worker import RenderJob, RenderWorker
from .server import LiveServer
from .twin import LiveTwin
from .wires import load_record

DEFAULT_SIZE = (640, 480)


def sensor_of(config: Path | None):
    """(PhoneCamera, PTZ presets, seed) of a dataset config's [sensor] and cameras, or the
    defaults at 640x480 without one."""
    if config is None:
        return PhoneCamera(width=DEFAULT_SIZE[0], height=DEFAULT_SIZE[1]), {}, None
    from ..datasets import config as dataset_config

    cfg = dataset_config.load(config)
    cam = PhoneCamera(width=cfg.sensor.width, height=cfg.sensor.height, samples=cfg.sensor.samples,
                      render_denoise=cfg.sensor.render_denoise)
    presets = {f"{c.mast}>{target}": (c.mast, target, zoom) for c in cfg.cameras if c.kind == "ptz"
               for target, zoom in c.presets}
    return cam, presets, cfg.seed


def make_server(build: Path, sources: Path, scenario: Path | None = None, *, speed: float = 1.0,
                start: str | None = None, bind: str = "127.0.0.1", port: int = 5555, sensor: Path | None = None,
                render: bool = True, step_s: float = 1.0, record: Path | None = None,
                foxglove: bool = True, inputs: Path | None = None, gazebo: str | None = None) -> LiveServer:
    build, sources = Path(build), Path(sources)
    site = load_site(build, sources)
    zone = scene_zone(build) or site.zone
    try:
        speed = check_speed(speed)
    except ValueError as e:
        raise UserError("--speed", None, str(e)) from None
    when = None
    if start is not None:
        try:
            when = parse_instant(start, zone)
        except ValueError as e:
            raise UserError("--start", None, str(e)) from None
    if scenario is not None:
        sc = graph.load_scenario(scenario, zone)
        if when is not None:
            sc.start = when.astimezone(dt.timezone.utc)
    else:
        now = dt.datetime.now(dt.timezone.utc).replace(microsecond=0)
        sc = default_scenario(site, when or now, step_s=step_s, wires=load_record(build))
    cam, presets, _ = sensor_of(sensor)
    try:
        twin = LiveTwin(sc, site, LiveCamera(site, presets))
    except ValueError as e:
        raise UserError(sc.path, None, str(e)) from None
    clock = SimClock(sc.start.astimezone(zone) if zone else sc.start, speed)
    signals_in = SignalsIn(inputs, twin.ports) if inputs else None
    gazebo_out = None
    if gazebo is not None:
        try:
            gazebo_out = GazeboOut(gazebo)
        except FileNotFoundError as e:
            raise UserError("--gazebo", None, str(e)) from None
    worker = None
    if render:
        worker = RenderWorker(RenderJob(str(build), str(sources), cam, sc.seed))
    sinks = []
    if record is not None:
        sinks.append(McapLog(record))
    if foxglove:
        try:
            sinks.append(FoxgloveLive(bind, port + 3 if port else 0))
        except Exception as e:  # noqa: BLE001 - the SDK's own error type: a port in use
            for s in sinks:
                s.close()
            raise UserError(f"{bind}:{port + 3}", None, f"cannot serve Foxglove's protocol: {e} (try --port 0)") from None
    recorder = Recorder(twin, sinks) if sinks else None
    info = {"versions": versions(), "site": {"origin": {"latitude_deg": site.origin[0], "longitude_deg": site.origin[1],
                                                       "height_m": site.origin[2]},
                                            "timezone": str(zone) if zone else None,
                                            "inspection_points": sorted(site.inspection)},
            "scene": {"build": str(build), "placements": len(site.placements),
                      "sensor": {"width": cam.width, "height": cam.height, "samples": cam.samples,
                                 "render_denoise": cam.render_denoise}}}
    return LiveServer(twin, clock, bind=bind, port=port, worker=worker, info=info, recorder=recorder,
                      inputs=signals_in, gazebo=gazebo_out)


def versions() -> dict:
    out = {"python": platform.python_version()}
    for name in ("substation-twin", "pyzmq", "websockets", "bpy", "mcap"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def serve(server: LiveServer) -> None:
    """Run until SIGINT, SIGTERM or `shutdown`; the endpoints go to stdout as one JSON line."""

    def ready(endpoints: dict) -> None:
        print(json.dumps(endpoints), flush=True)

    try:
        asyncio.run(server.run(ready))
    except OSError as e:
        raise UserError(f"{server.bind}:{server.port}", None, f"cannot serve: {e.strerror or e} (try --port 0)") from None
    except Exception as e:  # zmq's bind errors are not OSErrors
        if type(e).__name__ == "ZMQError":
            raise UserError(f"{server.bind}:{server.port}", None, f"cannot serve: {e} (try --port 0)") from None
        raise
    sys.stdout.flush()
