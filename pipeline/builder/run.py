"""`twin build`: plan the task graph from the sources, run it with progress."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..engine.cache import DEFAULT_LIMIT
from ..engine.executors import ExecutorFactory, local_pool
from ..engine.scheduler import BuildReport, Scheduler
from .tasks import plan


def build(sources: Path, out: Path, *, jobs: int | None = None, only: list[str] | None = None,
          cache: Path | None = None, quiet: bool = False, executor: ExecutorFactory = local_pool,
          cache_limit: int | None = DEFAULT_LIMIT, memory_limit: int | str | None = "auto") -> BuildReport:
    """`memory_limit`: each worker's address space in bytes, "auto" (its share of the
    machine) or None (no limit)."""
    t0 = time.perf_counter()
    p = plan(Path(sources), Path(out), only=only or None, cache=cache)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quiet:  # nothing to show: rich is not even imported (a quarter of a no-op's imports)
        return Scheduler(out, cache=cache, jobs=jobs, executor=executor, cache_limit=cache_limit,
                         memory_limit=memory_limit, roots=p.roots).run(p.tasks)
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    console = Console(file=sys.stderr)
    stages = sorted({t.stage for t in p.tasks}, key=["sources", "geometry", "assets", "terrain", "scene"].index)
    with Progress(TextColumn("{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False) as progress:
        bars = {s: progress.add_task(s, total=sum(t.stage == s for t in p.tasks)) for s in stages}
        scheduler = Scheduler(out, cache=cache, jobs=jobs, progress=lambda t: progress.advance(bars[t.stage]),
                              executor=executor, cache_limit=cache_limit, memory_limit=memory_limit,
                              roots=p.roots)
        report = scheduler.run(p.tasks)
    if report.cache.get("removed"):
        console.print(f"cache: dropped {report.cache['removed']} least recently used entries "
                      f"({report.cache['freed'] / 2**20:.0f} MB) to stay within {cache_limit / 2**20:.0f} MB")
    if p.unused and not only:
        console.print(f"not built (no placement or scenario uses them): {', '.join(p.unused)}")
    for warning in p.floorplan.warnings:
        console.print(f"floor plan: {warning}", markup=False)  # the messages name [floorplan] keys
    for line in source_warnings(report):
        console.print(line, markup=False)
    console.print(summary_line(report, len(p.tasks), time.perf_counter() - t0), markup=False, highlight=False,
                  soft_wrap=True)
    return report


def summary_line(report: BuildReport, tasks: int, seconds: float, most: int = 4) -> str:
    """What a build did, in a line: e.g. `built 3 of 52 tasks (source:x, geometry:x,
    asset:x), 49 fresh, in 4.2 s`; failed, blocked and cache-restored tasks counted apart."""
    failed = {e["task"] for e in report.explanations if "failed" in e} | {t for t, _ in report.failed}
    ran = [e["task"] for e in report.explanations if e["ran"] and e["task"] not in failed]  # in the order they ran
    restored = sum(not e["ran"] and e["reason"] == "restored from cache" for e in report.explanations)
    blocked = len(set(report.blocked) - failed)
    fresh = tasks - len(ran) - restored - len(failed) - blocked
    names = f" ({', '.join(ran[:most])}{f' and {len(ran) - most} more' if len(ran) > most else ''})" if ran else ""
    parts = [f"built {len(ran)} of {tasks} task{'s' if tasks != 1 else ''}{names}", f"{fresh} fresh"]
    if restored:
        parts.append(f"{restored} restored from the cache")
    if failed:
        parts.append(f"{len(failed)} failed")
    if blocked:
        parts.append(f"{blocked} not built")
    return ", ".join(parts) + f", in {seconds:.1f} s"


def source_warnings(report: BuildReport) -> list[str]:
    """What the readers could not carry (source task results' "warnings", kept for a
    task that did not rerun), a line each: `<asset>: warning: <message>`."""
    lines = []
    for name, result in sorted(report.results.items()):
        if name.startswith("source:"):
            lines += [f"{name.removeprefix('source:')}: warning: {w}" for w in result.get("warnings", [])]
    return lines


def failure_lines(report: BuildReport, traces: bool = False) -> list[str]:
    """What a build that failed somewhere tells its user at the end: each failure on
    its own line (a user error names its file and object; anything else names its
    task), then what was not built for want of it, and what was built on a failed
    task's last outputs. `traces`: a bug's trace under its line."""
    lines = []
    for e in report.errors:
        where = "" if "file" in e else f"{e['task']}: "
        lines.append(f"error: {where}{e['error']}")
        if traces and "trace" in e:
            lines.append(e["trace"].rstrip("\n"))
    by_cause: dict[tuple[str, ...], list[str]] = {}
    for name, behind in report.blocked.items():
        by_cause.setdefault(tuple(behind), []).append(name)
    for behind, names in sorted(by_cause.items()):
        cause = f" (blocked by {', '.join(behind)})" if behind else " (the build stopped)"
        lines.append(f"not built: {', '.join(sorted(names))}{cause}")
    stood_on: dict[tuple[str, ...], list[str]] = {}
    for why in report.explanations:
        if why.get("previous_of"):
            stood_on.setdefault(tuple(why["previous_of"]), []).append(why["task"])
    for previous, names in sorted(stood_on.items()):
        lines.append(f"made with the last good outputs of {', '.join(previous)} (not made in this build): "
                     f"{', '.join(sorted(names))}")
    return lines
