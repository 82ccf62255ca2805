"""The worker side of the engine: what a process that runs tasks sets up
(`init_worker`: its cores, CPU affinity and memory limit) and how it runs one
(`run_task`: a task's result, or its failure as data). Every executor runs tasks
through `run_task`; the local pool and dask's workers set themselves up with
`init_worker`."""

from __future__ import annotations

import atexit
import os
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from ..errors import UserError
from ..fork_join import SHARE_VARIABLE

# thread pools of the native libraries a task uses that a variable sizes (libigl's)
THREAD_VARIABLES = ("IGL_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@dataclass(frozen=True)
class Workers:
    """What a build asks of its workers.

    count:   tasks in flight at once (the scheduler never submits more);
    threads: cores each task may use for native thread pools and fork_join.beside;
    cpus:    CPUs to hold the workers to, empty for no affinity;
    memory:  bytes of address space each worker may map (RLIMIT_AS), None for no
             limit: a task that needs more fails with MemoryError, which is its own
             failure, before the kernel's out-of-memory killer picks a process;
    on_demand: a local pool starts its first worker with the first task and each
             further one only when the caller asks (`grow`: the scheduler, once a task
             has waited for one); otherwise one for each task submitted while none is
             idle."""

    count: int
    threads: int
    cpus: tuple[int, ...] = ()
    memory: int | None = None
    on_demand: bool = False


# a worker's address space holds far more than it touches (Blender, USD, thread
# stacks and malloc arenas reserve without using): never less than this
MIN_MEMORY = 4 << 30


def default_memory(count: int) -> int:
    """Each of `count` workers' share of the machine's physical memory, at least
    MIN_MEMORY."""
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return MIN_MEMORY
    return max(MIN_MEMORY, physical // max(1, count))


def memory_limit() -> int | None:
    """This process's address-space limit in bytes, None when there is none."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else soft


def run_task(action, args: dict, staging: str | None, cores: int | None = None) -> dict:
    """One task, wherever it runs: `action(staging=..., **args)`, or `action(**args)`
    for a call that writes no staging folder (`staging` None: a dataset's frame). User
    errors come back as data (with the file and the object they name) so the scheduler
    reports them; running out of memory is such a failure too; a bug keeps its trace for
    the report, not the user's screen. `cores`: the task's share of the cores for
    fork_join.beside and spread, which the scheduler gives when it submits the task (all
    of the build's to a task that starts with nothing beside it, the scene at the end of
    a cold build)."""
    before = os.environ.get(SHARE_VARIABLE)
    if cores is not None:
        os.environ[SHARE_VARIABLE] = str(cores)
        _hold_to(cores)
    try:
        t0 = time.perf_counter()
        result = (action(**args) if staging is None else action(staging=Path(staging), **args)) or {}
        return {"ok": True, "result": result, "seconds": time.perf_counter() - t0}
    except UserError as e:
        return {"ok": False, "user_error": str(e), "file": e.file, "object": e.obj, "message": e.message}
    except MemoryError:
        # an allocation refused under the task's memory limit: the task fails, the
        # worker lives on (what it held is freed with the frames of the action)
        limit = memory_limit()
        within = f" (its limit: {limit / 2**30:.1f} GB, twin build --memory-limit)" if limit else ""
        return {"ok": False, "error": f"ran out of memory{within}", "kind": "memory"}
    except (Exception, SystemExit) as e:  # a task that exits ends itself, not the build
        return {"ok": False, "error": f"{type(e).__name__}: {e}", "trace": traceback.format_exc()}
    finally:
        if before is None:
            os.environ.pop(SHARE_VARIABLE, None)
        else:
            os.environ[SHARE_VARIABLE] = before
        if _EXIT_FIRST:
            # the task may have imported a library with exit handlers of its own (bpy,
            # the first time a worker reads a .blend): this one stays the last
            # registered, so it runs first
            atexit.unregister(_exit_now)
            atexit.register(_exit_now)


def died(how: str = "") -> dict:
    """A task whose worker process died under it, as run_task's failures read; `how`:
    what is known of the death (an exit code)."""
    return {"ok": False, "error": f"its worker process died{how}", "kind": "worker"}


def pool_processes(pool) -> dict:
    """A local pool's worker processes by pid (empty for other executors): how many
    it has started, and by their exit codes how one died."""
    return dict(getattr(pool, "_processes", None) or {})


def death(workers: dict) -> str:
    """How a pool's worker died, from the exit codes of its processes: the pool
    terminates the others (SIGTERM) when one dies."""
    import signal

    codes = set()
    for process in workers.values():
        code = getattr(process, "exitcode", None)
        if code not in (None, 0, -signal.SIGTERM):
            codes.add(code)
    if len(codes) != 1:
        return ""
    code = codes.pop()
    if code == -signal.SIGKILL:
        return " (killed: SIGKILL, as the kernel's out-of-memory killer sends)"
    if code < 0:
        try:
            return f" ({signal.Signals(-code).name})"
        except ValueError:
            return f" (signal {-code})"
    return f" (exit code {code})"


def warm_up(modules: tuple[str, ...]) -> None:
    """Import `modules` (those a coming task's action will import), in a worker that
    would otherwise wait idle for it. A module that fails to import is left for the
    task to report."""
    import importlib

    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - the task that needs it reports it
            pass


# In a pool worker: the CPUs of the build, and the one this worker keeps to when its
# task has one core. None elsewhere (a task run in the calling process moves nothing).
_CPUS: tuple[int, ...] | None = None
_OWN_CPU: int | None = None
# In a pool worker: _exit_now is registered, and kept the last exit handler (run_task).
_EXIT_FIRST = False


def init_worker(threads: int, cpus: tuple[int, ...] = (), slots=None, memory: int | None = None,
                temp: str | None = None) -> None:
    """Worker initializer. Each worker's native thread pools get its share of the cores
    (N workers each running as many threads as there are cores only trade places);
    a variable the user set is kept. `cpus`: the CPUs a build given fewer cores than
    the machine is held to (fcpw starts a thread per core it sees, whatever the
    variables say). `slots`: a shared counter from which the worker takes the CPU it
    keeps to while its task has a single core (see _hold_to). `memory`: the worker's
    address-space limit (Workers.memory), inherited by the processes its tasks start.
    bpy is imported by the first read of a .blend in a worker, not here: a worker that
    reads none (the source, geometry and package tasks of an edit's chain) never pays
    for it. `temp`: the folder the worker keeps its temporary files in (scratch)."""
    global _CPUS, _OWN_CPU, _EXIT_FIRST
    if memory is not None:
        import resource

        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        limit = memory if hard == resource.RLIM_INFINITY else min(memory, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    if cpus:
        os.sched_setaffinity(0, cpus)
    if slots is not None and hasattr(os, "sched_getaffinity"):
        _CPUS = tuple(sorted(os.sched_getaffinity(0)))
        with slots.get_lock():
            _OWN_CPU = _CPUS[slots.value % len(_CPUS)]
            slots.value += 1
    for name in THREAD_VARIABLES:
        os.environ.setdefault(name, str(threads))
    os.environ[SHARE_VARIABLE] = str(threads)  # tasks may run two parts side by side (fork_join.beside)
    # Kept after bpy's own exit handler (run_task), so it runs first: Blender's exit
    # clean-up and the teardown of the interpreter's modules are time every worker
    # spends at exit, and the build waits for both. By then
    # the worker has handed back every result (multiprocessing flushes its queues
    # before). Only in a worker: a main process keeps its exit code.
    import multiprocessing

    if multiprocessing.parent_process() is not None:
        from ..scratch import use_temp_folder

        use_temp_folder(temp)  # before bpy makes its session folder: _exit_now skips its removal
        atexit.register(_exit_now)
        _EXIT_FIRST = True


def _hold_to(cores: int) -> None:
    """A pool worker whose task has one core keeps to a CPU of its own, and one with
    more to all of the build's. fcpw splits each query batch over a thread per CPU it
    sees: two workers' threads spread over both CPUs wait on each other's stragglers
    at the end of every batch."""
    if _CPUS is None or _OWN_CPU is None or len(_CPUS) < 2:
        return
    os.sched_setaffinity(0, (_OWN_CPU,) if cores <= 1 else _CPUS)


def _exit_now() -> None:
    from ..scratch import remove_temp_folder

    remove_temp_folder()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
