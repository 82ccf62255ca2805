"""A local process pool whose workers start when its caller says (the build's
scheduler: once a task has waited for one), imported only when a task runs."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor


class OnDemandPool(ProcessPoolExecutor):
    """A process pool that starts its first worker with the first task and each
    further one when `grow` is called. The stock pool starts one for every task
    submitted while no worker is idle, and counts a worker idle only after its last
    task's future is done: for an edit's chain of short tasks (a package, then its
    placement and the viewer at once) it starts a second process that imports the
    same libraries again and finishes no sooner. Written against CPython 3.11's pool (bpy
    pins 3.11): submit calls `_adjust_process_count` to start a worker."""

    def _adjust_process_count(self):
        if not self._processes:
            self._spawn_process()

    def grow(self) -> bool:
        """Start one more worker; False when the pool has all it may have, is broken
        or is shut down."""
        with self._shutdown_lock:
            if self._broken or self._shutdown_thread or len(self._processes) >= self._max_workers:
                return False
            self._spawn_process()
            self._executor_manager_thread_wakeup.wakeup()  # its loop watches the new worker too
            return True
