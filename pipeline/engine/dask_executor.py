"""Tasks on dask.distributed, behind a `concurrent.futures.Executor`: the build's
(`twin build --executor dask`, the factory `dask_pool`) and any other set of
independent calls, dataset frames for one (the context manager `dask_executor`).

With no scheduler address, a LocalCluster on this machine: one worker process per
task in flight, one thread each (a task is a process's work, as in the local pool),
no dashboard, its logs silenced. With an address, the cluster that scheduler runs:
its workers must import this package and see the build folder and the sources at
the same paths as this process (a shared filesystem), since tasks read and write
those paths themselves.

Workers are recycled between tasks: the scheduler retires the worker, which then
closes and its nanny starts it again (`_leave`): after `tasks_per_worker` tasks,
or once a task leaves the worker holding more than RECYCLE_SHARE of its memory (what
no later task frees: Blender's and the allocators' caches, fragmented heaps). The
worker stops taking tasks before its last one returns, so no task is cut short by a
recycle; one queued on it goes to another worker. Beyond that the nanny terminates a
worker whose memory passes dask's `terminate` threshold mid-task, and dask reruns a
task whose worker died on another one up to `allowed-failures` times: on a
LocalCluster once for any calls (a worker's memory may be what earlier calls left),
never for the build's tasks (one task per process: a death is the task's own, and
the local pool fails it too).

dask is imported when an executor starts, never at import time of the pipeline.
"""

from __future__ import annotations

import importlib
import logging
import os
import shutil
import time
import uuid
from concurrent.futures import CancelledError, Executor, Future
from contextlib import contextmanager, nullcontext, suppress
from pathlib import Path
from typing import Callable, Iterator

from ..errors import UserError
from .worker import THREAD_VARIABLES, Workers, died, init_worker, run_task

INSTALL_HINT = "dask.distributed is not installed: .venv/bin/pip install -e . (it is a dependency)"

# a worker left holding more than this share of its memory after a task is restarted
RECYCLE_SHARE = 0.5

# how long a recycled worker waits for the client to take its last results
HANDOVER_SECONDS = 60.0

# a LocalCluster's settings: a worker's memory beyond its limit is a restart, never a
# pause (tasks hand back small dicts, there is nothing to spill, and a paused worker
# whose heap stays large would hold the build forever); no statistical profiler,
# which takes the GIL from the task a hundred times a second for a dashboard that
# is not there
LOCAL_CONFIG = {
    "distributed.worker.memory.target": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.pause": False,
    "distributed.worker.profile.enabled": False,
}


# --- in a worker -----------------------------------------------------------------

_FINISHED = 0  # tasks this worker process has run


def call(fn, args: tuple, kwargs: dict, tasks_per_worker: int | None, memory: int | None):
    """`fn(*args, **kwargs)` in a worker; a worker worn out by it stops taking tasks
    before it returns, and restarts once its results are taken."""
    global _FINISHED
    try:
        return fn(*args, **kwargs)
    finally:
        _FINISHED += 1
        if worn_out(_FINISHED, tasks_per_worker, memory):
            try:
                _retire()
            except Exception:  # noqa: BLE001 - a worker that cannot leave serves on; the call's outcome stands
                pass


def worn_out(finished: int, tasks_per_worker: int | None, memory: int | None) -> bool:
    """Whether a worker that has run `finished` tasks is due for a restart."""
    if tasks_per_worker is not None and finished >= tasks_per_worker:
        return True
    if memory:
        import psutil  # a dependency of distributed

        return psutil.Process().memory_info().rss > RECYCLE_SHARE * memory
    return False


def _retire() -> None:
    """Pause this worker from its task's thread, so nothing starts after the task
    (the scheduler hands a paused worker no task, and the worker starts none of those
    queued on it), then restart it under its nanny once the results are taken."""
    import asyncio

    from distributed import get_worker

    worker = get_worker()
    loop = worker.loop.asyncio_loop
    asyncio.run_coroutine_threadsafe(_pause(worker), loop).result()
    loop.call_soon_threadsafe(lambda: asyncio.ensure_future(_leave(worker)))


async def _pause(worker) -> None:
    from distributed.core import Status

    if worker.status == Status.running:
        worker.status = Status.paused


async def _leave(worker) -> None:
    """A restart under the nanny, once the client took what this worker holds (results
    lost with it would be computed again) and the scheduler has retired it.

    The retirement must have happened before the worker goes: a task the scheduler
    handed it just before the pause reached the scheduler is queued here, and only a
    retired worker's tasks go elsewhere as if nothing happened. dask's own
    close_gracefully closes the worker even when the scheduler refused to retire it
    (results no other worker can take): its queued tasks would count as killed by it,
    and a build's task fails on such a death. A worker the scheduler will not retire
    within HANDOVER_SECONDS serves on."""
    import asyncio

    from distributed.core import Status

    deadline = time.monotonic() + HANDOVER_SECONDS
    while time.monotonic() < deadline:
        if not (worker.state.executing_count or worker.data):
            retired = await worker.scheduler.retire_workers(workers=[worker.address], close_workers=False, remove=True,
                                                             stimulus_id=f"twin-recycle-{time.time()}")
            if worker.address in retired:
                await worker.close(nanny=False, reason="twin: worker recycled")
                return
        await asyncio.sleep(0.05)
    if worker.status == Status.paused:
        worker.status = Status.running


class _Slot:
    """A worker's place among the LocalCluster's (its name), where init_worker takes
    it from the local pool's shared counter: the CPU it keeps to on a one-core task."""

    def __init__(self, value: int):
        self.value = value

    def get_lock(self):
        return nullcontext()


def _worker_plugin_class():
    from distributed import WorkerPlugin

    class Setup(WorkerPlugin):
        """What each worker does when it starts (a restarted one too): the local pool's
        set-up (worker.init_worker) when `threads` is given, then `preload`
        imported once. `local`: the workers are this machine's, named 0..n-1 by the
        LocalCluster: each keeps to its own CPU on one-core tasks as a local pool's
        worker does, and leaves Ctrl-C to the build, which closes the cluster (the
        terminal sends it to the whole process group, and a worker would end with
        a traceback on the user's screen)."""

        name = "twin-setup"

        def __init__(self, threads: int | None, cpus: tuple[int, ...], address_space: int | None,
                     preload: tuple[str, ...], local: bool):
            self.threads, self.cpus, self.address_space, self.preload = threads, cpus, address_space, preload
            self.local = local

        def setup(self, worker):

            if self.threads is not None:
                slot = _Slot(worker.name) if self.local and isinstance(worker.name, int) else None
                init_worker(self.threads, self.cpus if self.local else (), slot, self.address_space)
            if self.local:
                import signal

                signal.signal(signal.SIGINT, signal.SIG_IGN)
            for name in self.preload:
                importlib.import_module(name)

    return Setup


# --- in this process ---------------------------------------------------------------


class DaskExecutor(Executor):
    """`concurrent.futures` over a dask Client: each call is a task of its own
    (pure=False: never merged with an equal call), its result handed back and let go
    on the worker at once. `lost`: what a call whose workers all died returns instead
    of raising dask's KilledWorker (None: it raises). Shutting down closes the client,
    and the cluster when this executor started it."""

    def __init__(self, client, cluster=None, *, tasks_per_worker: int | None = None, memory: int | None = None,
                 lost: Callable[[Exception], object] | None = None, plugin: str | None = None):
        self.client, self.cluster = client, cluster
        self.tasks_per_worker, self.memory, self.lost, self.plugin = tasks_per_worker, memory, lost, plugin
        self._futures: set = set()  # dask futures not yet settled
        self._closed = False

    def submit(self, fn, /, *args, **kwargs) -> Future:
        if self._closed:
            raise RuntimeError("cannot submit to a dask executor after shutdown")
        key = f"{getattr(fn, '__name__', 'call')}-{uuid.uuid4().hex}"
        future = self.client.submit(call, fn, args, kwargs, self.tasks_per_worker, self.memory, key=key,
                                    pure=False)
        result: Future = Future()
        self._futures.add(future)
        future.add_done_callback(lambda f: self._settle(f, result))
        return result

    def _settle(self, future, result: Future) -> None:
        """The dask future's outcome onto `result` (in dask's callback thread)."""
        from distributed import KilledWorker

        try:
            value = future.result()
        except KilledWorker as e:
            if self.lost is None:
                _set(result, exception=e)
            else:
                _set(result, value=self.lost(e))
        except CancelledError:
            if result.cancel():
                result.set_running_or_notify_cancel()  # wakes concurrent.futures.wait
        except BaseException as e:  # noqa: BLE001 - the call's own error, as a pool hands it back
            _set(result, exception=e)
        else:
            _set(result, value=value)
        finally:
            self._futures.discard(future)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Cancel what has not finished (`cancel_futures`) or wait for it (`wait`), then
        close the client and the cluster this executor started."""
        if self._closed:
            return
        self._closed = True
        outstanding = list(self._futures)
        try:
            if cancel_futures and outstanding:
                self.client.cancel(outstanding)
            elif wait and outstanding:
                from distributed import wait as dask_wait

                dask_wait(outstanding)
            if self.plugin is not None and self.cluster is None:
                # a shared scheduler keeps its plugins for workers that join later
                try:
                    self.client.unregister_worker_plugin(self.plugin)
                except Exception:  # noqa: BLE001 - the cluster may be gone already
                    pass
        finally:
            try:
                self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()


def _set(result: Future, value=None, exception: BaseException | None = None) -> None:
    if result.done():  # cancelled meanwhile
        return
    if exception is not None:
        result.set_exception(exception)
    else:
        result.set_result(value)


def start(workers: int, scheduler: str | None = None, *, threads: int | None = None, cpus: tuple[int, ...] = (),
          address_space: int | None = None, preload: tuple[str, ...] = (), memory: int | None = None,
          tasks_per_worker: int | None = None, lost: Callable[[Exception], object] | None = None,
          retries: int = 1, executor_class: type[DaskExecutor] = DaskExecutor) -> DaskExecutor:
    """A DaskExecutor on a new LocalCluster of `workers` processes (no `scheduler`) or
    on the cluster at `scheduler`. `threads`: each worker's native thread pools and
    fork_join.beside share (worker.init_worker, with `cpus` and `address_space`);
    `memory`: bytes a worker may hold (the nanny's limit on a LocalCluster, and the
    recycling rule everywhere); `retries`: workers a LocalCluster lets a call's death
    cost after the first before it fails with KilledWorker."""
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise UserError("--executor dask", None, INSTALL_HINT) from None

    Setup = _worker_plugin_class()
    plugin = Setup(threads, cpus, address_space, tuple(preload), local=scheduler is None)
    cluster = None
    if scheduler is None:
        # in the workers only: a variable the user set is kept, as in the local pool
        share = str(threads or max(1, (os.cpu_count() or 1) // max(1, workers)))
        env = {name: os.environ.get(name, share) for name in THREAD_VARIABLES}
        # the nanny sets its pre-spawn variables in this process too; "random" is
        # Python's own default, where dask would fix the seed of later subprocesses
        spawn = {"PYTHONHASHSEED": os.environ.get("PYTHONHASHSEED", "random")}
        with dask.config.set({**LOCAL_CONFIG, "distributed.nanny.pre-spawn-environ": spawn,
                              "distributed.scheduler.allowed-failures": retries}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=logging.CRITICAL,
                                   memory_limit=memory or 0, env=env,
                                   # its health and metrics routes, on any free port of this machine's
                                   # loopback (8787 by default, which another cluster may hold)
                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    client = None
    try:
        try:
            client = Client(cluster or scheduler, set_as_default=False, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise UserError("--scheduler", scheduler, f"cannot reach the dask scheduler: {e}") from None
        try:
            client.register_plugin(plugin)
        except ImportError as e:
            raise UserError("--executor dask", None, f"a dask worker cannot import {e.name or e}: "
                                                     "install it where the workers run") from None
    except BaseException:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        raise
    return executor_class(client, cluster, tasks_per_worker=tasks_per_worker, memory=memory, lost=lost,
                          plugin=Setup.name)


@contextmanager
def dask_executor(workers: int, scheduler: str | None = None, *, preload: tuple[str, ...] = (),
                  memory: int | None = None, tasks_per_worker: int | None = None) -> Iterator[Executor]:
    """An Executor on dask for the block: `workers` processes on a LocalCluster of this
    machine (no `scheduler`), or the cluster at the `scheduler` address (workers see
    the same paths as this process). `preload`: modules each worker imports once when
    it starts ("bpy"); `memory`: bytes a worker may hold before it is recycled
    (RECYCLE_SHARE of it, between tasks) or, on a LocalCluster, terminated mid-task;
    `tasks_per_worker`: tasks a worker runs before it is recycled. The cluster is
    closed when the block ends, whatever ends it."""
    executor = start(workers, scheduler, preload=preload, memory=memory, tasks_per_worker=tasks_per_worker)
    try:
        yield executor
    finally:
        executor.shutdown(wait=False, cancel_futures=True)


# --- the build's --------------------------------------------------------------------


class BuildExecutor(DaskExecutor):
    """The build's tasks each in an empty staging folder: dask reruns a task whose
    worker died elsewhere, and what the dead attempt left must not enter the cache."""

    def submit(self, fn, /, *args, **kwargs) -> Future:

        return super().submit(run_afresh if fn is run_task else fn, *args, **kwargs)


def run_afresh(action, args: dict, staging: str | None, cores: int | None = None) -> dict:
    """worker.run_task in a folder of this run's own, which becomes the task's staging
    folder when the task succeeds. dask runs a task at least once, and two runs of one
    task can overlap (a worker recycled or lost while the scheduler hands its task to
    another): neither may see the other's files (a package lists what its folder holds).
    The first run to land keeps its folder; a later one, the same files, is dropped."""
    if staging is None:
        return run_task(action, args, staging, cores)
    own = Path(f"{staging}.{uuid.uuid4().hex}")
    own.mkdir(parents=True)
    try:
        out = run_task(action, args, str(own), cores)
        if out.get("ok"):
            with suppress(OSError):
                os.rmdir(staging)  # the empty folder the scheduler made, never a landed run's
            with suppress(OSError):
                os.rename(own, staging)
        return out
    finally:
        shutil.rmtree(own, ignore_errors=True)


def worker_died(error: Exception) -> dict:
    """A task whose workers all died, as the scheduler reports a local worker's death."""
    tries = getattr(error, "allowed_failures", 0) + 1
    times = f" ({tries} workers in turn)" if tries > 1 else ""
    return died(times)


def dask_pool(workers: Workers, scheduler: str | None = None, tasks_per_worker: int | None = None) -> Executor:
    """The build's executor on dask (EXECUTORS["dask"]): `workers.count` worker processes
    on a LocalCluster, set up as the local pool's (thread variables, CPUs, address-space
    limit), or the cluster at `scheduler`, whose workers must see the build folder and
    the sources at the same paths as this process."""
    return start(workers.count, scheduler, threads=workers.threads, cpus=workers.cpus,
                 address_space=workers.memory, memory=workers.memory, tasks_per_worker=tasks_per_worker,
                 lost=worker_died, retries=0, executor_class=BuildExecutor)
