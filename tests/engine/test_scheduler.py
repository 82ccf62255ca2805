"""The scheduler on a toy graph: incremental, cached, locked, kill-safe."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import toy_graph
from helpers import ROOT, TESTS


def test_cold_then_noop(src, tmp_path):
    out = tmp_path / "build"
    r1 = toy_graph.build(src, out)
    assert sorted(r1.ran) == ["join", "upper:a", "upper:b"]
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"
    r2 = toy_graph.build(src, out)
    assert r2.ran == []
    assert {e["reason"] for e in r2.explanations} == {"up to date"}


def test_edit_reruns_only_its_chain(src, tmp_path):
    out = tmp_path / "build"
    toy_graph.build(src, out)
    (src / "a.txt").write_text("ALPHA2")
    r = toy_graph.build(src, out)
    assert sorted(r.ran) == ["join", "upper:a"]
    why = {e["task"]: e for e in r.explanations}
    assert why["upper:a"]["changed"] == [f"input {os.path.relpath(src / 'a.txt', out)}"]
    assert why["join"]["changed"] == ["dependency upper:a"]
    assert (out / "joined.txt").read_text() == "ALPHA2+BETA"


def test_a_rerun_that_makes_the_same_bytes_stops_the_chain(src, tmp_path):
    """Early cutoff: a dependency enters a key by what it made, not by its own key."""
    out = tmp_path / "build"
    toy_graph.build(src, out)
    (src / "a.txt").write_text("ALPHA")  # a new input that upper-cases to the same text
    r = toy_graph.build(src, out)
    assert r.ran == ["upper:a"]
    join = {e["task"]: e for e in r.explanations}["join"]
    assert join["reason"] == "up to date" and join["cut_off_after"] == ["upper:a"]

    graph = toy_graph.tasks(src, out)
    for t in graph:  # new code for both upper tasks, same output: join stays up to date
        t.code = "v2" if t.name.startswith("upper:") else t.code
    from pipeline.engine.scheduler import Scheduler
    r = Scheduler(out).run(graph)
    assert sorted(r.ran) == ["upper:a", "upper:b"]
    assert [e["changed"] for e in r.explanations if e["ran"]] == [["code"], ["code"]]
    (src / "b.txt").write_text("gamma")  # a real change still goes all the way
    r = Scheduler(out).run(toy_graph.tasks(src, out))
    assert sorted(r.ran) == ["join", "upper:b"]
    assert {e["task"]: e["reason"] for e in r.explanations}["upper:a"] == "restored from cache"  # code v1 again
    assert (out / "joined.txt").read_text() == "ALPHA+GAMMA"


def test_same_content_new_mtime_runs_nothing(src, tmp_path):
    out = tmp_path / "build"
    toy_graph.build(src, out)
    os.utime(src / "a.txt", (1, 1))  # what a fresh CI checkout does to every file
    assert toy_graph.build(src, out).ran == []


def test_parameter_change_reruns_what_uses_it(src, tmp_path):
    out = tmp_path / "build"
    toy_graph.build(src, out)
    r = toy_graph.build(src, out, sep="-")
    assert r.ran == ["join"]
    assert [e["changed"] for e in r.explanations if e["ran"]] == [["parameters"]]


def test_shared_cache_fills_an_empty_build(src, tmp_path):
    cache = tmp_path / "cache"
    toy_graph.build(src, tmp_path / "b1", cache=cache)
    r = toy_graph.build(src, tmp_path / "b2", cache=cache)
    assert r.ran == []
    assert {e["reason"] for e in r.explanations} == {"restored from cache"}
    assert (tmp_path / "b2" / "joined.txt").read_text() == "ALPHA+BETA"


def test_in_process_executor_makes_what_the_pool_makes(src, tmp_path):
    """The executor decides where tasks run, never what they make: the keys do not name
    it, so a pool build after an in-process one finds nothing to do."""
    from pipeline.engine.executors import in_process
    from pipeline.engine.scheduler import Scheduler

    pool_out, here_out = tmp_path / "pool", tmp_path / "here"
    toy_graph.build(src, pool_out)
    r = Scheduler(here_out, executor=in_process).run(toy_graph.tasks(src, here_out))
    assert sorted(r.ran) == ["join", "upper:a", "upper:b"]
    assert set(r.timings) == {"join", "upper:a", "upper:b"}
    for rel in ("up/a.txt", "up/b.txt", "joined.txt"):
        assert (here_out / rel).read_bytes() == (pool_out / rel).read_bytes()
    assert toy_graph.build(src, here_out).ran == []


def test_in_process_executor_reports_a_task_error_like_the_pool(src, tmp_path):
    from pipeline.engine.executors import in_process
    from pipeline.engine.scheduler import Scheduler

    (src / "b.txt").unlink()  # upper:b's action fails reading it: a bug's trace, not a crash
    tasks = toy_graph.tasks(src, tmp_path / "build")
    tasks[1].inputs = ()
    r = Scheduler(tmp_path / "build", executor=in_process).run(tasks)
    assert [name for name, _ in r.failed] == ["upper:b"] and "FileNotFoundError" in r.failed[0][1]
    assert "Traceback" in r.results["upper:b"]["trace"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_any_concurrent_futures_executor_runs_the_graph(src, tmp_path, jobs):
    """A third-party engine plugs in as a concurrent.futures.Executor (a thread pool
    stands for one here); the scheduler never has more tasks in flight than it asked for."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.engine.scheduler import Scheduler

    class Counting(ThreadPoolExecutor):
        def __init__(self, workers):
            super().__init__(max_workers=4)  # more than asked: the scheduler is the limit
            self.workers, self.active, self.peak, self.lock = workers, 0, 0, threading.Lock()

        def submit(self, fn, /, *args, **kwargs):
            def counted():
                with self.lock:
                    self.active += 1
                    self.peak = max(self.peak, self.active)
                try:
                    return fn(*args, **kwargs)
                finally:
                    with self.lock:
                        self.active -= 1
            return super().submit(counted)

    made = []
    out = tmp_path / "build"
    r = Scheduler(out, jobs=jobs, executor=lambda w: made.append(Counting(w)) or made[-1]).run(
        toy_graph.tasks(src, out, delay=0.02))
    assert sorted(r.ran) == ["join", "upper:a", "upper:b"]
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"
    assert len(made) == 1 and made[0].workers.count == jobs
    assert made[0].peak == jobs  # both upper tasks at once with two, one at a time with one
    assert Scheduler(out, jobs=jobs, executor=lambda w: made.append(w)).run(toy_graph.tasks(src, out)).ran == []
    assert len(made) == 1  # a no-op build starts no executor


def _run_script(src, out, delay):
    env = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{ROOT}")
    return subprocess.Popen([sys.executable, str(TESTS / "toy_graph.py"), str(src), str(out), str(delay)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _leftovers(out: Path) -> list[Path]:
    return [p for p in out.rglob("*") if ".tmp-" in p.name or p.parent.name == ".staging"]


@pytest.mark.parametrize("kill_after", [0.3, 1.2, 2.5])
def test_sigkill_at_any_point_recovers(src, tmp_path, kill_after):
    out = tmp_path / "build"
    proc = _run_script(src, out, delay=0.05)
    time.sleep(kill_after)
    os.killpg(proc.pid, signal.SIGKILL)  # the build and its workers, mid-write
    proc.wait()
    for p in [out / "up" / "a.txt", out / "up" / "b.txt", out / "joined.txt"]:
        if p.exists():  # outputs are whole or absent, never half-written
            assert p.read_text() in ("ALPHA", "BETA", "ALPHA+BETA"), p
    toy_graph.build(src, out)
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"
    assert (out / "up" / "a.txt").read_text() == "ALPHA"
    assert not _leftovers(out)
    assert toy_graph.build(src, out).ran == []


def test_second_concurrent_build_waits(src, tmp_path):
    out = tmp_path / "build"
    first = _run_script(src, out, delay=0.3)
    time.sleep(1.0)
    second = _run_script(src, out, delay=0.02)
    o1, e1 = first.communicate(timeout=120)
    o2, e2 = second.communicate(timeout=120)
    assert first.returncode == 0 and second.returncode == 0, e1 + e2
    assert "waiting for another build" in e2
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"
    assert o2.strip() == "ran"  # the second found the first's work complete


@pytest.mark.parametrize("costly", ["a", "b"])
def test_longest_task_starts_first(src, tmp_path, costly):
    """A worker takes the costliest ready task, whatever the names' order."""
    from pipeline.engine.scheduler import Scheduler

    graph = toy_graph.tasks(src, tmp_path / "build")
    for t in graph:
        t.cost = 10.0 if t.name == f"upper:{costly}" else 1.0
    report = Scheduler(tmp_path / "build", jobs=1).run(graph)
    other = "b" if costly == "a" else "a"
    assert [e["task"] for e in report.explanations] == [f"upper:{costly}", f"upper:{other}", "join"]
    assert (tmp_path / "build" / "joined.txt").read_text() == "ALPHA+BETA"


def test_a_worker_exits_before_the_exit_handlers_its_tasks_registered(tmp_path):
    """bpy registers an exit handler when a worker's first read of a .blend imports it
    (Blender's clean-up: a quarter of a second per worker, waited for at the end of
    every build); the worker's own quick exit stays the last handler registered, so it
    runs first and the others never do."""
    from pipeline.engine.executors import local_pool
    from pipeline.engine.worker import Workers, run_task

    marker = tmp_path / "marker"
    pool = local_pool(Workers(count=1, threads=1))
    out = pool.submit(run_task, toy_graph.register_exit_handler, {"marker": str(marker)}, str(tmp_path)).result()
    pool.shutdown(wait=True)
    assert out["ok"] and not marker.exists()


def test_thread_share_follows_what_can_run_side_by_side(src, tmp_path, monkeypatch):
    """Native thread pools: each worker gets cores / tasks that can start together."""
    from pipeline.engine.graph import FileHasher, check_graph
    from pipeline.engine.worker import init_worker
    from pipeline.engine.scheduler import Scheduler
    from pipeline.fork_join import SHARE_VARIABLE

    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    out = tmp_path / "build"

    def share(jobs: int | None) -> int:
        sched = Scheduler(out, jobs=jobs)
        state = sched._load_state()
        return sched._worker_setup(check_graph(toy_graph.tasks(src, out)), state, FileHasher(state.get("hashes")))

    # cold: both upper tasks start at once; --jobs caps the cores the build may use
    assert (share(None), share(2), share(1)) == (2, 1, 1)
    toy_graph.build(src, out)
    (src / "a.txt").write_text("changed")
    # one chain, upper:a then join: one task at a time gets the build's whole share
    assert (share(None), share(2), share(1)) == (4, 2, 1)

    for name in ("IGL_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")  # the user's setting is kept
    monkeypatch.setenv(SHARE_VARIABLE, "1")  # restored after the test: init_worker sets it
    init_worker(3)
    assert (os.environ["IGL_NUM_THREADS"], os.environ["OMP_NUM_THREADS"], os.environ["OPENBLAS_NUM_THREADS"],
            os.environ[SHARE_VARIABLE]) == ("3", "3", "1", "3")


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="needs two CPUs")
def test_a_task_that_starts_alone_gets_every_core(src, tmp_path):
    """A cold build splits the cores between the tasks that start together; the last
    task, with nothing beside it, is given them all for its side-by-side parts."""
    report = toy_graph.build(src, tmp_path / "build", jobs=2)
    assert [report.results[n]["cores"] for n in ("upper:a", "upper:b", "join")] == ["1", "1", "2"]
    (src / "b.txt").write_text("beta, edited")  # an edit: its one chain runs task by task, each alone
    report = toy_graph.build(src, tmp_path / "build", jobs=2)
    assert [report.results[n]["cores"] for n in ("upper:b", "join")] == ["2", "2"]


def _affinity() -> list[int]:
    return sorted(os.sched_getaffinity(0))


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two usable CPUs")
def test_build_given_fewer_cores_holds_its_workers_to_them(tmp_path):
    """fcpw starts a thread per core it sees: `--jobs 1` must still be one core."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from pipeline.engine.worker import init_worker
    from pipeline.engine.scheduler import Scheduler

    usable = _affinity()
    assert Scheduler(tmp_path / "b", jobs=1)._cpus() == (usable[0],)
    assert Scheduler(tmp_path / "b", jobs=len(usable))._cpus() == ()  # the whole machine: no affinity
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=init_worker,
                             initargs=(1, (usable[0],))) as pool:
        assert pool.submit(_affinity).result() == [usable[0]]


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two usable CPUs")
def test_a_one_core_task_keeps_to_a_cpu_of_its_own(src, tmp_path):
    """Two tasks side by side each run on their own CPU (fcpw's threads of one would
    otherwise wait on the other's); a task alone runs on all of the build's."""
    import dataclasses

    from pipeline.engine.executors import local_pool

    def two_workers(workers):
        # a worker for each task in flight, however busy the machine: the build's own
        # pool grows only onto an idle core, and a test suite's other workers leave none
        return local_pool(dataclasses.replace(workers, on_demand=False))

    usable = _affinity()
    # both uppers run at once: each waits for the other
    report = toy_graph.build(src, tmp_path / "build", jobs=2, meet=tmp_path / "meet", executor=two_workers)
    a, b = (report.results[n]["cpus"] for n in ("upper:a", "upper:b"))
    assert len(a) == 1 and len(b) == 1 and a != b and set(a + b) <= set(usable)
    assert report.results["join"]["cpus"] == usable


def test_init_worker_in_a_main_process_keeps_its_exit_code():
    """Workers skip the interpreter's exit clean-up (os._exit); a main process that
    calls init_worker (a test does) must still exit with its own code."""
    code = "import sys; from pipeline.engine.worker import init_worker; init_worker(1); sys.exit(3)"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=120)
    assert proc.returncode == 3


def test_a_build_on_a_shared_cache_leaves_another_builds_temporary_entries(tmp_path):
    """Two build folders, one --cache: the second build to start must not sweep the
    entry the first is writing; once alone, a build sweeps what a killed one left."""
    from pipeline.engine.cache import Cache

    root = tmp_path / "cache"
    with Cache(root).in_use():
        (root / ".tmp-being-written").mkdir()
        (root / ".tmp-memo.npz").write_bytes(b"half")
        with Cache(root).in_use():
            assert (root / ".tmp-being-written").is_dir() and (root / ".tmp-memo.npz").is_file()
    with Cache(root).in_use():
        assert not list(root.glob(".tmp-*"))


def test_code_version_follows_the_pinned_libraries(monkeypatch):
    """A new pin of a geometry library reruns the tasks: its results are theirs."""
    from pipeline.engine import code

    pins = code.pinned_libraries()
    assert any(p.startswith("meshoptimizer==") for p in pins) and any(p.startswith("bpy==") for p in pins)
    before = code.code_of("pipeline.geometry.lod")
    bumped = [p if not p.startswith("meshoptimizer==") else "meshoptimizer==9.9.9" for p in pins]
    monkeypatch.setattr(code, "pinned_libraries", lambda: bumped)
    assert code.code_of("pipeline.geometry.lod") != before
    monkeypatch.setattr(code, "pinned_libraries", lambda: pins)
    assert code.code_of("pipeline.geometry.lod") == before


def _entries(cache: Path) -> set[str]:
    return {p.parent.name for p in cache.glob("*/*/meta.json")}


def test_the_cache_keeps_within_its_limit_dropping_what_was_used_longest_ago(src, tmp_path):
    """After a build that stored something, the least recently used entries go until
    the cache is within its limit; the build folder's own entries never do, so the
    next build has everything it needs, and an undone edit runs again."""
    out, cache = tmp_path / "build", tmp_path / "build" / ".cache"
    toy_graph.build(src, out)
    first = _entries(cache)
    (src / "a.txt").write_text("alpha, edited")
    toy_graph.build(src, out, cache_limit=None)  # no limit: both versions kept
    assert first < _entries(cache)
    report = toy_graph.build(src, out, sep="-", cache_limit=0)  # a third version, and nothing but it kept
    kept = _entries(cache)
    state = json.loads((out / ".state.json").read_text())
    assert kept == {e["key"] for e in state["tasks"].values()}
    assert report.cache["removed"] >= 3 and report.cache["freed"] > 0
    assert toy_graph.build(src, out, sep="-", cache_limit=0).ran == []  # nothing of its own went
    again = toy_graph.build(src, out, sep="+", cache_limit=0)  # the joined "+" version was dropped: it runs
    assert again.ran == ["join"] and (out / "joined.txt").read_text() == "ALPHA, EDITED+BETA"


def test_pruning_drops_the_least_recently_used_first_and_counts_linked_files_once(tmp_path):
    from pipeline.engine.cache import MEMO_FOLDER, Cache

    cache = Cache(tmp_path / "cache")
    for i, key in enumerate(["aa01", "aa02", "bb03"]):
        staging = tmp_path / f"staging{i}"
        staging.mkdir()
        (staging / "f.bin").write_bytes(b"x" * 1000)
        cache.put(key, staging, {})
        os.utime(cache.entry(key) / "meta.json", (1000 + i, 1000 + i))  # used in this order
    memo = tmp_path / "cache" / MEMO_FOLDER / "ab"
    memo.mkdir(parents=True)
    os.link(cache.entry("bb03") / "files" / "f.bin", memo / "linked")  # one file, two names
    os.utime(memo / "linked", (2000, 2000))
    items = {str(p.relative_to(tmp_path / "cache")): size for _, size, p, _ in cache._items()}
    assert items[f"{MEMO_FOLDER}/ab/linked"] == 500  # its half of the linked file
    cache.restore("aa01", tmp_path / "restored")  # a use: aa01 is now the most recent entry
    with cache.in_use():  # room for all but one entry: the oldest one not kept goes (aa02 is kept)
        result = cache.prune(limit=sum(items.values()) - items["bb/bb03"], keep={"aa02"})
    assert result["removed"] == 1 and not cache.has("bb03")
    assert cache.has("aa01") and cache.has("aa02") and (memo / "linked").is_file()


def test_the_cache_is_walked_only_when_what_it_holds_may_be_over_its_limit(tmp_path):
    """A walk leaves the cache's total; entries and memo files stored after add their
    bytes to it (an upper bound of what the next walk finds), and pruning walks again
    only when that total is over the limit."""
    import numpy as np

    from pipeline.engine.cache import Cache
    from pipeline.engine.memo import ArrayMemo

    cache = Cache(tmp_path / "cache")

    def put(key: str, size: int) -> None:
        staging = tmp_path / f"staging-{key}"
        staging.mkdir()
        (staging / "f.bin").write_bytes(b"x" * size)
        cache.put(key, staging, {})

    put("aa01", 1000)
    with cache.in_use():
        first = cache.prune(limit=100_000, keep=set())
    assert first["walked"] and first["bytes"] > 1000
    put("aa02", 2000)
    ArrayMemo(cache.root, "namespace").put("key", {"a": np.zeros(100)})
    with cache.in_use():
        second = cache.prune(limit=100_000, keep=set())
    assert not second["walked"] and second["bytes"] >= first["bytes"] + 2000 + 800
    with cache.in_use():  # a byte less: a walk, which finds the total exact (no file is linked)
        third = cache.prune(limit=second["bytes"] - 1, keep={"aa01", "aa02"})
    assert third["walked"] and third["bytes"] == second["bytes"] and third["removed"] == 1  # the memo file
    with cache.in_use():
        assert not cache.prune(limit=third["bytes"] - third["freed"], keep=set())["walked"]


def test_pruning_waits_for_a_cache_no_other_build_uses(tmp_path):
    from pipeline.engine.cache import Cache

    staging = tmp_path / "staging"
    staging.mkdir()
    (staging / "f.bin").write_bytes(b"x" * 100)
    Cache(tmp_path / "cache").put("cc01", staging, {})
    with Cache(tmp_path / "cache").in_use() as other, Cache(tmp_path / "cache").in_use() as this:
        assert this.prune(limit=0, keep=set()) == {}  # another build may be restoring it
        assert other.has("cc01")
    with Cache(tmp_path / "cache").in_use() as alone:
        assert alone.prune(limit=0, keep=set())["removed"] == 1


def test_cache_limit_sizes():
    from pipeline.engine.cache import parse_size

    assert parse_size("2G") == 2 << 30 and parse_size("500M") == 500 << 20 and parse_size("64kb") == 64 << 10
    assert parse_size("0") == 0 and parse_size("1.5K") == 1536
    for bad in ("-1", "five", "inf", "nan", "3X"):
        with pytest.raises(ValueError):
            parse_size(bad)


def test_an_idle_worker_imports_ahead_what_the_waiting_tasks_will(src, tmp_path):
    """An edit runs its chain task by task: while one runs, an idle worker imports
    the modules the tasks waiting on it name (Task.warm). A cold build, whose
    workers are all busy, sends none."""
    from dataclasses import replace

    from pipeline.engine.executors import InProcess
    from pipeline.engine.scheduler import Scheduler

    calls = []

    class Recording(InProcess):
        def submit(self, fn, /, *args, **kwargs):
            calls.append(fn.__name__ if fn.__name__ == "warm_up" else args[0].__name__)
            if fn.__name__ == "warm_up":
                calls.append(args[0])
            return super().submit(fn, *args, **kwargs)

    out = tmp_path / "build"

    def build():
        calls.clear()
        up_a, up_b, join = toy_graph.tasks(src, out)
        Scheduler(out, jobs=2, executor=lambda workers: Recording()).run([up_a, up_b, replace(join, warm=("wave",))])
        return list(calls)

    assert build() == ["upper", "upper", "join"]
    (src / "a.txt").write_text("alpha, edited")
    assert build() == ["upper", "warm_up", ("wave",), "join"]
    assert "wave" in sys.modules


def _fan_out(delay: float) -> list:
    """first -> second, third: the two become ready together when first is done;
    each sleeps `delay` s."""
    from pipeline.engine.graph import Task

    def task(name, deps=()):
        return Task(name=name, stage="assets", action=toy_graph.whose, args={"name": name, "delay": delay},
                    deps=deps, params={"delay": delay}, code="v1", outputs=(f"out/{name}.txt",))

    return [task("first"), task("second", ("first",)), task("third", ("first",))]


def _machine(monkeypatch, idle_cores: float) -> None:
    """The scheduler sees a machine whose cores stand `idle_cores` idle on average."""
    from pipeline.engine import scheduler

    monkeypatch.setattr(scheduler, "idle_core_seconds", lambda: idle_cores * time.monotonic())


def _counted(started: list):
    """The local pool, with how many workers it started appended to `started` when it
    shuts down."""
    from pipeline.engine.executors import local_pool
    from pipeline.engine.worker import pool_processes

    def counted(workers):
        pool = local_pool(workers)
        shutdown = pool.shutdown

        def recorded(*args, **kwargs):
            started.append(len(pool_processes(pool)))
            return shutdown(*args, **kwargs)

        pool.shutdown = recorded
        return pool

    return counted


def test_a_second_worker_starts_only_for_a_task_that_waited_for_one(tmp_path, monkeypatch):
    """An edit's package is followed by its placement and the viewer at once: short
    tasks that become ready together run in the worker already started. Tasks that
    keep a worker busy past GROW_AFTER_S get a second one, side by side, on a machine
    with a core to spare."""
    from pipeline.engine.scheduler import GROW_AFTER_S, Scheduler

    _machine(monkeypatch, idle_cores=1.0)
    started = []
    counted = _counted(started)

    short = Scheduler(tmp_path / "short", jobs=2, executor=counted).run(_fan_out(0.0))
    assert started == [1] and len({short.results[n]["pid"] for n in ("first", "second", "third")}) == 1
    long = Scheduler(tmp_path / "long", jobs=2, executor=counted).run(_fan_out(4 * GROW_AFTER_S))
    assert started == [1, 2] and long.results["second"]["pid"] != long.results["third"]["pid"]


def test_no_second_worker_starts_while_every_core_is_busy(tmp_path, monkeypatch):
    """The tasks that get a second worker on a machine with a core to spare keep to the
    one started while the machine's cores are all busy: a new worker would take its
    start-up from the task already running."""
    from pipeline.engine.scheduler import GROW_AFTER_S, GROW_IDLE_CORES, Scheduler

    _machine(monkeypatch, idle_cores=GROW_IDLE_CORES / 2)
    started = []
    long = Scheduler(tmp_path / "busy", jobs=2, executor=_counted(started)).run(_fan_out(4 * GROW_AFTER_S))
    assert started == [1] and len({long.results[n]["pid"] for n in ("first", "second", "third")}) == 1


def test_the_machines_idle_time_is_read_from_the_kernel():
    """/proc/stat's idle and iowait time: it never goes back, and grows by no more than
    every core idle for the time between two readings."""
    from pipeline.engine.scheduler import idle_core_seconds

    if not Path("/proc/stat").is_file():
        assert idle_core_seconds() is None
        return
    t0, a = time.monotonic(), idle_core_seconds()
    time.sleep(0.3)
    b, t1 = idle_core_seconds(), time.monotonic()
    assert 0.0 < a <= b <= a + (os.cpu_count() or 1) * (t1 - t0) + 0.05


def test_a_pool_on_demand_grows_to_its_count_and_no_further(tmp_path):
    from pipeline.engine.executors import local_pool
    from pipeline.engine.worker import Workers, pool_processes, run_task

    pool = local_pool(Workers(count=2, threads=1, on_demand=True))
    try:
        pids = {pool.submit(run_task, toy_graph.whose, {"name": str(i)}, str(tmp_path / str(i))).result()["result"]["pid"]
                for i in range(3)}
        assert len(pids) == 1 and len(pool_processes(pool)) == 1
        assert pool.grow() and len(pool_processes(pool)) == 2
        assert not pool.grow()
    finally:
        pool.shutdown(wait=True)
    assert not pool.grow()
