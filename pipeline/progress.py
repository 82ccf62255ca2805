"""Progress of long commands on stderr (rich), so stdout stays the command's result
(`--json`, a path) whether or not a terminal is watching; and Blender's log (its C
code writes on file descriptors 1 and 2) into a file instead of the terminal."""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


class Bar:
    """One bar: a count of steps done out of a total that may grow as work is found."""

    def __init__(self, progress, task, label: str, total: int | None):
        self._progress, self._task, self._label, self._total = progress, task, label, total

    def update(self, done: int, total: int | None = None) -> None:
        if total is not None:
            self._total = total
        self._progress.update(self._task, completed=done, total=self._total)

    def add(self, steps: int) -> None:
        """`steps` more to do."""
        self._total = (self._total or 0) + steps
        self._progress.update(self._task, total=self._total)

    def step(self, what: str | None = None) -> None:
        """One step done; `what` says what ran (shown beside the bar's label)."""
        label = self._label if what is None else f"{self._label}: {what}"
        self._progress.update(self._task, advance=1, description=label)


@contextmanager
def bar(label: str, total: int | None = None) -> Iterator[Bar]:
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    columns = (TextColumn("{task.description:<28}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    sys.stderr.flush()
    # the terminal's stderr as it is now: a block of output_to inside keeps the bar on it
    with os.fdopen(os.dup(sys.stderr.fileno()), "w") as terminal:
        with Progress(*columns, console=Console(file=terminal), transient=False) as progress:
            task = progress.add_task(label, total=total)
            try:
                yield Bar(progress, task, label, total)
            finally:
                progress.update(task, description=label)  # what the last step was is no news at the end


@contextmanager
def output_to(log: Path) -> Iterator[None]:
    """File descriptors 1 and 2 of this process append to `log` for the block (what
    Blender logs while it renders here), and are given back after it."""
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    fd = os.open(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (fd, *saved):
            os.close(f)
