"""Progress of long commands on stderr (rich), so stdout stays the command's result
(`--json`, a path) whether or not a terminal is watching; and Blender's log (its C
code writes on file descriptors 1 and 2) into a file instead of the terminal."""

from __future__ import annotations

import contextlib
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


class Bar:
    """One bar: a count of steps done out of a total that may grow as work is found.
    It appears when it is first told of some work: an error before that comes alone."""

    def __init__(self, progress, label: str, total: int | None):
        self._progress, self._label, self._total = progress, label, total
        self._task = None

    def _show(self, **fields) -> None:
        if self._task is None:
            self._progress.start()
            self._task = self._progress.add_task(self._label, total=self._total)
        self._progress.update(self._task, total=self._total, **fields)

    def update(self, done: int, total: int | None = None) -> None:
        if total is not None:
            self._total = total
        self._show(completed=done)

    def add(self, steps: int) -> None:
        """`steps` more to do (none: no bar yet)."""
        if steps <= 0:
            return
        self._total = (self._total or 0) + steps
        self._show()

    def step(self, what: str | None = None) -> None:
        """One step done; `what` says what ran (shown beside the bar's label)."""
        self._show(advance=1, description=self._label if what is None else f"{self._label}: {what}")

    def close(self) -> None:
        if self._task is not None:
            self._progress.update(self._task, description=self._label)  # the last step is no news at the end
            self._progress.stop()


@contextmanager
def bar(label: str, total: int | None = None) -> Iterator[Bar]:
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    columns = (TextColumn("{task.description:<28}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    sys.stderr.flush()
    # the terminal's stderr as it is now: a block of output_to inside keeps the bar on it
    # (a stderr that is no file, as click's test runner gives, is used as it is)
    try:
        terminal = os.fdopen(os.dup(sys.stderr.fileno()), "w")
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both of the last two
        terminal = contextlib.nullcontext(sys.stderr)
    with terminal as stream:
        # sys.stdout and sys.stderr stay what they are: on a terminal rich would swap in
        # proxies printing above the bar, and what Blender's Python logs (the glTF
        # importer's handler keeps the stream it found) would reach the terminal
        progress = Progress(*columns, console=Console(file=stream), transient=False, redirect_stdout=False,
                            redirect_stderr=False)
        shown = Bar(progress, label, total)
        try:
            yield shown
        finally:
            shown.close()


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
