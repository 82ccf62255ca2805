"""A small task graph with cheap actions, to test the scheduler on its own.

sources/a.txt, sources/b.txt -> upper:a, upper:b (copy upper-cased, slowly if asked)
-> joined (concatenates both). Run as a script to build in a separate process.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from pipeline.engine.graph import Task
from pipeline.engine.scheduler import Scheduler
from pipeline.fork_join import SHARE_VARIABLE


def upper(staging: Path, src: str, name: str, delay: float = 0.0, meet: str | None = None) -> dict:
    """`meet`: a folder where each upper leaves its name and waits for the other's: the
    two run side by side, each in a worker of its own."""
    out = staging / "up" / f"{name}.txt"
    out.parent.mkdir(parents=True, exist_ok=True)
    text = Path(src).read_text().upper()
    with open(out, "w") as f:  # written in pieces so a kill can land mid-file
        for ch in text:
            f.write(ch)
            f.flush()
            if delay:
                time.sleep(delay)
    if meet is not None:
        _meet(Path(meet), name, ("a", "b"))
    return {"chars": len(text), "cores": os.environ.get(SHARE_VARIABLE), "cpus": _cpus()}


def _meet(folder: Path, name: str, everyone: tuple[str, ...], timeout_s: float = 300.0) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).touch()
    deadline = time.monotonic() + timeout_s
    while not all((folder / n).exists() for n in everyone):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{name} waited {timeout_s} s for {everyone} in {folder}")
        time.sleep(0.01)


def join(staging: Path, build: str, sep: str) -> dict:
    parts = [(Path(build) / "up" / f"{n}.txt").read_text() for n in ("a", "b")]
    out = staging / "joined.txt"
    out.write_text(sep.join(parts))
    return {"parts": 2, "cores": os.environ.get(SHARE_VARIABLE), "cpus": _cpus()}


def register_exit_handler(staging: Path, marker: str) -> dict:
    """An action that, as importing bpy does, registers an exit handler: it would
    write `marker` when its process exits normally."""
    import atexit

    atexit.register(Path(marker).write_text, "an exit handler of the task's ran")
    return {}


def whose(staging: Path, name: str, delay: float = 0.0) -> dict:
    """The process that ran it, after `delay` s, in out/<name>.txt and its result."""
    time.sleep(delay)
    (staging / "out").mkdir(parents=True, exist_ok=True)
    (staging / "out" / f"{name}.txt").write_text(str(os.getpid()))
    return {"pid": os.getpid()}


def die(staging: Path, **_) -> dict:
    """An action whose worker dies under it, as the kernel's out-of-memory killer
    ends a process (SIGKILL), after writing a part of an output."""
    import signal

    (staging / "up").mkdir(parents=True, exist_ok=True)
    (staging / "up" / "b.txt").write_text("HALF")
    os.kill(os.getpid(), signal.SIGKILL)
    return {}


def exhaust(staging: Path, src: str, name: str, **_) -> dict:
    """An action refused the memory it asks for, after writing a part of an output."""
    (staging / "up").mkdir(parents=True, exist_ok=True)
    (staging / "up" / f"{name}.txt").write_text("HALF")
    raise MemoryError


def refuse(staging: Path, src: str, name: str, **_) -> dict:
    """An action that finds its input bad (a user error naming the file and the object),
    after writing a part of an output."""
    from pipeline.errors import UserError

    (staging / "up").mkdir(parents=True, exist_ok=True)
    (staging / "up" / f"{name}.txt").write_text("HALF")
    raise UserError(src, "line 1", "not a word")


def sigpipe_state(staging: Path, src: str, name: str, **_) -> dict:
    """upper's output, and whether the process that runs it ignores SIGPIPE (under the
    in-process executor, the build's own process)."""
    import signal

    return {**upper(staging, src, name), "sigpipe_ignored": signal.getsignal(signal.SIGPIPE) == signal.SIG_IGN}


def _cpus() -> list[int] | None:
    """The CPUs the task's process may run on (None where the OS does not say)."""
    return sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None


def tasks(src: Path, build: Path, sep: str = "+", delay: float = 0.0, meet: Path | None = None) -> list[Task]:
    ups = [Task(name=f"upper:{n}", stage="assets", action=upper,
                args={"src": str(src / f"{n}.txt"), "name": n, "delay": delay,
                      **({"meet": str(meet)} if meet is not None else {})},
                inputs=(src / f"{n}.txt",), params={"n": n}, code="v1", outputs=(f"up/{n}.txt",))
           for n in ("a", "b")]
    joined = Task(name="join", stage="scene", action=join, args={"build": str(build), "sep": sep},
                  deps=("upper:a", "upper:b"), params={"sep": sep}, code="v1", outputs=("joined.txt",))
    return [*ups, joined]


def build(src: Path, out: Path, sep: str = "+", delay: float = 0.0, jobs: int = 2, cache: Path | None = None,
          meet: Path | None = None, **scheduler):
    return Scheduler(out, cache=cache, jobs=jobs, **scheduler).run(tasks(src, out, sep, delay, meet))


if __name__ == "__main__":
    src, out, delay = Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3])
    report = build(src, out, delay=delay)
    print("ran", " ".join(report.ran))
