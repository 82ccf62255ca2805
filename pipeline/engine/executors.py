"""Where tasks run. The scheduler decides what runs and when; an executor only runs
`run_task(action, args, staging, cores)` calls and hands back `concurrent.futures` futures.

An executor is a factory `Workers -> concurrent.futures.Executor`, called once per
build when the first task has to run (a no-op build starts none). Tasks are pure
functions of their declared inputs and write only into the staging folder they are
given, so any engine that implements `concurrent.futures.Executor` can run them:
the local process pool below, the calling process itself (`in_process`, for a
debugger or a profiler), or a distributed engine's executor (dask.distributed's
`Client.get_executor()`, for one) whose workers see the build folder and the
sources at the same paths (a shared filesystem). Results come back as data; the
scheduler alone moves outputs into the cache and the build folder.
"""

from __future__ import annotations

from concurrent.futures import BrokenExecutor, Executor, Future
from typing import Callable

from .dask_executor import dask_pool
from .worker import Workers, died, init_worker

ExecutorFactory = Callable[[Workers], Executor]


# --- a local pool of spawned processes (the default) ---------------------------


def local_pool(workers: Workers) -> Executor:
    """`workers.count` spawned processes that serve many tasks each (spawned, not
    forked: the scheduler's process holds threads, and Blender does not survive a
    fork of a process that imported it); started as tasks need them, or on demand
    (Workers.on_demand, OnDemandPool)."""
    import multiprocessing  # only when a task runs: a no-op build and the CLI's options need none
    from concurrent.futures import ProcessPoolExecutor

    from ..scratch import pool_folder, remove_with
    from .pool import OnDemandPool

    context = multiprocessing.get_context("spawn")
    slots = context.Value("i", 0)  # each worker takes the next: the CPU it keeps to on a one-core task
    temp = pool_folder()  # the workers' temp folders (Blender's among them), whatever becomes of them
    kind = OnDemandPool if workers.on_demand else ProcessPoolExecutor
    pool = kind(max_workers=workers.count, mp_context=context, initializer=init_worker,
                initargs=(workers.threads, workers.cpus, slots, workers.memory, temp))
    remove_with(pool, temp)
    return pool


# --- the calling process -------------------------------------------------------


class InProcess(Executor):
    """Runs each task in the calling process when it is submitted, one at a time:
    breakpoints, profilers and tracebacks see the task's own stack. Nothing is set up
    (the process keeps its environment, bpy is imported by the first reader that
    needs it); each task has the share of the cores the scheduler gives it for the
    duration of its run."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as e:  # as a pool would hand it back (Ctrl-C goes on up)
            future.set_exception(e)
        return future


def in_process(workers: Workers) -> Executor:
    return InProcess()


def outcome(future: Future) -> dict:
    """A run_task call's result from any executor: a local pool's worker that died
    (the pool broken) reads as dask's does (dask_executor.worker_died)."""
    try:
        return future.result()
    except BrokenExecutor:
        return died()


EXECUTORS: dict[str, ExecutorFactory] = {"local": local_pool, "in-process": in_process, "dask": dask_pool}
