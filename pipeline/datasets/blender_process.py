"""A Blender process that renders a dataset's frames, and the worker side that talks to it.

Whatever runs a frame (a local pool's worker, a dask worker's thread, the calling
process) hands it to a Blender process of its own: `python -m
pipeline.datasets.blender_process LOG`, a plain subprocess, not a multiprocessing
child, so it starts under a daemonic process too (a dask worker under its nanny).
Blender renders on the main thread of its process, which a dask worker's task
threads are not.

The two speak JSON lines: a request {"job", "index"} on the process's stdin, one
reply line on the stdout it had when it started: {"ok": true, seconds of its parts} or
the frame's failure
as data (a user error with its file and object, or a bug with its trace). Blender's
own log (its file descriptors 1 and 2) goes to LOG. The process keeps its scene
between frames of one job (frame.py), is replaced after `tasks_per_worker` frames
(a long run's memory stays that of a fresh one), ends at the end of its stdin,
after IDLE_SECONDS without a frame, and as soon as the process that started it is
gone.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from ..errors import UserError

# the folder that holds the pipeline package: a Blender process imports it whatever
# the worker's working folder
_ROOT = str(Path(__file__).resolve().parents[2])

# a Blender process with no frame for this long ends (a worker of a shared cluster
# keeps none of a finished run's scenes); its worker replaces one idle for half of it
IDLE_SECONDS = 120.0


class FrameFailed(RuntimeError):
    """A frame's bug, with the trace from the Blender process."""


# --- the worker side ----------------------------------------------------------------------


class BlenderProcess:
    """One Blender subprocess, started for one job."""

    def __init__(self, job: dict):
        self.key = json.dumps(job, sort_keys=True)
        self.log = job.get("log") or os.devnull
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([_ROOT, *filter(None, [env.get("PYTHONPATH")])])
        self.proc = subprocess.Popen([sys.executable, "-m", "pipeline.datasets.blender_process", self.log],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, text=True)
        self.frames = 0
        self.used = time.monotonic()

    def render(self, job: dict, index: int) -> dict:
        self.used = time.monotonic()
        self.proc.stdin.write(json.dumps({"job": job, "index": index}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            code = self.proc.wait()
            raise FrameFailed(f"the Blender process died (exit code {code}); Blender's log: {self.log}")
        self.frames += 1
        self.used = time.monotonic()
        return json.loads(line)

    def close(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


_OWN = threading.local()  # the Blender process of this thread (a dask worker runs tasks on several)
_ALL: list[BlenderProcess] = []  # every one this process started, closed at its exit
_ALL_LOCK = threading.Lock()


def render_frame(job: dict, index: int, tasks_per_worker: int) -> dict:
    """Frame `index` of `job` in this thread's Blender process (started, or replaced
    after `tasks_per_worker` frames or when the job changes). A user error is raised
    as one (engine.worker.run_task reports it); a bug or a dead Blender process raises
    FrameFailed."""
    blender = getattr(_OWN, "blender", None)
    if blender is not None and (blender.key != json.dumps(job, sort_keys=True) or blender.frames >= tasks_per_worker
                                or blender.proc.poll() is not None
                                or time.monotonic() - blender.used > IDLE_SECONDS / 2):
        _retire(blender)
        blender = None
    if blender is None:
        blender = _OWN.blender = BlenderProcess(job)
        with _ALL_LOCK:
            if not _ALL:
                _close_at_exit()
            _ALL.append(blender)
    t0 = time.perf_counter()
    try:
        reply = blender.render(job, index)
    except (FrameFailed, OSError, ValueError):
        _retire(blender)
        raise
    if reply.get("user_error") is not None:
        raise UserError(reply["file"], reply["object"], reply["message"])
    if not reply["ok"]:
        raise FrameFailed(f"{reply['error']}\n{reply.get('trace', '')}")
    return {**{k: v for k, v in reply.items() if k != "ok"}, "seconds": time.perf_counter() - t0}


def _retire(blender: BlenderProcess) -> None:
    blender.close()
    if getattr(_OWN, "blender", None) is blender:
        _OWN.blender = None
    with _ALL_LOCK:
        if blender in _ALL:
            _ALL.remove(blender)


def _close_all() -> None:
    with _ALL_LOCK:
        left = list(_ALL)
        _ALL.clear()
    for blender in left:
        blender.close()


def _close_at_exit() -> None:
    """Close the Blender processes when this process ends in order: in a pool's
    worker through multiprocessing's finalizers, which run before the exit handlers
    (engine.worker ends a worker with os._exit from one of those), elsewhere at exit."""
    import atexit
    import multiprocessing.util

    multiprocessing.util.Finalize(None, _close_all, exitpriority=10)
    atexit.register(_close_all)


# --- the Blender process ------------------------------------------------------------------


def main(log: str) -> int:
    """Serve frames from stdin until it ends; replies on the stdout this process had
    when it started, Blender's log on `log`."""
    replies = os.fdopen(os.dup(1), "w")
    fd = os.open(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    _exit_with_parent()
    from . import frame

    import select

    # one request in flight at a time (the worker waits for its reply): none waits in
    # stdin's buffer unseen by select
    while select.select([sys.stdin], [], [], IDLE_SECONDS)[0]:
        line = sys.stdin.readline()
        if not line:
            break
        request = json.loads(line)
        replies.write(json.dumps(_serve(frame.render, request["job"], request["index"])) + "\n")
        replies.flush()
    return 0


def _serve(render, job: dict, index: int) -> dict:
    try:
        return {"ok": True, **(render(job, index) or {})}
    except UserError as e:
        return {"ok": False, "user_error": str(e), "file": e.file, "object": e.obj, "message": e.message}
    except Exception as e:  # noqa: BLE001 - the worker reports it with the frame it stopped at
        import traceback

        return {"ok": False, "error": f"{type(e).__name__}: {e}", "trace": traceback.format_exc()}
    finally:
        sys.stdout.flush()
        sys.stderr.flush()


def _exit_with_parent() -> None:
    """End when the process that started this one is gone (a killed run, a dask worker
    closed by its nanny), even in the middle of a frame."""
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
