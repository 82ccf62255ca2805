"""The build's tasks on dask.distributed (issue 27 item 3): `twin build --executor dask`
makes what the local pool makes, reports failures the same way, survives recycled
workers, and leaves no process behind; dask_executor runs any calls the same way."""

from __future__ import annotations

import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import toy_graph
from helpers import ROOT, tree_hashes, twin

try:
    import distributed  # noqa: F401
except ImportError:
    if os.environ.get("CI"):
        raise RuntimeError("dask.distributed is missing in CI: it is a dependency (pip install -e .)") from None
    pytest.skip("dask.distributed is not installed", allow_module_level=True)

import psutil

from pipeline.builder import run
from pipeline.engine.dask_executor import BuildExecutor, dask_executor, dask_pool, run_afresh, worn_out
from pipeline.engine.scheduler import Scheduler


def children() -> set[int]:
    """This process's descendants, less multiprocessing's resource tracker (started
    with the first spawned process, it lives as long as this one)."""
    return {p.pid for p in psutil.Process().children(recursive=True)
            if "resource_tracker" not in " ".join(_cmdline(p))}


def _cmdline(process: psutil.Process) -> list[str]:
    try:
        return process.cmdline()
    except psutil.Error:
        return []


@pytest.fixture(scope="session")
def mini(mini_build):
    """The mini sources and their build by the local pool (two jobs)."""
    return mini_build


# --- the build ------------------------------------------------------------------------


def test_a_dask_build_makes_the_bytes_the_local_pool_makes(mini, tmp_path):
    sources, local = mini
    out = tmp_path / "dask"
    proc = twin("build", "--sources", sources, "--out", out, "--jobs", "2", "--json", "--executor", "dask")
    assert proc.returncode == 0, proc.stderr[-3000:]
    tasks = json.loads(proc.stdout)["tasks"]
    assert tasks and all(e["ran"] for e in tasks)
    assert tree_hashes(out) == tree_hashes(local)
    assert not (out / ".staging").exists()


def test_overlapping_runs_of_a_task_each_see_only_their_own_files(tmp_path):
    """dask runs a task at least once, and two runs of one task can overlap: each lists
    only what it wrote itself, and the staging folder holds the first run to land."""
    staging = tmp_path / ".staging" / "key"
    staging.mkdir(parents=True)  # as the scheduler makes it
    first_wrote, second_landed = threading.Event(), threading.Event()

    def package(staging: Path, which: str) -> dict:
        (staging / "mesh.bin").write_text(which)
        if which == "first":
            first_wrote.set()
            assert second_landed.wait(60)
        listed = sorted(p.name for p in staging.iterdir())
        (staging / "manifest.json").write_text(json.dumps(listed))
        return {"listed": listed}

    outcomes = {}
    first = threading.Thread(target=lambda: outcomes.update(first=run_afresh(package, {"which": "first"}, str(staging))))
    first.start()
    assert first_wrote.wait(60)
    outcomes["second"] = run_afresh(package, {"which": "second"}, str(staging))
    second_landed.set()
    first.join(60)
    assert [outcomes[r]["result"]["listed"] for r in ("first", "second")] == [["mesh.bin"], ["mesh.bin"]]
    assert (staging / "mesh.bin").read_text() == "second"
    assert json.loads((staging / "manifest.json").read_text()) == ["mesh.bin"]
    assert [p.name for p in staging.parent.iterdir()] == ["key"]  # neither run's own folder is left


def test_recycled_workers_still_build_the_same_bytes(mini, tmp_path):
    """Every worker restarts under its nanny after two tasks: tasks queued on it go to
    another, and the outputs are the local pool's."""
    sources, local = mini
    started: list[BuildExecutor] = []
    before = children()

    def recycled(workers):
        started.append(dask_pool(workers, tasks_per_worker=2))
        return started[-1]

    out = tmp_path / "dask"
    report = run.build(sources, out, jobs=2, executor=recycled, quiet=True)
    assert not report.failed
    assert len(report.ran) == len(report.explanations)
    events = started[0].cluster.scheduler.get_events("all")  # the LocalCluster's, kept after it closed
    assert sum(e.get("action") == "add-worker" for _, e in events) > 2  # restarted workers joined
    assert tree_hashes(out) == tree_hashes(local)
    assert _gone(children() - before)


def test_a_user_error_under_dask_is_the_one_line_the_local_pool_gives(mini, tmp_path):
    sources, _ = mini
    src = tmp_path / "src"
    shutil.copytree(sources, src)
    (src / "assets" / "pole" / "pole.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    lines = {}
    for executor in ("local", "dask"):
        proc = twin("build", "--sources", src, "--out", tmp_path / executor, "--jobs", "2", "--executor", executor)
        assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
        lines[executor] = [line for line in proc.stderr.splitlines() if line.startswith(("error:", "not built:"))]
    errors = [line for line in lines["dask"] if line.startswith("error:")]
    assert len(errors) == 1 and "pole.obj" in errors[0]
    assert lines["dask"] == lines["local"]


def test_a_scheduler_address_is_only_for_dask(tmp_path):
    proc = twin("build", "--out", tmp_path, "--scheduler", "tcp://127.0.0.1:1")
    assert proc.returncode == 2 and "--scheduler" in proc.stderr


# --- the scheduler on dask, with the toy graph ----------------------------------------


def test_a_task_whose_worker_dies_fails_alone_and_the_cluster_goes(src, tmp_path):
    """A worker killed under its task fails that task alone, as a local worker's death
    does (one task per worker process: the death is its own); the build goes on and
    closes its cluster."""
    out = tmp_path / "build"
    graph = toy_graph.tasks(src, out)
    for t in graph:
        if t.name == "upper:b":
            t.action = toy_graph.die
    before = children()
    r = Scheduler(out, jobs=2, executor=dask_pool).run(graph)
    assert [(e["task"], e["kind"]) for e in r.errors] == [("upper:b", "worker")]
    assert r.errors[0]["error"].startswith("its worker process died")
    assert r.blocked == {"join": ["upper:b"]}
    assert (out / "up" / "a.txt").read_text() == "ALPHA"
    assert not (out / "up" / "b.txt").exists() and not (out / ".staging").exists()
    assert _gone(children() - before)
    fixed = Scheduler(out, jobs=2, executor=dask_pool).run(toy_graph.tasks(src, out))
    assert sorted(fixed.ran) == ["join", "upper:b"]


def upper_and_limits(staging: Path, src: str, name: str, delay: float = 0.0) -> dict:
    """toy_graph.upper, and the limits its worker was set up with."""
    import resource

    return {**toy_graph.upper(staging, src, name, delay), "omp": os.environ.get("OMP_NUM_THREADS"),
            "address_space": resource.getrlimit(resource.RLIMIT_AS)[0]}


def test_workers_are_set_up_as_the_local_pools(src, tmp_path, monkeypatch):
    """Thread variables, the address-space limit, and each one-core task on a CPU of
    its own (a task alone on all of the build's), as worker.init_worker sets them."""
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    out = tmp_path / "build"
    graph = toy_graph.tasks(src, out, delay=0.05)  # both uppers run at once
    for t in graph[:2]:
        t.action = upper_and_limits
    report = Scheduler(out, jobs=2, executor=dask_pool, memory_limit=5 << 30).run(graph)
    assert not report.failed
    a, b = (report.results[n] for n in ("upper:a", "upper:b"))
    assert a["address_space"] == b["address_space"] == 5 << 30
    assert a["omp"] == a["cores"] == str(max(1, min(2, os.cpu_count()) // 2))
    usable = sorted(os.sched_getaffinity(0))
    if len(usable) >= 2:
        assert len(a["cpus"]) == 1 and len(b["cpus"]) == 1 and a["cpus"] != b["cpus"]
    assert report.results["join"]["cpus"] == usable


def test_ctrl_c_closes_the_cluster(src, tmp_path):
    """SIGINT to the build's process group (as the terminal's Ctrl-C) while tasks
    run: the build ends and no worker process outlives it."""
    out = tmp_path / "build"
    # The build takes Ctrl-C as a terminal's foreground job does: a background job of a
    # shell without job control (CI's) starts with SIGINT ignored, which pytest's
    # processes pass on to theirs. It dumps its threads' stacks on SIGUSR1: what a
    # build that outlives the signal was doing.
    script = ("import faulthandler, signal, sys, toy_graph; from pathlib import Path; "
              "from pipeline.engine.scheduler import Scheduler; from pipeline.engine.dask_executor import dask_pool; "
              "signal.signal(signal.SIGINT, signal.default_int_handler); "
              "faulthandler.register(signal.SIGUSR1, all_threads=True); "
              "src, out = Path(sys.argv[1]), Path(sys.argv[2]); "
              "Scheduler(out, jobs=2, executor=dask_pool).run(toy_graph.tasks(src, out, delay=30.0))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "tests"), str(ROOT)])}
    proc = subprocess.Popen([sys.executable, "-c", script, str(src), str(out)], env=env, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    build = psutil.Process(proc.pid)
    deadline = time.monotonic() + 120
    while not (out / ".staging").is_dir() or not any((out / ".staging").iterdir()):  # a task has started
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1].decode()[-3000:]
        time.sleep(0.1)
    time.sleep(0.5)
    workers = {p.pid for p in build.children(recursive=True)}
    assert len(workers) >= 2
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGUSR1)
        time.sleep(2.0)
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        pytest.fail(f"the build outlived Ctrl-C by 120 s:\n{err.decode(errors='replace')[-6000:]}")
    assert proc.returncode != 0 and b"KeyboardInterrupt" in err, err.decode(errors="replace")[-6000:]
    assert b"Dask Worker process" not in err  # the workers leave Ctrl-C to the build: no trace of theirs
    assert _gone(workers)


def _gone(pids: set[int], timeout: float = 30.0) -> bool:
    """Whether every process in `pids` has ended (a zombie, ended but not reaped,
    counts as ended) within `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        alive = [p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        if not alive or time.monotonic() > deadline:
            return not alive
        time.sleep(0.2)


# --- any calls --------------------------------------------------------------------------


def _where(i: int) -> tuple[int, int, bool]:
    return i, os.getpid(), "pipeline.geometry" in sys.modules


def test_dask_executor_preloads_recycles_and_closes():
    before = children()
    with dask_executor(2, preload=("pipeline.geometry",), tasks_per_worker=2) as executor:
        done = [f.result(timeout=300) for f in [executor.submit(_where, i) for i in range(6)]]
    assert [i for i, _, _ in done] == list(range(6))
    assert all(loaded for _, _, loaded in done)  # imported when each worker started
    assert len({pid for _, pid, _ in done}) >= 3  # no worker ran more than 2
    assert _gone(children() - before)


def test_dask_executor_hands_back_a_calls_own_error():
    with dask_executor(1) as executor:
        with pytest.raises(ZeroDivisionError):
            executor.submit(divmod, 1, 0).result(timeout=300)
        assert executor.submit(divmod, 7, 2).result(timeout=300) == (3, 1)


def _die_once(marker: str) -> int:
    """Kills its worker the first time (as a nanny ends one past its memory), then
    returns its pid."""
    if not os.path.exists(marker):
        Path(marker).write_text("died")
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid()


def test_a_call_whose_worker_died_runs_once_more_on_a_fresh_one(tmp_path):
    with dask_executor(1) as executor:
        assert executor.submit(_die_once, str(tmp_path / "died")).result(timeout=300) > 0
    assert (tmp_path / "died").is_file()


def test_a_preload_no_worker_can_import_is_a_user_error_and_closes_the_cluster():
    from pipeline.errors import UserError

    before = children()
    with pytest.raises(UserError, match="cannot import no_such_module"):
        with dask_executor(1, preload=("no_such_module",)):
            pass
    assert _gone(children() - before)


def test_a_worker_is_worn_out_by_its_task_count_or_its_memory():
    assert not worn_out(3, None, None)
    assert worn_out(3, 3, None) and not worn_out(2, 3, None)
    rss = psutil.Process().memory_info().rss
    assert worn_out(1, None, rss) and not worn_out(1, None, 4 * rss)


def test_the_build_factory_takes_a_scheduler_address(src, tmp_path):
    """--scheduler: the build on a cluster started elsewhere (here a LocalCluster of
    this test's), which keeps running after the build."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=50) as cluster:
        out = tmp_path / "build"
        r = Scheduler(out, jobs=1, executor=functools.partial(dask_pool, scheduler=cluster.scheduler_address)
                      ).run(toy_graph.tasks(src, out))
        assert not r.failed and (out / "joined.txt").read_text() == "ALPHA+BETA"
        assert len(cluster.scheduler.workers) == 1
        assert "twin-setup" not in cluster.scheduler.worker_plugins  # taken back with the client


def _kill_own_process(staging=None) -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _echo(value: int) -> dict:
    return {"value": value}


def test_calls_without_staging_and_a_dead_worker_read_the_same_on_every_executor():
    """run_task with no staging folder (a dataset's frame) on the local pool and on
    dask: the result comes back as data, and a worker that dies under its call reads
    as the scheduler reports one (engine.executors.outcome)."""
    from pipeline.engine.executors import local_pool, outcome
    from pipeline.engine.worker import Workers, run_task

    workers = Workers(count=1, threads=1)
    for factory in (local_pool, dask_pool):
        pool = factory(workers)
        try:
            ok = outcome(pool.submit(run_task, _echo, {"value": 7}, None))
            assert ok["ok"] and ok["result"] == {"value": 7}, factory
            dead = outcome(pool.submit(run_task, _kill_own_process, {}, None))
            assert dead == {"ok": False, "error": "its worker process died", "kind": "worker"}, factory
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
