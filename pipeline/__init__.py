"""substation-twin: a reproducible build system for digital twins of substations."""

import os

# OpenBLAS's idle threads (numpy's and scipy's) spin on sched_yield for about 2**28
# cycles before they sleep, once when the library loads and again after each call:
# CPU that every process of ours (the CLI, build workers, Blender processes) takes
# from the others on a busy machine, for nothing. With this they sleep at once. Their
# number is unchanged, and with it every result. Set before numpy loads OpenBLAS, and
# inherited by every process ours start; a value the user set is kept.
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")

__version__ = "0.1.0"
