"""Fork-join over spare cores: independent parts of one task side by side, when its
worker has a core to spare.

A cold build keeps every core busy with tasks of its own; an edit that reruns one
asset's chain leaves all but one idle. The scheduler tells each worker its share of
the cores (`SHARE_VARIABLE`, see engine.worker.init_worker); with more than one, `beside`
runs a task's second part in a forked child while the first runs here, and `spread`
runs each part after the first in a child of its own. Forking hands a child the
task's data without pickling it; only the child's result comes back.

The outputs do not depend on it: every part runs the same code either way, and a
child that fails or dies is simply run again here, so its error surfaces as it would
have.
"""

from __future__ import annotations

import os
import pickle
from typing import Callable, TypeVar

SHARE_VARIABLE = "TWIN_WORKER_CORES"

A = TypeVar("A")
B = TypeVar("B")
T = TypeVar("T")


def core_share() -> int:
    """The cores this process was given (by the scheduler), at least 1."""
    try:
        return max(1, int(os.environ.get(SHARE_VARIABLE, "1")))
    except ValueError:
        return 1


def cores_to_spare() -> bool:
    """Whether this process was given more than one core (by the scheduler)."""
    return core_share() > 1


def beside(here: Callable[[], A], child: Callable[[], B]) -> tuple[A, B]:
    """(here(), child()): child in a forked process while here() runs, when this
    process has a core to spare and can fork; one after the other otherwise.
    child's result must pickle. Exceptions of either come out as from a plain call."""
    first, second = spread([here, child])
    return first, second


def spread(parts: list[Callable[[], T]]) -> list[T]:
    """[part() for part in parts]: the first here and each of the others in a forked
    child of its own, when this process has a core to spare and can fork; one after
    the other otherwise. More parts than cores share them (the OS interleaves; the
    wall time is about the sum over the cores). Results must pickle; an exception of
    any part comes out as from a plain call, the first part's first."""
    if len(parts) < 2 or not cores_to_spare() or not hasattr(os, "fork"):
        return [part() for part in parts]
    children = [_fork(part) for part in parts[1:]]
    try:
        first = parts[0]()
    finally:
        payloads = [_collect(pid, read_end) for pid, read_end in children]
    # a part that failed or died there runs again here, so its error is the task's
    return [first] + [pickle.loads(payload) if payload is not None else part()
                      for part, payload in zip(parts[1:], payloads)]


def _fork(part: Callable[[], object]) -> tuple[int, int]:
    """Start part() in a forked child; (its pid, the pipe its pickled result comes on)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never return into the caller's stack
        os.close(read_end)
        status = 1
        try:
            payload = pickle.dumps(part(), protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(write_end, "wb") as pipe:
                pipe.write(payload)
            status = 0
        finally:
            os._exit(status)  # no atexit handlers of the parent's libraries (Blender's)
    os.close(write_end)
    return pid, read_end


def _collect(pid: int, read_end: int) -> bytes | None:
    """A forked part's pickled result, or None when it failed or died."""
    with os.fdopen(read_end, "rb") as pipe:
        payload = pipe.read()
    _, status = os.waitpid(pid, 0)
    return payload if status == 0 and payload else None
