"""Progress of long commands on stderr (rich), so stdout stays the command's result
(`--json`, a path) whether or not a terminal is watching."""

from __future__ import annotations

import sys
from contextlib import contextmanager
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
    with Progress(*columns, console=Console(file=sys.stderr), transient=False) as progress:
        task = progress.add_task(label, total=total)
        try:
            yield Bar(progress, task, label, total)
        finally:
            progress.update(task, description=label)  # what the last step was is no news at the end
