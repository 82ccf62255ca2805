"""Runs a task graph on an executor (worker processes by default), incrementally and safely.

- A task whose key matches the last build and whose outputs are in place is skipped;
  one whose key is in the cache is restored; the rest run in workers. A task's key
  is known once its dependencies are done: it holds the digest of what they made
  (graph.output_digest), so a rerun that made the same bytes stops there.
- Tasks run on an executor (engine.executors; by default a pool of spawned
  workers that serve many tasks each); the scheduler tells it how many tasks run at
  once and each one's share of the cores (`_worker_setup`), and a local pool when a
  task has waited long enough for a worker to start another (GROW_AFTER_S) while a
  core of the machine stood idle (GROW_IDLE_CORES).
- The build folder is locked (fcntl) for the whole build: a second build waits.
- Every output reaches build/ through the cache by temp-and-rename, and the state
  file is rewritten atomically after each task, so a killed build resumes cleanly.
- A failure fails its own task alone (keep going): a user error, a bug, memory
  refused, or the death of its worker. Its staging folder goes, so neither the
  cache nor build/ sees anything of it, and its state entry stays the last good
  one. The tasks that need it are blocked; a task that may stand on what the
  failed one made last (Task.previous_ok: the scene) runs on that instead.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import sys
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, Future, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import UserError
from ..files import atomic_write
from .cache import DEFAULT_LIMIT, Cache, cache_root
from .executors import ExecutorFactory, local_pool
from .worker import Workers, death, default_memory, died, pool_processes, run_task, warm_up
from .graph import FileHasher, Task, check_graph, explain, output_digest, record

STATE_FILE = ".state.json"
# A task that has waited this long for a busy worker gets a new one (a pool that starts
# workers on demand): less than a spawned worker takes to start and import a task's
# libraries, more than the short tasks of an edit's chain take to run.
GROW_AFTER_S = 0.25
# ... and only if this many of the machine's cores stood idle, on average, over that
# wait: on a machine whose cores are all busy (other builds, a test suite's other workers) a new
# worker's start-up takes its core from the tasks already running and runs nothing sooner.
GROW_IDLE_CORES = 0.5
LOCK_FILE = ".lock"


def idle_core_seconds() -> float | None:
    """CPU-seconds the machine's cores have stood idle (or waiting on I/O) since boot,
    from /proc/stat; None where there is no such file."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return (int(fields[4]) + int(fields[5])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


@dataclass
class BuildReport:
    explanations: list[dict] = field(default_factory=list)
    results: dict[str, dict] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    failed: list[tuple[str, str]] = field(default_factory=list)  # (task, error) of each task that failed
    errors: list[dict] = field(default_factory=list)  # each failure: task, error, and file, object, message, kind
    blocked: dict[str, list[str]] = field(default_factory=dict)  # task not run -> the failed tasks it needs
    cache: dict = field(default_factory=dict)  # what pruning the cache did (Cache.prune)

    @property
    def ran(self) -> list[str]:
        return [e["task"] for e in self.explanations if e["ran"]]


@dataclass
class _Build:
    """One build's state, as the scheduler's steps share it: what waits, runs and is
    done, what each finished task made, what failed, the pool and the report."""

    order: list[Task]
    state: dict  # the state file: each task's last good entry, the file hash memo
    hasher: FileHasher
    stop_on_error: bool
    report: BuildReport = field(default_factory=BuildReport)
    pending: dict[str, Task] = field(default_factory=dict)
    done: set[str] = field(default_factory=set)
    running: dict[Future, Task] = field(default_factory=dict)
    digests: dict[str, str] = field(default_factory=dict)  # what each finished task made (its dependents' keys hold it)
    remade: set[str] = field(default_factory=set)  # tasks run or restored in this build
    broken: dict[str, list[str]] = field(default_factory=dict)  # task without new outputs -> the failed tasks behind it
    suspects: set[str] = field(default_factory=set)  # in flight when a worker died: rerun one at a time
    warming: list[tuple[Future, tuple[str, ...]]] = field(default_factory=list)  # warm-ups sent to idle workers
    pool: Any = None  # started when the first task needs a worker (Scheduler._pool)
    threads: int | None = None  # cores per worker (Scheduler._worker_setup), set once per build
    dead: bool = False  # the pool refused a task: one of its workers died

    def __post_init__(self):
        self.pending = {t.name: t for t in self.order}


class BuildLock:
    """An exclusive lock on the build folder; a second build waits and says so."""

    def __init__(self, build: Path, wait: bool = True, notify=print):
        self.path = Path(build) / LOCK_FILE
        self.wait = wait
        self.notify = notify
        self.fd = None

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not self.wait:
                os.close(self.fd)
                raise UserError(self.path, None, "another build is using this build folder") from None
            self.notify(f"waiting for another build that holds {self.path}")
            fcntl.flock(self.fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


class Scheduler:
    def __init__(self, build: Path, cache: Path | None = None, jobs: int | None = None, progress=None,
                 executor: ExecutorFactory = local_pool, cache_limit: int | None = DEFAULT_LIMIT,
                 memory_limit: int | str | None = None, roots: dict[str, Path] | None = None):
        self.build = Path(build)
        # folders the tasks' inputs are named under in their keys (graph.input_name):
        # moving one of them changes no key
        self.roots = dict(roots or {})
        self.executor = executor
        self.cache = Cache(cache_root(self.build, cache))
        self.cache_limit = cache_limit  # bytes kept after a build that stored something (None: all)
        self.jobs = max(1, jobs or os.cpu_count() or 1)
        # each worker's address space in bytes (Workers.memory); "auto": its share of the machine
        self.memory_limit = default_memory(self.jobs) if memory_limit == "auto" else memory_limit
        # `jobs` is the build's share of the machine: at most that many cores busy, so
        # `--jobs 1` is one core (a shared CI runner's cap), not one worker with threads
        self.cores = max(1, min(self.jobs, os.cpu_count() or 1))
        self.progress = progress

    # --- state ------------------------------------------------------------------
    def _load_state(self) -> dict:
        try:
            return json.loads((self.build / STATE_FILE).read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return {"tasks": {}, "hashes": {}}

    def _save_state(self, state: dict) -> None:
        atomic_write(self.build / STATE_FILE, json.dumps(state, sort_keys=True, indent=1))

    def _fresh(self, previous: dict | None, key: str) -> bool:
        """Whether the last build ran this key and its outputs are still in place."""
        if not previous or previous.get("key") != key or "digest" not in previous:
            return False
        return all((self.build / rel).is_file() for rel in previous.get("files", []))

    def _place(self, task: Task, key: str) -> dict:
        """Restore a cache entry into build/ and drop files the task no longer makes."""
        meta = self.cache.restore(key, self.build)
        keep = set(meta["files"])
        for out in task.outputs:
            # a folder output ("x/") or a family of folders ("x__lod*"): the task owns
            # every file in them, so what its new run did not make goes
            folders = sorted(self.build.glob(out)) if out.endswith("*") else [self.build / out]
            for folder in folders:
                if not folder.is_dir():
                    continue
                for p in sorted(folder.rglob("*"), reverse=True):
                    rel = str(p.relative_to(self.build))
                    if p.is_file() and rel not in keep:
                        p.unlink()
                    elif p.is_dir() and not any(p.iterdir()):
                        p.rmdir()
                if not any(folder.iterdir()):
                    folder.rmdir()
        return meta

    def _worker_setup(self, order: list[Task], state: dict, hasher: FileHasher) -> int:
        """The cores per worker for native thread pools and fork_join.beside, from the
        tasks this build will run: split among the tasks that can start side by side.
        An edit that reruns one asset's chain gives its task every core of the build's
        share, a cold build gives each worker its part of it. A task after one that
        will run is counted as running too (whether it is cut off is known only then)."""
        digests: dict[str, str] = {}
        stale, names = [], set()
        for t in order:
            if t.problem is not None:  # fails without running (never keyed: its input may be huge)
                names.add(t.name)
                continue
            if names.intersection(t.deps):
                stale.append(t)
                names.add(t.name)
                continue
            previous = state["tasks"].get(t.name)
            key = self._key(t, hasher, digests, previous)
            if self._fresh(previous, key):
                digests[t.name] = previous["digest"]
            elif self.cache.has(key):
                digests[t.name] = output_digest(self.cache.meta(key)["files"])
            else:
                stale.append(t)
                names.add(t.name)
        width = sum(1 for t in stale if not names.intersection(t.deps))
        return max(1, self.cores // max(1, min(self.jobs, width)))

    def _key(self, task: Task, hasher: FileHasher, digests: dict[str, str], previous: dict | None) -> str:
        """The task's key, with the files its last run opened (Task.reads_in): as this
        build folder's state recorded them, else as the cache's last run of it did."""
        if task.reads_in is None or previous is not None:
            return task.compute_key(hasher, digests, self.build, self.roots, _opened(previous))
        base = task.compute_key(hasher, digests, self.build, self.roots)
        names = self.cache.opened_by(base)
        return task.compute_key(hasher, digests, self.build, self.roots, dict.fromkeys(names)) if names else base

    def _cpus(self) -> tuple[int, ...]:
        """The CPUs the workers are held to: the first `cores` this process may use
        when that is fewer than all of them, else none (no affinity set)."""
        if not hasattr(os, "sched_getaffinity"):
            return ()
        usable = sorted(os.sched_getaffinity(0))
        return tuple(usable[:self.cores]) if self.cores < len(usable) else ()

    # --- run --------------------------------------------------------------------
    def run(self, tasks: list[Task], stop_on_error: bool = False) -> BuildReport:
        """Build what is out of date. A task that fails (a user error, a bug, memory,
        its worker's death) fails alone: what depends on it is blocked, unless it
        stands on that dependency's last good outputs (Task.previous_ok), and
        everything else still runs. `stop_on_error`: start nothing after a failure."""
        order = check_graph(tasks)
        with BuildLock(self.build, notify=lambda m: print(m, file=sys.stderr)), self.cache.in_use(), _pipes_ignored():
            shutil.rmtree(self.build / ".staging", ignore_errors=True)
            state = self._load_state()
            b = _Build(order, state, FileHasher(state.get("hashes")), stop_on_error)
            try:
                self._loop(b)
            finally:
                self._close(b)
            if b.remade and self.cache_limit is not None:
                b.report.cache = self.cache.prune(self.cache_limit, {e["key"] for e in state["tasks"].values()})
        # in task order, not in the order workers happened to finish
        b.report.errors.sort(key=lambda e: e["task"])
        b.report.failed.sort()
        return b.report

    def _loop(self, b: _Build) -> None:
        """Start what is ready, wait for a task in flight, record it; until none is left."""
        while b.pending or b.running:
            self._dispatch(b)
            if b.dead and not b.running:  # nothing in flight to learn more from: a new pool
                self._drop_pool(b)
                continue
            if b.pool is not None and not b.dead:
                self._warm_idle(b)
            if not b.running:
                if b.pending:  # everything left waits on a failed task
                    continue
                break
            self._collect(b, self._wait(b))

    def _close(self, b: _Build) -> None:
        """The end of a build, however it ends: the pool stops, the state is saved, staging goes."""
        if b.pool is not None:
            b.pool.shutdown(wait=True, cancel_futures=True)
        b.state["hashes"] = b.hasher.kept()
        self._save_state(b.state)
        shutil.rmtree(self.build / ".staging", ignore_errors=True)

    # --- select and decide ------------------------------------------------------
    def _select(self, b: _Build) -> list[Task]:
        """The tasks whose dependencies are done: a dead worker's suspects first, then
        the longest, so a long task that becomes ready is not queued behind short ones."""
        ready = [t for t in b.pending.values() if all(d in b.done for d in t.deps)]
        return sorted(ready, key=lambda t: (t.name not in b.suspects, -t.cost, t.name))

    def _dispatch(self, b: _Build) -> None:
        """Decide each ready task in turn; stop when the pool refuses one (a worker died)."""
        ready = self._select(b)
        for task in ready:
            b.pending.pop(task.name)
            if not self._decide(b, task, ready):
                break

    def _decide(self, b: _Build, task: Task, ready: list[Task]) -> bool:
        """Fail (the planner refused it), block, keep (fresh), restore (cached), wait for
        a free worker, or submit `task`. False: the pool is broken, stop submitting."""
        if task.problem is not None:  # the planner found it cannot run
            self._fail(b, task, _as_failure(task.problem))
            b.done.add(task.name)
            return True
        stood_on, missing = self._stand_in(b, task)
        if missing:
            self._block(b, task, missing)
            b.done.add(task.name)
            return True
        previous = b.state["tasks"].get(task.name)
        self._key(task, b.hasher, b.digests, previous)
        if self._fresh(previous, task.key):
            self._keep(b, task, previous, stood_on)
        elif self.cache.has(task.key):
            self._restore(b, task, previous, stood_on)
        elif len(b.running) >= (1 if b.suspects else self.jobs):
            # while a dead worker's tasks are retried, one runs at a time
            b.pending[task.name] = task  # its turn comes when a worker is free
        else:
            return self._submit(b, task, previous, stood_on, ready)
        return True

    def _keep(self, b: _Build, task: Task, previous: dict, stood_on: list[str]) -> None:
        """A task the last build ran with this key, whose outputs are in place."""
        self.cache.used(task.key)
        why = explain(task, previous, False, b.digests)
        renewed = sorted(d for d in task.deps if d in b.remade)
        if renewed:  # they reran (or came from the cache) and made the same files
            why["cut_off_after"] = renewed
        b.report.explanations.append(_stood_on(why, stood_on))
        b.report.results[task.name] = previous.get("result", {})
        b.digests[task.name] = previous["digest"]
        b.done.add(task.name)
        self._tick(task)

    def _restore(self, b: _Build, task: Task, previous: dict | None, stood_on: list[str]) -> None:
        """A task whose key is in the cache: its outputs come from there."""
        b.remade.add(task.name)
        meta = self._place(task, task.key)
        b.report.explanations.append(_stood_on(explain(task, previous, True, b.digests), stood_on))
        self._finish(b.state, task, b.digests, meta, b.report)
        b.done.add(task.name)

    # --- submit and the pool ----------------------------------------------------
    def _submit(self, b: _Build, task: Task, previous: dict | None, stood_on: list[str], ready: list[Task]) -> bool:
        """Send `task` to a worker, into a fresh staging folder. False: the pool refused it."""
        b.remade.add(task.name)
        pool = self._pool(b)
        staging = self.build / ".staging" / task.key
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        # a task that starts with nothing running or waiting beside it gets every
        # core (what becomes ready later shares them)
        alone = not b.running and not any(t.name in b.pending for t in ready if t is not task)
        try:
            future = pool.submit(run_task, task.action, task.args, str(staging), self.cores if alone else b.threads)
        except BrokenExecutor:  # a worker died since the last wait: its pool is gone
            b.pending[task.name] = task
            b.dead = True
            return False
        b.running[future] = task
        b.report.explanations.append(_stood_on(explain(task, previous, False, b.digests), stood_on))
        return True

    def _pool(self, b: _Build):
        """The build's pool, started when the first task needs a worker (a build with
        every task fresh starts none); its cores per worker are set once per build."""
        if b.pool is None:
            if b.threads is None:
                b.threads = self._worker_setup(b.order, b.state, b.hasher)
            b.pool = self.executor(Workers(self.jobs, b.threads, self._cpus(), self.memory_limit, on_demand=True))
        return b.pool

    def _drop_pool(self, b: _Build) -> dict:
        """Shut a pool one of whose workers died (the next task starts a new one); the
        processes it had, whose exit codes say how the worker died (read before the
        shutdown, which forgets them)."""
        workers = pool_processes(b.pool)
        b.pool.shutdown(wait=True, cancel_futures=True)
        b.pool, b.warming, b.dead = None, [], False
        return workers

    # --- collect ----------------------------------------------------------------
    def _wait(self, b: _Build) -> list[Future]:
        """The futures that finished, in task order; all of them when a worker died
        (its pool goes with it: every task in flight ends now)."""
        finished = self._first_finished(b)
        if any(isinstance(f.exception(), BrokenExecutor) for f in finished):
            finished, _ = wait(list(b.running))
        return sorted(finished, key=lambda f: b.running[f].name)

    def _first_finished(self, b: _Build) -> set[Future]:
        """Wait for a task in flight to finish. While a task waits in the pool for a
        worker (more in flight than workers started), a pool that starts workers on
        demand (`grow`) gets one more each GROW_AFTER_S in which the machine had an
        idle core (a machine that cannot say grows it all the same)."""
        grow = getattr(b.pool, "grow", None)
        while True:
            queued = grow is not None and self._in_flight(b) > len(pool_processes(b.pool))
            idle = idle_core_seconds() if queued else None
            finished, _ = wait(list(b.running), timeout=GROW_AFTER_S if queued else None, return_when=FIRST_COMPLETED)
            if finished:
                return finished
            now = idle_core_seconds()
            if idle is None or now is None or now - idle >= GROW_IDLE_CORES * GROW_AFTER_S:
                grow()

    def _in_flight(self, b: _Build) -> int:
        """Tasks and warm-ups sent to the pool and not yet finished."""
        return len(b.running) + sum(not f.done() for f, _ in b.warming)

    def _collect(self, b: _Build, finished: list[Future]) -> None:
        """Record each finished task: its outputs, its failure, or its worker's death."""
        lost: list[Task] = []  # tasks whose worker died under them
        for fut in finished:
            task = b.running.pop(fut)
            out = _outcome(fut)
            if out is None:
                lost.append(task)
            elif out["ok"]:
                self._store(b, task, out)
            else:
                self._failed_run(b, task, out)
        if lost:
            self._worker_died(b, lost, self._drop_pool(b))

    def _store(self, b: _Build, task: Task, out: dict) -> None:
        """A task that ran: its staging folder into the cache, from there into build/."""
        b.suspects.discard(task.name)
        b.report.timings[task.name] = out["seconds"]
        staging = self.build / ".staging" / task.key  # named by the key it was submitted under
        task.settle(out["result"].get("opened", {}), b.digests)  # what it read enters its key
        if task.opened:
            self.cache.keep_opened(task.base_key, sorted(task.opened))
        self.cache.put(task.key, staging, out["result"])
        meta = self._place(task, task.key)
        self._finish(b.state, task, b.digests, meta, b.report)
        b.done.add(task.name)
        b.state["hashes"] = b.hasher.kept()
        self._save_state(b.state)

    def _failed_run(self, b: _Build, task: Task, out: dict) -> None:
        """A task that ran and failed: nothing of it is kept."""
        self._fail(b, task, out)
        b.suspects.discard(task.name)
        shutil.rmtree(self.build / ".staging" / task.key, ignore_errors=True)
        b.done.add(task.name)
        if b.stop_on_error:
            for waiting in list(b.pending.values()):
                if waiting.name not in b.suspects:
                    b.pending.pop(waiting.name)
                    self._block(b, waiting, waiting.deps, stopped=True)
                    b.done.add(waiting.name)

    # --- failures ---------------------------------------------------------------
    def _stand_in(self, b: _Build, task: Task) -> tuple[list[str], list[str]]:
        """(the failed dependencies whose last good outputs `task` runs on, those it is
        blocked by): it stands on those Task.previous_ok names whose last outputs are
        all in place. Those enter its key as the last build recorded them, so a scene
        made from them before is still up to date."""
        failed = [d for d in task.deps if d in b.broken]
        last = {d: b.state["tasks"].get(d) for d in failed}
        missing = [d for d, entry in last.items() if d not in task.previous_ok or not entry or "digest" not in entry
                   or not all((self.build / rel).is_file() for rel in entry.get("files", []))]
        if missing:
            return [], missing
        for d, entry in last.items():
            b.digests[d] = entry["digest"]
        return failed, []

    def _fail(self, b: _Build, task: Task, out: dict) -> None:
        """A task that made nothing: its error in the report, its last outputs left as they were."""
        report = b.report
        error = {"task": task.name, **{k: out[k] for k in ("file", "object", "message", "kind", "trace") if k in out}}
        error["error"] = out.get("user_error") or out.get("error") or "failed"
        report.errors.append(error)
        report.failed.append((task.name, error["error"]))
        if "trace" in out:
            report.results[task.name] = {"trace": out["trace"]}
        for why in report.explanations:
            if why["task"] == task.name:
                why["failed"] = error["error"]
                break
        else:  # it never started (the planner refused it)
            report.explanations.append({"task": task.name, "ran": False, "reason": "failed", "changed": [],
                                        "failed": error["error"]})
        b.broken[task.name] = [task.name]
        self._tick(task)

    def _block(self, b: _Build, task: Task, deps, stopped: bool = False) -> None:
        """A task not run because `deps`, tasks it needs, failed or were blocked in turn
        (or because the build stopped at a failure)."""
        behind = sorted({x for d in deps if d in b.broken for x in b.broken[d]})
        b.broken[task.name] = behind
        b.report.blocked[task.name] = behind
        reason = "not started: the build stopped at a failure" if stopped or not behind else \
            "blocked by " + ", ".join(behind)
        b.report.explanations.append({"task": task.name, "ran": False, "reason": reason, "changed": [],
                                      "blocked_by": behind})
        self._tick(task)

    def _worker_died(self, b: _Build, lost: list[Task], workers: dict) -> None:
        """A worker process died (killed, out of memory, a crash in native code) and its
        pool with it. A task that was running alone killed it: it fails. Tasks that were
        running side by side go back to wait and run one at a time until each has
        either finished or died alone."""
        for task in lost:
            shutil.rmtree(self.build / ".staging" / task.key, ignore_errors=True)
        if len(lost) == 1:
            task = lost[0]
            b.suspects.discard(task.name)
            self._fail(b, task, died(death(workers)))
            b.done.add(task.name)
            return
        names = {t.name for t in lost}
        b.report.explanations[:] = [e for e in b.report.explanations if e["task"] not in names]
        for task in lost:
            b.suspects.add(task.name)
            b.pending[task.name] = task

    def _warm_idle(self, b: _Build) -> None:
        """Workers left idle while the tasks still waiting depend on running ones import
        what the next of those will (Task.warm: of the tasks that wait on running ones
        alone): an edit runs its chain task by task, and each task would otherwise start
        in a worker that has not imported its libraries. A pool hands the next call to
        the worker that has waited longest, so the idle worker warmed now is the one the
        next task goes to. Each set of modules is sent once: warming every waiting
        task's modules at once would keep the idle worker busy past the next task's
        start, and an edit's source task would run in the worker that has just read the
        .blend, importing its own libraries. Only a started worker warms up: a pool that
        starts workers on demand would otherwise start one to import and wait."""
        workers = len(pool_processes(b.pool)) if hasattr(b.pool, "grow") else self.jobs
        idle = workers - self._in_flight(b)
        started = b.done | {t.name for t in b.running.values()}
        modules = tuple(dict.fromkeys(m for t in b.pending.values() if started.issuperset(t.deps) for m in t.warm))
        if idle <= 0 or not modules or any(sent == modules for _, sent in b.warming):
            return
        try:
            b.warming += [(b.pool.submit(warm_up, modules), modules) for _ in range(idle)]
        except BrokenExecutor:
            pass  # a worker died: the tasks in flight say so when they are waited for

    def _finish(self, state: dict, task: Task, digests: dict, meta: dict, report: BuildReport) -> None:
        entry = record(task, digests, meta["files"])
        entry["result"] = meta.get("result", {})
        digests[task.name] = entry["digest"]
        state["tasks"][task.name] = entry
        report.results[task.name] = entry["result"]
        self._tick(task)

    def _tick(self, task: Task) -> None:
        if self.progress is not None:
            self.progress(task)


@contextmanager
def _pipes_ignored():
    """SIGPIPE ignored for the build, as Python starts: a worker that dies leaves the
    pool's pipes to it without a reader, and writing to them must be an error the pool
    handles, not the end of the build. A library this process loaded may have reset
    it behind Python's back (gmsh's initialize does)."""
    import signal
    import threading

    if not hasattr(signal, "SIGPIPE") or threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGPIPE, before)


def _as_failure(problem: Exception) -> dict:
    """A planner's refusal as a worker's failure (worker.run_task)."""
    if isinstance(problem, UserError):
        return {"user_error": str(problem), "file": problem.file, "object": problem.obj, "message": problem.message}
    return {"error": f"{type(problem).__name__}: {problem}"}


def _opened(previous: dict | None) -> dict:
    """The files the task's last run opened beyond its inputs (Task.reads_in)."""
    return (previous or {}).get("opened") or {}


def _outcome(fut: Future) -> dict | None:
    """A finished task's result (worker.run_task), the executor's own failure as one,
    or None: its worker died."""
    try:
        return fut.result()
    except BrokenExecutor:
        return None
    except Exception as e:  # noqa: BLE001 - the executor's failure, not the build's
        return {"ok": False, "error": f"{type(e).__name__}: {e}"}


def _stood_on(why: dict, failed: list[str]) -> dict:
    """An explanation that names the failed dependencies whose last outputs the task used."""
    if failed:
        why["previous_of"] = failed
    return why

