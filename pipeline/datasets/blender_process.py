"""A Blender process, and the side that talks to it: how `twin dataset`'s workers and
`twin serve` run Blender.

`python -m pipeline.datasets.blender_process LOG IDLE` is a plain subprocess, not a
multiprocessing child, so it starts under a daemonic process too (a dask worker under
its nanny); Blender renders on the main thread of its process, which a dask worker's
task threads are not. The two speak over the process's stdin and the stdout it had
when it started, in multiprocessing.connection's framing (length-prefixed pickles):
a request names a function of this package and its arguments, `("module:function",
args)`; the reply is `("ok", result)`, `("user_error", file, object, message, more)` or
`("error", message, trace)`. The process keeps its module state between requests (a
loaded scene, frame.py), ends at the end of its stdin, after IDLE seconds without a
request (0: never), and as soon as the process that started it is gone. Blender's own
log (its file descriptors 1 and 2) goes to LOG ("": stdout to /dev/null, stderr kept).
Its temporary files (Blender's session folder) are in a folder its starter removes.

The dataset's side (`render_frame`): whatever runs a frame (a local pool's worker, a
dask worker's thread, the calling process) hands it to a Blender process of its own.
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path

from ..errors import UserError
from ..scratch import pool_folder, remove_folder

# the folder that holds the pipeline package: a Blender process imports it whatever
# the worker's working folder
_ROOT = str(Path(__file__).resolve().parents[2])

# a dataset's Blender process with no frame for this long ends (a worker of a shared
# cluster keeps none of a finished run's scenes); its worker replaces one idle for half of it
IDLE_SECONDS = 120.0
PACKAGE = "pipeline"  # what a request may call (this module runs as __main__ in the process)


class BlenderDied(RuntimeError):
    """The Blender process ended before it replied."""


class TooSlow(RuntimeError):
    """No reply within the time allowed: the process was stopped."""


class CallFailed(RuntimeError):
    """A bug in the called function, with the trace from the Blender process."""


# --- the side that starts it --------------------------------------------------------------


class BlenderProcess:
    """One Blender subprocess; `call` runs a function in it."""

    def __init__(self, log: str | None = None, idle_s: float = 0.0):

        self.log = log
        self.temp = pool_folder("twin_blender_")
        env = dict(os.environ, TMPDIR=self.temp)
        env["PYTHONPATH"] = os.pathsep.join([_ROOT, *filter(None, [env.get("PYTHONPATH")])])
        self.proc = subprocess.Popen([sys.executable, "-m", __name__, log or "", str(idle_s)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self._to = Connection(os.dup(self.proc.stdin.fileno()), readable=False)
        self._from = Connection(os.dup(self.proc.stdout.fileno()), writable=False)
        self.proc.stdin.close()
        self.proc.stdout.close()
        self.calls = 0
        self.used = time.monotonic()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def call(self, function: str, *args, timeout_s: float | None = None):
        """`function(*args)` in the process ("pipeline.module:name"): send, then reply."""
        self.send(function, *args)
        return self.reply(timeout_s)

    def send(self, function: str, *args) -> None:
        """Ask for `function(*args)`; `reply` waits for its result (one call at a time)."""
        self.used = time.monotonic()
        try:
            self._to.send((function, args))
        except OSError:
            self._died()

    def reply(self, timeout_s: float | None = None):
        """The result of the call sent last. A user error is raised as one; a bug raises
        CallFailed; BlenderDied or TooSlow (the process stopped) when no reply came."""
        try:
            if timeout_s is not None and not self._from.poll(timeout_s):
                self.kill()
                raise TooSlow(f"no reply in {timeout_s:g} s")
            reply = self._from.recv()
        except (EOFError, OSError):
            self._died()
        self.calls += 1
        self.used = time.monotonic()
        if reply[0] == "user_error":
            raise UserError(*reply[1:4], more=reply[4])
        if reply[0] == "error":
            raise CallFailed(f"{reply[1]}\n{reply[2]}")
        return reply[1]

    def _died(self):
        code = self.proc.wait()
        raise BlenderDied(f"the Blender process died (exit code {code})"
                          + (f"; Blender's log: {self.log}" if self.log else "")) from None

    def close(self, wait_s: float = 30.0) -> None:
        """End the process (the end of its stdin), killed when it takes over `wait_s`."""
        self._to.close()
        try:
            self.proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            self.kill()
        self._from.close()
        remove_folder(self.temp)

    def kill(self) -> None:
        if self.alive():
            self.proc.kill()
        self.proc.wait()
        remove_folder(self.temp)


# --- a dataset's frames, on whatever runs them --------------------------------------------

FRAME = "pipeline.datasets.frame:render"
_OWN = threading.local()  # the Blender process of this thread (a dask worker runs tasks on several)
_ALL: list[BlenderProcess] = []  # every one this process started, closed at its exit
_ALL_LOCK = threading.Lock()


def render_frame(job: dict, index: int, tasks_per_worker: int) -> dict:
    """Frame `index` of `job` in this thread's Blender process (started, or replaced
    after `tasks_per_worker` frames or when the job changes): {render_s, labels_s}. A
    user error is raised as one (engine.worker.run_task reports it); a bug or a dead
    Blender process raises."""
    blender = getattr(_OWN, "blender", None)
    key = json.dumps(job, sort_keys=True)
    if blender is not None and (_OWN.job != key or blender.calls >= tasks_per_worker or not blender.alive()
                                or time.monotonic() - blender.used > IDLE_SECONDS / 2):
        _retire(blender)
        blender = None
    if blender is None:
        blender = _OWN.blender = BlenderProcess(job.get("log"), IDLE_SECONDS)
        _OWN.job = key
        with _ALL_LOCK:
            if not _ALL:
                _close_at_exit()
            _ALL.append(blender)
    try:
        return blender.call(FRAME, job, index)
    except (BlenderDied, CallFailed, OSError):
        _retire(blender)
        raise


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


def main(log: str, idle_s: float) -> int:
    """Serve calls from stdin until it ends; replies on the stdout this process had
    when it started, Blender's log on `log`."""
    import signal

    # Ctrl-C reaches the whole process group: the process that started this one decides
    # when it ends (the end of stdin, or its own end)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    requests = Connection(os.dup(0), writable=False)
    replies = Connection(os.dup(1), readable=False)
    sys.stdout.flush()
    fd = os.open(log or os.devnull, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    os.dup2(fd, 1)
    if log:
        os.dup2(fd, 2)
    os.close(fd)
    _exit_with_parent()
    while idle_s <= 0 or requests.poll(idle_s):
        try:
            function, args = requests.recv()
        except EOFError:
            break
        replies.send(_serve(function, args))
    return 0


def _serve(function: str, args: tuple) -> tuple:
    try:
        module, name = function.split(":")
        if module != PACKAGE and not module.startswith(PACKAGE + "."):
            raise ValueError(f"{function}: not a function of {PACKAGE}")
        return ("ok", getattr(importlib.import_module(module), name)(*args))
    except UserError as e:
        return ("user_error", e.file, e.obj, e.message, e.more)
    except Exception as e:  # noqa: BLE001 - the caller reports it with what it asked for
        import traceback

        return ("error", f"{type(e).__name__}: {e}", traceback.format_exc())
    finally:
        sys.stdout.flush()
        sys.stderr.flush()


def _exit_with_parent() -> None:
    """End when the process that started this one is gone (a killed run, a dask worker
    closed by its nanny, a killed twin), even in the middle of a frame."""
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], float(sys.argv[2])))
