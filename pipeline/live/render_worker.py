"""Renders on request: one Blender process (datasets.blender_process, the process
`twin dataset`'s workers render in) that loads the scene once and keeps it, each request
setting only the frame's own properties (seed, shown placements, switch joints, camera,
sun and sky, bound visuals) through the code `twin dataset` shoots with
(datasets.frame.open_scene and shoot), so a frame is byte-identical to the dataset's for
the same camera, instant, state and seed.

The process ends with its parent (also a killed one) and is started again after it dies.
`load` and `render` below run in it."""

from __future__ import annotations

import io
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..datasets.blender_process import BlenderDied, BlenderProcess, CallFailed, TooSlow
from ..datasets.plan import FramePlan
from ..errors import UserError
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
        self.blender: BlenderProcess | None = None
        self.load_s: float | None = None
        self.renders = 0
        self.starts = 0
        self._lock = threading.Lock()  # one request at a time on the pipe

    @property
    def pid(self) -> int | None:
        return self.blender.pid if self.blender is not None and self.blender.alive() else None

    def start(self) -> None:
        """Start the process; the scene loads in it while the twin runs."""
        if self.blender is not None and self.blender.alive():
            return
        self._stop()
        self.blender = BlenderProcess()
        self.blender.send(f"{__name__}:load", self.job)
        self.load_s, self.starts = None, self.starts + 1

    def render(self, plan: FramePlan, mask: bool, depth: bool, timeout_s: float = 600.0) -> dict:
        """{"png", "mask" (PNG bytes or None), "depth" (.npy bytes or None), "record",
        "seconds"}; RenderError when it fails (the process is replaced if it died)."""
        with self._lock:
            if self.blender is not None and not self.blender.alive():  # since the last render: said once
                code = self.blender.proc.returncode
                self._stop()
                raise RenderError(f"the render process died between renders (exit code {code}): a new one "
                                  "starts with the next render")
            self.start()
            if self.load_s is None:
                self.load_s = self._reply("loading the scene", self.load_timeout_s)["load_s"]
            out = self._reply("rendering", timeout_s, f"{__name__}:render", plan, mask, depth)
            self.renders += 1
            return out

    def _reply(self, doing: str, timeout_s: float, *request) -> dict:
        """The reply to the call in flight, or to `request` (a function and its arguments)."""
        try:
            if request:
                self.blender.send(*request)
            return self.blender.reply(timeout_s)
        except TooSlow:
            self._stop()
            raise RenderError(f"the render process took over {timeout_s:g} s {doing}: stopped, "
                              "a new one starts with the next render") from None
        except BlenderDied:
            code = self.blender.proc.returncode
            self._stop()
            raise RenderError(f"the render process died {doing} (exit code {code}): a new one starts with "
                              "the next render") from None
        except (CallFailed, UserError) as e:
            if self.load_s is None:  # no scene: the next render starts from a new process
                self._stop()
                raise RenderError(f"could not load the scene: {str(e).splitlines()[0]}") from None
            raise RenderError(f"render failed: {str(e).splitlines()[0]}") from None

    def _stop(self) -> None:
        if self.blender is not None:
            self.blender.kill()
        self.blender = None
        self.load_s = None

    def close(self) -> None:
        """Ask the process to end, then make sure it has: no child left behind."""
        if self.blender is not None:
            self.blender.close(wait_s=10.0)
        self.blender = None
        self.load_s = None


# --- in the Blender process ---------------------------------------------------------------

_SCENE: dict = {}  # the loaded scene (datasets.frame.open_scene)


def load(job: RenderJob) -> dict:
    """Load the scene every render of this process shoots in."""
    from ..datasets.frame import open_scene
    from ..runtime.site import load_site

    t0 = time.perf_counter()
    site = load_site(Path(job.build), Path(job.sources))
    _SCENE.update(open_scene(site, job.cam, job.seed, scene_tags(site)))
    return {"load_s": time.perf_counter() - t0}


def render(plan: FramePlan, mask: bool, depth: bool) -> dict:
    from ..datasets.frame import encode_png, shoot

    t0 = time.perf_counter()
    shot = shoot(_SCENE, plan)
    npy = None
    if depth:
        import numpy as np

        buf = io.BytesIO()
        np.save(buf, shot["depth"], allow_pickle=False)
        npy = buf.getvalue()
    return {"png": encode_png(shot["rgb"][..., ::-1]), "mask": encode_png(shot["ids"]) if mask else None,
            "depth": npy, "record": shot["record"], "seconds": time.perf_counter() - t0}
