"""Two independent parts of one task side by side, when its worker has a core to spare.

A cold build keeps every core busy with tasks of its own; an edit that reruns one
asset's chain leaves all but one idle. The scheduler tells each worker its share of
the cores (`SHARE_VARIABLE`, see scheduler.init_worker); with more than one, `beside`
runs a task's second part in a forked child while the first runs here. Forking hands
the child the task's data without pickling it; only the child's result comes back.

The outputs do not depend on it: both parts run the same code either way, and a child
that fails or dies is simply run again here, so its error surfaces as it would have.
"""

from __future__ import annotations

import os
import pickle
from typing import Callable, TypeVar

SHARE_VARIABLE = "TWIN_WORKER_CORES"

A = TypeVar("A")
B = TypeVar("B")


def cores_to_spare() -> bool:
    """Whether this process was given more than one core (by the scheduler)."""
    try:
        return int(os.environ.get(SHARE_VARIABLE, "1")) > 1
    except ValueError:
        return False


def beside(here: Callable[[], A], child: Callable[[], B]) -> tuple[A, B]:
    """(here(), child()): child in a forked process while here() runs, when this
    process has a core to spare and can fork; one after the other otherwise.
    child's result must pickle. Exceptions of either come out as from a plain call."""
    if not cores_to_spare() or not hasattr(os, "fork"):
        return here(), child()
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never return into the caller's stack
        os.close(read_end)
        status = 1
        try:
            payload = pickle.dumps(child(), protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(write_end, "wb") as pipe:
                pipe.write(payload)
            status = 0
        finally:
            os._exit(status)  # no atexit handlers of the parent's libraries (Blender's)
    os.close(write_end)
    try:
        first = here()
    finally:
        with os.fdopen(read_end, "rb") as pipe:
            payload = pipe.read()
        _, status = os.waitpid(pid, 0)
    if status == 0 and payload:
        return first, pickle.loads(payload)
    return first, child()  # it failed or died there: here, its error is the task's
