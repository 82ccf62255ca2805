"""Run one command and measure its wall time and peak memory.

`python -m pipeline.bench.measure LOG -- CMD...` runs CMD with its stdout in LOG.out and
its stderr in LOG.err, and prints one JSON line: {seconds, returncode, maxrss_bytes, tree_peak_bytes}.

- maxrss_bytes: resource.getrusage(RUSAGE_CHILDREN).ru_maxrss of this wrapper once CMD
  has exited, i.e. the peak RSS of the largest single process in CMD's tree (the
  kernel folds reaped grandchildren, the build's workers, into it). A fresh wrapper
  per command keeps one build's figure from leaking into the next one's.
- tree_peak_bytes: the largest SUM of the tree's RSS seen by a sampler every 0.1 s:
  what the workers hold at the same time (shared pages count once per process, so
  this overstates; ru_maxrss understates). Both are reported.

The sampler runs in a thread while the main thread waits, so the wall time is exact.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

PAGE = os.sysconf("SC_PAGE_SIZE")
# The kernel's list of each thread's children (/proc/PID/task/TID/children, where it
# keeps one): a walk down the measured tree reads a few files. Without it, every
# process's stat is read to find the tree: on a busy machine, hundreds of files ten
# times a second, CPU taken from the command being measured.
_CHILD_LISTS = os.path.exists(f"/proc/{os.getpid()}/task/{os.getpid()}/children")


def _children(pid: int) -> list[int]:
    """pid's child processes, from its threads' lists (a thread or process that has
    gone has none)."""
    try:
        threads = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return []
    kids: list[int] = []
    for tid in threads:
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                kids.extend(int(k) for k in f.read().split())
        except OSError:
            continue
    return kids


def _children_map() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        kids.setdefault(ppid, []).append(int(entry))
    return kids


def tree_rss(pid: int) -> int:
    """Sum of the resident set sizes (bytes) of pid and all its descendants."""
    kids = None if _CHILD_LISTS else _children_map()
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/statm") as f:
                total += int(f.read().split()[1]) * PAGE
        except OSError:
            pass
        todo.extend(_children(p) if kids is None else kids.get(p, []))
    return total


def measure(cmd: list[str], log: Path, env: dict | None = None, cwd: str | None = None) -> dict:
    peak = [0]
    log = Path(log)
    with open(f"{log}.out", "ab") as out, open(f"{log}.err", "ab") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env, cwd=cwd)
        done = threading.Event()

        def sample():
            while not done.is_set():
                peak[0] = max(peak[0], tree_rss(proc.pid))
                done.wait(0.1)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        code = proc.wait()
        seconds = time.perf_counter() - t0
        done.set()
        sampler.join()
    maxrss_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # Linux: kB
    return {"seconds": seconds, "returncode": code, "maxrss_bytes": maxrss_kb * 1024, "tree_peak_bytes": peak[0]}


def run_measured(cmd: list[str], log: Path, env: dict | None = None, cwd: str | None = None,
                 timeout: float | None = None) -> dict:
    """Run cmd under a fresh measuring wrapper (see module docstring); returns its dict."""
    wrapper = [sys.executable, "-m", "pipeline.bench.measure", str(log), "--", *cmd]
    proc = subprocess.run(wrapper, capture_output=True, text=True, env=env, cwd=cwd, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"measure wrapper failed: {proc.stderr.strip()[-400:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    log_path, sep, *command = sys.argv[1:]
    if sep != "--" or not command:
        sys.exit("usage: python -m pipeline.bench.measure LOG -- CMD...")
    print(json.dumps(measure(command, Path(log_path))))
