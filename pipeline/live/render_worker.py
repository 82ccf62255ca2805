"""Renders on request: one Blender process that loads the scene once and keeps it, each
request setting only the frame's own properties (seed, shown placements, switch joints,
camera, sun and sky, bound visuals) through the code `twin dataset` renders with
(datasets.run.open_scene and shoot), so a frame is byte-identical to the dataset's for
the same camera, instant, state and seed.

The process is spawned (Blender does not survive a fork), ends with its parent (also a
killed one: datasets.run.init_blender_process), and is started again after it dies."""

from __future__ import annotations

import io
import multiprocessing
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..datasets.plan import FramePlan
from ..render.sensor import PhoneCamera


class RenderError(RuntimeError):
    """A render that failed (the message says why); the twin goes on."""


@dataclass(frozen=True)
class RenderJob:
    build: str
    sources: str
    cam: PhoneCamera
    seed: int


def scene_tags(site) -> list[str]:
    """Every placement whose package has a glb: the scene the process keeps."""
    return sorted(p["tag"] for p in site.placements if p["asset"] in site.manifests
                  and (Path(site.build) / "models" / p["asset"] / f"{p['asset']}.glb").is_file())


class RenderWorker:
    def __init__(self, job: RenderJob, load_timeout_s: float = 1800.0):
        self.job, self.load_timeout_s = job, load_timeout_s
        self.proc = self.conn = None
        self.load_s: float | None = None
        self.renders = 0
        self.starts = 0
        self._lock = threading.Lock()  # one request at a time on the pipe

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None and self.proc.is_alive() else None

    def start(self) -> None:
        """Start the process; the scene loads in it while the twin runs."""
        if self.proc is not None and self.proc.is_alive():
            return
        ctx = multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, args=(child, self.job), name="twin-render", daemon=True)
        self.proc.start()
        child.close()
        self.load_s, self.starts = None, self.starts + 1

    def render(self, plan: FramePlan, mask: bool, depth: bool, timeout_s: float = 600.0) -> dict:
        """{"png", "mask" (PNG bytes or None), "depth" (.npy bytes or None), "record",
        "seconds"}; RenderError when it fails (the process is replaced if it died)."""
        with self._lock:
            self.start()
            if self.load_s is None:
                self.load_s = self._receive(self.load_timeout_s, "loading the scene")["load_s"]
            self.conn.send((plan, mask, depth))
            out = self._receive(timeout_s, "rendering")
            self.renders += 1
            return out

    def _receive(self, timeout_s: float, doing: str) -> dict:
        try:
            ready = self.conn.poll(timeout_s)
            if not ready:
                self._stop()
                raise RenderError(f"the render process took over {timeout_s:g} s {doing}: stopped, "
                                  "a new one starts with the next render")
            status, payload = self.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            code = self.proc.exitcode if self.proc is not None else None
            self._stop()
            raise RenderError(f"the render process died {doing} (exit code {code}): a new one starts with "
                              "the next render") from None
        if status != "ok":
            if status == "fatal":
                self._stop()
            raise RenderError(payload)
        return payload

    def _stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)
        self.proc = None
        self.load_s = None

    def close(self) -> None:
        """Ask the process to end, then make sure it has: no child left behind."""
        if self.proc is not None and self.proc.is_alive():
            try:
                self.conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            self.proc.join(10)
        self._stop()


def _serve(conn, job: RenderJob) -> None:
    """The Blender process: load, then answer (plan, mask, depth) requests until None."""
    import signal

    from ..datasets.run import encode_png, init_blender_process, open_scene, shoot
    from ..runtime.site import load_site

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the process group: the twin ends us
    _quiet()
    init_blender_process()
    t0 = time.perf_counter()
    try:
        site = load_site(Path(job.build), Path(job.sources))
        ctx = open_scene(site, job.cam, job.seed, scene_tags(site))
    except Exception as e:  # noqa: BLE001 - reported to the twin, which goes on without renders
        conn.send(("fatal", f"could not load the scene: {type(e).__name__}: {e}"))
        return
    conn.send(("ok", {"load_s": time.perf_counter() - t0}))
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            ctx["scene"].close()
            return
        plan, mask, depth = msg
        try:
            t0 = time.perf_counter()
            rgb, ids, dist, record = shoot(ctx, plan)
            npy = None
            if depth:
                import numpy as np

                buf = io.BytesIO()
                np.save(buf, dist, allow_pickle=False)
                npy = buf.getvalue()
            conn.send(("ok", {"png": encode_png(rgb[..., ::-1]), "mask": encode_png(ids) if mask else None,
                              "depth": npy, "record": record, "seconds": time.perf_counter() - t0}))
        except Exception as e:  # noqa: BLE001 - one failed frame; the scene stays loaded
            conn.send(("error", f"render failed: {type(e).__name__}: {e}"))


def _quiet() -> None:
    """Blender's importers print a line per object to stdout: into /dev/null, not into
    the twin's stdout (a pipe its caller may not read, whose full buffer would block this
    process). stderr stays: a crash's message is worth keeping."""
    import os
    import sys

    sys.stdout.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)
