"""The live section: `twin serve` on the built sample, driven over its sockets as a
client would, each figure beside its goal (issue 34):

- step and publish latency (the step due on the clock -> its message sent, measured by
  the twin; sent -> received by a ZeroMQ subscriber) p50/p99 at 1 Hz and 30 Hz;
- command round trip p50/p99 of get (one port, every port) and set;
- render on request at 640x480 after a warm-up: a short `twin dataset` run's frames
  rendered again on request (their instant, camera, states, sky and seed), seconds
  against that run's steady frame in the same conditions, bytes compared, and the
  render process started once (no reload);
- set -> visible in the live page (Chromium), when a browser is installed;
- memory (RSS) over 10,000 steps and over renders: the twin's and its Blender process's.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .context import Context
from .dataset import CONFIG, _config

START = "2025-03-20T10:00:00"  # the site's wall clock: the sun up


def _serve(build: Path, sources: Path, *args) -> tuple[subprocess.Popen, dict]:
    root = Path(__file__).resolve().parents[2]
    log = tempfile.TemporaryFile("w+")  # its stderr, read only if it fails: a pipe nobody reads fills up
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "serve", "--out", str(build), "--sources",
                             str(sources), "--port", "0", "--start", START, "--no-foxglove", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=log, text=True, env=env)
    line = proc.stdout.readline()
    if not line:
        proc.wait(30)
        log.seek(0)
        raise RuntimeError(f"twin serve did not start: {log.read()[-2000:]}")
    return proc, json.loads(line)


def _stop(proc: subprocess.Popen, client) -> None:
    try:
        client("shutdown")
    except Exception:  # noqa: BLE001 - already gone: terminate below
        pass
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.terminate()
        proc.wait(30)
    client.close()


def _pcts(values) -> dict:
    v = np.asarray(list(values), float)
    if not len(v):
        return {"n": 0}
    return {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)), "max": float(v.max()),
            "n": int(len(v))}


def _rss(pid: int | None) -> int | None:
    import psutil

    try:
        return psutil.Process(pid).memory_info().rss if pid else None
    except psutil.NoSuchProcess:
        return None


def _latency(build: Path, sources: Path, hz: float, seconds: float, commands: int) -> dict:
    import zmq

    from ..live.client import LiveClient

    proc, ep = _serve(build, sources, "--no-render", "--step", 1.0 / hz)
    c = LiveClient(ep["commands"])
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.RCVTIMEO, 2000)
    sub.connect(ep["publish"])
    try:
        c("hello")
        time.sleep(0.5)
        while True:  # what queued while the subscription settled is stale: not a latency
            try:
                sub.recv(flags=zmq.NOBLOCK)
            except zmq.Again:
                break
        transport, t_end = [], time.monotonic() + seconds
        while time.monotonic() < t_end:
            try:
                raw = sub.recv()
            except zmq.Again:
                continue
            got = dt.datetime.now(dt.timezone.utc)
            sent = dt.datetime.fromisoformat(json.loads(raw)["wall_time"])
            transport.append((got - sent).total_seconds() * 1000.0)
        stats = c("hello")["stats"]
        trips = {}
        ports = [p["name"] for p in c("hello")["ports"]]
        settable = next(p for p in c("hello")["ports"] if p["settable"] and p["type"] == "float" and p.get("range"))
        lo, hi = settable["range"]
        for name, req in (("get_one", {"cmd": "get", "ports": ["sun.elevation"]}), ("get_all", {"cmd": "get"}),
                          ("set", None)):
            times = []
            for i in range(commands):
                r = req or {"cmd": "set", "values": {settable["name"]: lo + (hi - lo) * (i % 10) / 10}}
                t0 = time.perf_counter()
                c.sock.send(json.dumps(r).encode())
                reply = json.loads(c.sock.recv())
                times.append((time.perf_counter() - t0) * 1000.0)
                assert reply["ok"], reply
            trips[name] = _pcts(times)
        return {"hz": hz, "seconds": seconds, "ports": len(ports), "steps": stats["steps"],
                "load_average": list(os.getloadavg()),
                "step_due_to_sent_ms": stats["step_latency_ms"], "sent_to_subscriber_ms": _pcts(transport),
                "round_trip_ms": trips, "set_port": settable["name"]}
    finally:
        sub.close()
        _stop(proc, c)


def _reproduce(c, record: dict, ports: dict[str, str]) -> None:
    """Put the twin in a dataset frame's instant, camera, states and sky (test_live does
    the same on the tiny scene)."""
    from ..live.default_scenario import switch_node

    c("clock", action="pause")
    c("clock", action="seek", to=record["local_time"])
    cam = record["camera"]
    c("camera", pose=[v for row in cam["pose"] for v in row], zoom=cam["zoom"], target=cam["target"] or "")
    values = {ports[f"{tag}.{var}"]: v for tag, levels in record["states"]["oil_levels"].items()
              for var, v in levels.items() if f"{tag}.{var}" in ports}
    values |= {f"{switch_node(tag)}.value": position for tag, position in record["states"]["switches"].items()}
    values |= {"tau_atm.value": record["sky"]["tau_atm"], "aerosol.value": record["sky"]["aerosol_density"]}
    c("set", values=values)


def _renders(ctx: Context, build: Path, dataset: dict | None) -> dict:
    """The frames of a short dataset run, rendered again on request after a warm-up:
    seconds against the dataset's steady frame in the same conditions, and bytes."""
    from ..datasets.run import run_dataset
    from ..live.client import LiveClient

    width, height = ctx.pick((160, 120), (640, 480))
    frames = ctx.pick(3, 4)
    config = _config(ctx.sources / CONFIG, ctx.work / "live_sensor.toml", frames, width, height)
    out = ctx.work / "live_dataset"
    out.mkdir(parents=True)
    for sub in ("models", "scene"):
        (out / sub).symlink_to(build / sub)
    folder = run_dataset(config, out, sources=ctx.sources)
    timings = json.loads((folder / "timings.json").read_text())
    steady = float(np.median(sorted(timings["frame_s"])[:-1]))  # the slowest frame loaded the scene
    proc, ep = _serve(build, ctx.sources, "--sensor", config)
    c = LiveClient(ep["commands"], timeout_s=3600)
    try:
        hello = c("hello")
        ports = {f"{b['tag']}.{b['port'].rsplit('.', 1)[1]}": b["port"] for b in hello["scene"]["bindings"]}
        t0 = time.perf_counter()
        c("render")  # the warm-up: it waits for the scene to load
        first = time.perf_counter() - t0
        seconds, identical = [], 0
        for i in range(frames):
            record = json.loads((folder / "records" / f"{i:06d}.json").read_text())
            _reproduce(c, record, ports)
            t0 = time.perf_counter()
            reply, (png,) = c.call("render", seed=record["seed"])
            seconds.append(time.perf_counter() - t0)
            identical += png == (folder / "images" / f"{i:06d}.png").read_bytes()
        proc_info = c("hello")["stats"]["render_process"]
        median = float(np.median(seconds))
        return {"frame": f"{width}x{height}", "frames": frames, "first_render_s": first,
                "scene_load_s": proc_info["load_s"], "render_s": seconds, "render_median_s": median,
                "dataset_steady_frame_s": steady, "dataset_frame_s": timings["frame_s"],
                "dataset_section_steady_frame_s": (dataset or {}).get("runs", {}).get("local_1", {})
                .get("steady_frame_median_s"),
                "ratio_to_dataset": median / steady, "identical_to_dataset": identical,
                "process_starts": proc_info["starts"], "load_average": list(os.getloadavg()),
                "goal": "ratio <= 1.0, no scene reload (process_starts == 1)"}
    finally:
        _stop(proc, c)


def _memory(ctx: Context, build: Path, sources: Path, config: Path) -> dict:
    """RSS of the twin over 10,000 steps (1 s steps at 1000x), and of it and its Blender
    process over renders (at the sensor of `config`, a dataset config: a leak per render
    shows at any size)."""
    from ..live.client import LiveClient

    steps, renders = ctx.pick(2000, 10000), ctx.pick(10, 100)
    proc, ep = _serve(build, sources, "--sensor", config, "--speed", 1000)
    c = LiveClient(ep["commands"], timeout_s=3600)
    try:
        while c("hello")["stats"]["steps"] < steps // 10:
            time.sleep(0.1)
        base = _rss(proc.pid)
        t0 = time.perf_counter()
        while c("hello")["stats"]["steps"] < steps:
            time.sleep(0.2)
        stepped = time.perf_counter() - t0
        after_steps = _rss(proc.pid)
        c("clock", action="pause")
        c("render")
        worker = c("hello")["stats"]["render_process"]["pid"]
        base_twin, base_worker = _rss(proc.pid), _rss(worker)
        for i in range(renders - 1):
            c("set", values={"tau_atm.value": 0.1 + 0.3 * (i % 10) / 10})
            c("render")
        end_twin, end_worker = _rss(proc.pid), _rss(worker)
        growth = lambda a, b: (b - a) / a * 100.0 if a and b else None  # noqa: E731
        return {"steps": steps, "steps_per_s": (steps - steps // 10) / stepped, "rss_after_10pct_steps": base,
                "rss_after_steps": after_steps, "steps_growth_pct": growth(base, after_steps),
                "renders": renders, "twin_rss_growth_pct": growth(base_twin, end_twin),
                "blender_rss_after_first_render": base_worker, "blender_rss_end": end_worker,
                "blender_rss_growth_pct": growth(base_worker, end_worker), "goal": "RSS growth <= 5 %"}
    finally:
        _stop(proc, c)


def _page(build: Path, sources: Path, sets: int) -> dict:
    from ..live.client import LiveClient
    from ..viewer import check

    lacking = [n for n in check.missing() if n in ("node", "chromium", "playwright-core")]
    if lacking:
        return {"skipped": f"missing {', '.join(lacking)}"}
    proc, ep = _serve(build, sources, "--no-render")
    c = LiveClient(ep["commands"])
    page = None
    try:
        gauge = next((b for b in c("hello")["scene"]["bindings"] if b["effect"] == "rotate"), None)
        if gauge is None:
            return {"skipped": "no gauge in the scene"}
        driver = Path(__file__).resolve().parents[2] / "tools" / "live_check.mjs"
        page = subprocess.Popen([shutil.which("node"), str(driver), "--url", ep["page"], "--selector",
                                 f"#pointer-{gauge['tag']}-{gauge['target']}"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "CHROMIUM": str(check.chromium())})
        ready = json.loads(page.stdout.readline() or "{}")
        if not ready.get("ready"):
            return {"error": f"the page did not get ready: {ready}"}
        latencies = []
        for i in range(sets):
            page.stdin.write("watch\n")
            page.stdin.flush()
            time.sleep(0.2)
            sent = time.time()
            c("set", values={gauge["port"]: 10.0 + 80.0 * ((i * 37) % 10) / 10 + i * 0.01})
            seen = json.loads(page.stdout.readline())
            latencies.append(seen["at"] / 1000.0 - sent if "at" in seen else float("nan"))
        page.stdin.write("quit\n")
        page.stdin.flush()
        return {"set_to_page_ms": _pcts(1000.0 * np.array(latencies)), "gauge": gauge["port"], "goal": "<= 1000 ms"}
    finally:
        if page is not None:
            try:
                page.wait(30)
            except subprocess.TimeoutExpired:
                page.kill()
        _stop(proc, c)


def live_section(ctx: Context, dataset: dict | None = None) -> dict:
    build = ctx.built or ctx.out
    if not (build / "scene" / "placements.json").is_file():
        return {"skipped": "no built scene"}
    out: dict = {}
    commands = ctx.pick(200, 2000)
    # quick mode (the test suite's run) only shows the section works: three 1 Hz steps
    for hz, seconds in ((1.0, ctx.pick(3, 60)), (30.0, ctx.pick(3, 60))):
        out[f"at_{hz:g}_hz"] = _latency(build, ctx.sources, hz, seconds, commands)
    out["page"] = _page(build, ctx.sources, ctx.pick(3, 10))
    if not (ctx.sources / CONFIG).is_file():  # its sensor and PTZ presets drive the renders
        out["render"] = out["memory"] = {"skipped": f"no {CONFIG} in these sources"}
        return out
    out["render"] = _renders(ctx, build, dataset)
    out["memory"] = _memory(ctx, build, ctx.sources,
                            _config(ctx.sources / CONFIG, ctx.work / "live_memory.toml", 1, 160, 120))
    return out
