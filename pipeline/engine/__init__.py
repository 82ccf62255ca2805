"""The build engine: a task graph keyed on content, run incrementally. It knows no
domain folder (tests/test_architecture.py): tasks bring their actions with them.

- graph:         Task (inputs, outputs, action, parameters), keys, explain records
- scheduler:     what runs, what is fresh or cached, and where results go
- cache:         the content-addressed cache shared between build folders
- memo:          per-array and per-file memos a task keeps under its code version
- code:          the code version of the modules an action imports
- worker:        a worker's set-up (cores, affinity, memory), `run_task`, how one died
- executors:     where tasks run: a local pool of spawned processes, in process, dask
- pool:          the local pool whose workers start on demand (a build's)
- dask_executor: dask.distributed as a concurrent.futures.Executor
"""
