"""The `twin` command line: parses flags and calls the layers below, nothing more.

User errors exit 1 with one line naming the file and the object; usage errors exit 2
(click); long work shows rich progress on stderr.
"""

from __future__ import annotations

import contextlib
import functools
import json
import sys
from pathlib import Path

import click

from .engine.executors import EXECUTORS
from .errors import UserError

SOURCES = click.option("--sources", type=click.Path(path_type=Path), default=Path("sources"),
                       show_default=True, help="sources folder (site.toml, floorplan/, assets/, scenarios/)")
OUT = click.option("--out", type=click.Path(path_type=Path), default=Path("build"),
                   show_default=True, help="build folder")


def user_errors(fn):
    """One clear line and exit 1 for bad input; never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except UserError as e:
            for line in str(e).splitlines():  # a config's every problem, one line each
                click.echo(f"error: {line}", err=True)
            sys.exit(1)

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="substation-twin")
def main():
    """substation-twin: build georeferenced, LOD-ed substation digital twins."""


@main.command()
@SOURCES
@user_errors
def info(sources: Path):
    """What the sources hold, and what is wrong with them."""
    from .info import gather, render
    from .progress import bar

    with bar("reading") as progress:
        report = gather(sources, progress=progress)
    render(report)
    if report.problems:
        sys.exit(1)


@main.command()
@SOURCES
@OUT
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None, help="cores to use: worker processes, and threads of a task running alone (default: all)")
@click.option("--only", multiple=True, metavar="ASSET", help="build just this asset's package (repeatable)")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder (default: OUT/.cache)")
@click.option("--cache-limit", default="2G", show_default=True, metavar="SIZE",
              help="after a build that stored something, drop the least recently used cache entries "
                   "above this size (e.g. 500M; 0 keeps only this build's; 'none' keeps all)")
@click.option("--memory-limit", default="auto", show_default=True, metavar="SIZE",
              help="address space each worker process may use (e.g. 8G; 'auto': its share of the machine's "
                   "memory, at least 4G; 'none': no limit); a task that needs more fails on its own")
@click.option("--explain", is_flag=True, help="say for each task why it ran or was skipped")
@click.option("--json", "as_json", is_flag=True, help="print the explanation as JSON on stdout")
@click.option("--executor", type=click.Choice(sorted(EXECUTORS)), default="local", show_default=True,
              help="where tasks run: worker processes, this one (for a debugger or profiler), "
                   "or dask.distributed (worker processes on this machine, or --scheduler's cluster)")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="with --executor dask: the dask scheduler to run on (e.g. tcp://host:8786), whose "
                   "workers see the sources and OUT at the same paths as here (default: a local cluster)")
@user_errors
def build(sources: Path, out: Path, jobs: int | None, only: tuple[str, ...], cache: Path | None,
          cache_limit: str, memory_limit: str, explain: bool, as_json: bool, executor: str,
          scheduler: str | None):
    """Build the model packages and the scene."""
    from .engine.cache import parse_size
    from .builder.run import build as run_build, failure_lines

    try:
        limit = None if cache_limit.strip().lower() == "none" else parse_size(cache_limit)
    except ValueError:
        raise click.BadParameter(f"{cache_limit!r} is not a size (like 500M or 2G)", param_hint="--cache-limit")
    memory = memory_limit.strip().lower()
    try:
        memory = None if memory == "none" else memory if memory == "auto" else parse_size(memory)
    except ValueError:
        raise click.BadParameter(f"{memory_limit!r} is not a size (like 8G), auto or none",
                                 param_hint="--memory-limit")
    if scheduler is not None and executor != "dask":
        raise click.BadParameter("a scheduler is for --executor dask", param_hint="--scheduler")
    factory = functools.partial(EXECUTORS[executor], scheduler=scheduler) if scheduler else EXECUTORS[executor]
    report = run_build(sources, out, jobs=jobs, only=list(only), cache=cache, quiet=as_json,
                       executor=factory, cache_limit=limit, memory_limit=memory)
    # how long each task that ran took in its worker (the build files carry no timings)
    tasks = [{**e, "seconds": round(report.timings[e["task"]], 4)} if e["task"] in report.timings else e
             for e in report.explanations]
    if as_json:
        # "failed" stays the first key: readers find the document by it (bench.builds)
        click.echo(json.dumps({"tasks": tasks, "failed": report.errors, "not_built": report.blocked},
                              indent=1, sort_keys=True))
    elif explain:
        for e in tasks:
            took = f" ({e['seconds']:.2f} s)" if "seconds" in e else ""
            same = f" ({', '.join(e['cut_off_after'])} made the same files)" if "cut_off_after" in e else ""
            mark = "FAIL" if "failed" in e else "RAN " if e["ran"] else "skip"
            click.echo(f"{mark} {e['task']}: {e['reason']}{same}{took}")
    if report.failed:
        # every failure at the end, after the progress bars: one line each
        for line in failure_lines(report, traces=explain):
            click.echo(line, err=True)
        sys.exit(1)


@main.command()
@SOURCES
@OUT
@user_errors
def validate(sources: Path, out: Path):
    """Validate the build; writes OUT/reports/, exits 1 on errors."""
    from .progress import bar
    from .validate.report import validate_build

    with bar("validating") as progress:
        summary = validate_build(sources, out, progress)
    click.echo(f"{summary['errors']} errors, {summary['warnings']} warnings -> {out / 'reports'}")
    if summary["errors"]:
        sys.exit(1)


@main.command()
@click.argument("scenario", type=click.Path(path_type=Path))
@OUT
@click.option("--record", type=click.Path(path_type=Path), default=None,
              help="also write the run as MCAP (Foxglove schemas: states, moving parts) to this file")
@user_errors
def run(scenario: Path, out: Path, record: Path | None):
    """Run a scenario on the built scene OUT: states and variants over time, into OUT/runs/<scenario>/."""
    from .progress import bar
    from .runtime.run import run_scenario

    with bar("running") as progress:
        summary = run_scenario(scenario, out, progress=progress)
    if record is not None:
        from .live.foxglove_io import record_run

        summary["record"] = record_run(scenario, out, record)
    click.echo(json.dumps(summary, indent=1, sort_keys=True))


@main.command()
@click.argument("scenario", type=click.Path(path_type=Path), required=False)
@click.option("--study", is_flag=True, help="the study's six light conditions on the main-tank gauge")
@SOURCES
@OUT
@user_errors
def render(scenario: Path | None, study: bool, sources: Path, out: Path):
    """Render image sets with labels and the study's image metrics (Blender's log:
    OUT/logs/render_<scenario or study>.log)."""
    from .progress import bar, output_to
    from .render.scenario import render_scenario
    from .render.study import render_study

    if not study and scenario is None:
        raise click.UsageError("give a SCENARIO or --study")
    log = out / "logs" / f"render_{'study' if study else scenario.stem}.log"
    if out.is_dir():  # else the renderer says what is missing, and no build folder appears
        log.parent.mkdir(exist_ok=True)
        log.write_bytes(b"")  # this run's
    with bar("frames") as progress, (output_to(log) if out.is_dir() else contextlib.nullcontext()):
        if study:
            render_study(out, sources, progress=progress.update)
        else:
            render_scenario(scenario, out, sources, progress=progress.update)
    click.echo(f"Blender's log: {log}", err=True)


@main.command()
@click.argument("config", type=click.Path(path_type=Path))
@SOURCES
@OUT
@click.option("--frames", type=click.IntRange(min=1), default=None,
              help="render the first N frames of the config's sequence (default: its count)")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="where frames render: worker processes here, or dask.distributed")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="a dask scheduler's address (default: a local cluster); its workers must see OUT and "
                   "the sources at the same paths")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="frames rendered at once (each renders on 2 threads)")
@user_errors
def dataset(config: Path, sources: Path, out: Path, frames: int | None, executor: str, scheduler: str | None,
            workers: int):
    """Render a labelled image set (images, instance masks, depth, COCO, frames.jsonl)
    from the built scene OUT into OUT/datasets/<name>/; a stopped run resumes."""
    from .datasets.run import blender_log, run_dataset

    from .progress import bar

    if scheduler is not None and executor != "dask":
        raise click.BadParameter("a scheduler is for --executor dask", param_hint="--scheduler")
    with bar("frames") as progress:
        folder = run_dataset(config, out, frames=frames, executor=executor, scheduler=scheduler, workers=workers,
                             sources=sources, progress=progress.update)
    click.echo(f"Blender's log: {blender_log(out, folder.name)}", err=True)
    click.echo(str(folder))


@main.command()
@click.argument("dataset_folder", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="build folder whose reports/ receive the report (default: the dataset's own build)")
@SOURCES
@user_errors
def baseline(dataset_folder: Path, out: Path | None, sources: Path):
    """The study's gauge reader over a dataset's conditions: reading error against sun
    elevation and local time, into OUT/reports/baseline_<name>.json and .html."""
    from .perception.baseline import run_baseline
    from .progress import bar

    with bar("frames") as progress:
        report = run_baseline(dataset_folder, out, sources=sources, progress=progress.update)
    click.echo(str(report))

@main.command()
@click.argument("scenario", type=click.Path(path_type=Path), required=False)
@OUT
@SOURCES
@click.option("--speed", type=float, default=1.0, show_default=True,
              help="simulated seconds per real second (the study's accelerated virtual time)")
@click.option("--start", metavar="ISO-TIME", default=None,
              help="the clock's first instant (without an offset: the site's wall-clock time; "
                   "default: the scenario's start, or now)")
@click.option("--bind", default="127.0.0.1", show_default=True, help="address the sockets listen on")
@click.option("--port", type=click.IntRange(0, 65532), default=5555, show_default=True,
              help="the command socket; PUB on PORT+1, the WebSocket and live page on PORT+2, Foxglove's "
                   "protocol on PORT+3 (0: any free ones)")
@click.option("--sensor", type=click.Path(path_type=Path), default=None,
              help="a dataset config whose [sensor] renders use and whose PTZ presets the camera knows "
                   "(default: 640x480, the phone's defaults)")
@click.option("--record", type=click.Path(path_type=Path), default=None,
              help="write the run to this MCAP file (Foxglove schemas)")
@click.option("--step", type=click.FloatRange(min=0.001), default=1.0, show_default=True,
              help="without a SCENARIO: the default scenario's step, simulated seconds")
@click.option("--no-render", is_flag=True, help="no Blender process: every command but render")
@click.option("--no-foxglove", is_flag=True, help="do not serve Foxglove's live protocol (on PORT+3)")
@click.option("--inputs", type=click.Path(path_type=Path), default=None,
              help="external signals (IEC 61850, MQTT) mapped onto settable inputs: a TOML file "
                   "(schemas/inputs.schema.json)")
@click.option("--gazebo", "gazebo_world", metavar="WORLD", default=None,
              help="push the sun, switch joints and bound materials into the running gz-sim world WORLD "
                   "(its transport; tools/gzbridge)")
@user_errors
def serve(scenario: Path | None, out: Path, sources: Path, speed: float, start: str | None, bind: str, port: int,
          sensor: Path | None, record: Path | None, step: float, no_render: bool, no_foxglove: bool,
          inputs: Path | None, gazebo_world: str | None):
    """The live twin: the scenario (default: every bound state settable) on a simulated clock,
    commands on tcp://BIND:PORT (ZeroMQ, JSON), state published every step, renders on request."""
    from .live.app import make_server, serve as run_server

    run_server(make_server(out, sources, scenario, speed=speed, start=start, bind=bind, port=port, sensor=sensor,
                           render=not no_render, record=record, foxglove=not no_foxglove, step_s=step,
                           inputs=inputs, gazebo=gazebo_world))


@main.command()
@OUT
@click.option("--port", type=click.IntRange(0, 65535), default=None,
              help="port on 127.0.0.1 (default: 8000, or a free one when 8000 is taken; 0: any free one)")
@user_errors
def view(out: Path, port: int | None):
    """Serve OUT on 127.0.0.1 for the web viewer (OUT/viewer/index.html) and the globe:
    its regular files only (no dotfiles, no folder listings, no symlinks out of OUT),
    to requests addressed to 127.0.0.1, localhost or [::1] at the port served."""
    from .viewer.serve import DEFAULT_PORT, address, server

    page = out / "viewer" / "index.html"
    if not page.is_file():
        raise UserError(page, None, "no viewer in this build folder: run `twin build` first")
    missing = sorted(p.parent.name for p in (out / "viewer" / "lib").glob("*/MISSING.txt"))
    if missing:
        click.echo(f"warning: built without {', '.join(missing)}: bash .ci/install-tools, then twin build", err=True)
    try:
        srv = server(out, port)
    except OSError as e:
        raise UserError(out, None, f"cannot serve on 127.0.0.1:{port or DEFAULT_PORT}: {e.strerror} "
                                   "(try --port 0)") from None
    url = address(srv)
    if port is None and srv.server_address[1] != DEFAULT_PORT:
        click.echo(f"port {DEFAULT_PORT} is taken: serving on {srv.server_address[1]}", err=True)
    click.echo(f"viewer: {url}viewer/index.html")
    click.echo(f"globe:  {url}viewer/globe.html")
    click.echo("Ctrl-C stops the server")
    sys.stdout.flush()  # the address, before serving, also when piped
    try:
        srv.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        srv.server_close()


@main.command()
@SOURCES
@OUT
@click.option("--quick", is_flag=True, help="fewer repeats and sizes (for tests)")
@click.option("--section", "sections", multiple=True, metavar="NAME",
              help="run only this section (repeatable), e.g. build, scale, gazebo, lod")
@user_errors
def bench(sources: Path, out: Path, quick: bool, sections: tuple[str, ...]):
    """Speed against error for every stage; writes OUT/reports/bench.json and bench.html."""
    from .bench import run_bench

    path = run_bench(sources, out, quick=quick, only=list(sections) or None)
    click.echo(f"wrote {path}")


if __name__ == "__main__":
    main()
