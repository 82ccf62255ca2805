"""Keep going (DESIGN.md s.5, issue 25 item 5): a task that fails (bad input, memory
refused, its worker killed) fails alone, what needs it is blocked, everything else
builds; the run ends with every error listed and exit 1; what the failed asset made
last stays byte for byte as it was, and nothing of a failed run reaches the cache.

First the scheduler on the toy graph, then `twin build` on the mini sources."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

import toy_graph
from helpers import twin
from pipeline.engine.executors import in_process
from pipeline.engine.scheduler import Scheduler
from pipeline.errors import UserError


def _graph(src: Path, out: Path, **actions) -> list:
    """The toy graph with some tasks' actions replaced (upper_b=toy_graph.refuse, ...)."""
    graph = toy_graph.tasks(src, out, delay=0.05)
    for t in graph:
        t.action = actions.get(t.name.replace(":", "_"), t.action)
    return graph


def _why(report) -> dict[str, dict]:
    return {e["task"]: e for e in report.explanations}


# --- the scheduler --------------------------------------------------------------------


def test_a_failure_blocks_only_what_needs_it_and_leaves_its_last_outputs(src, tmp_path):
    out = tmp_path / "build"
    toy_graph.build(src, out)
    last = json.loads((out / ".state.json").read_text())["tasks"]["upper:b"]
    (src / "a.txt").write_text("alpha, edited")
    (src / "b.txt").write_text("beta, edited")
    r = Scheduler(out, jobs=2).run(_graph(src, out, upper_b=toy_graph.refuse))
    assert r.errors == [{"task": "upper:b", "error": f"{src / 'b.txt'}: line 1: not a word",
                         "file": str(src / "b.txt"), "object": "line 1", "message": "not a word"}]
    assert r.failed == [("upper:b", f"{src / 'b.txt'}: line 1: not a word")]
    assert r.blocked == {"join": ["upper:b"]}
    assert _why(r)["join"]["reason"] == "blocked by upper:b"
    assert (out / "up" / "a.txt").read_text() == "ALPHA, EDITED"  # the independent task built
    assert (out / "up" / "b.txt").read_text() == "BETA"  # not the half the failed run wrote
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"
    state = json.loads((out / ".state.json").read_text())["tasks"]["upper:b"]
    assert state == last  # the last good run's record, still

    # nothing of the failed run was kept: the same input fails again, the rest is done
    again = Scheduler(out, jobs=2).run(_graph(src, out, upper_b=toy_graph.refuse))
    assert again.ran == ["upper:b"] and [e["task"] for e in again.errors] == ["upper:b"]
    fixed = toy_graph.build(src, out)
    assert sorted(fixed.ran) == ["join", "upper:b"] and not fixed.errors
    assert (out / "joined.txt").read_text() == "ALPHA, EDITED+BETA, EDITED"


def test_a_task_that_may_stand_on_a_failed_dependencys_last_outputs(src, tmp_path):
    """Task.previous_ok (the scene): it runs on what the failed task made last, keyed
    on that, and is blocked only when there is none."""
    out = tmp_path / "build"

    def graph(fail: bool) -> list:
        g = _graph(src, out, **({"upper_b": toy_graph.refuse} if fail else {}))
        g[-1].previous_ok = ("upper:b",)
        return g

    cold = Scheduler(out).run(graph(fail=True))
    assert cold.blocked == {"join": ["upper:b"]} and not (out / "joined.txt").exists()
    Scheduler(out).run(graph(fail=False))

    (src / "b.txt").write_text("beta, edited")
    r = Scheduler(out).run(graph(fail=True))  # b fails, and join's inputs are as they were
    assert r.ran == ["upper:b"] and _why(r)["join"]["reason"] == "up to date"
    assert _why(r)["join"]["previous_of"] == ["upper:b"]
    (src / "a.txt").write_text("alpha, edited")
    r = Scheduler(out).run(graph(fail=True))
    assert sorted(r.ran) == ["join", "upper:a", "upper:b"] and _why(r)["join"]["previous_of"] == ["upper:b"]
    assert (out / "joined.txt").read_text() == "ALPHA, EDITED+BETA"

    # only on the dependencies it names: a failed upper:a blocks it
    (src / "a.txt").write_text("alpha, broken")
    g = graph(fail=True)
    g[0].action = toy_graph.refuse
    assert Scheduler(out).run(g).blocked == {"join": ["upper:a"]}

    (out / "up" / "b.txt").unlink()  # its last outputs are no longer all there: nothing to stand on
    (src / "a.txt").write_text("alpha, edited again")
    r = Scheduler(out).run(graph(fail=True))
    assert r.blocked == {"join": ["upper:b"]}
    assert (out / "joined.txt").read_text() == "ALPHA, EDITED+BETA"


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_task_whose_worker_dies_fails_alone(src, tmp_path, jobs):
    """A worker killed under its task (as the out-of-memory killer does) takes its pool
    with it: the tasks that were running beside it run again one at a time, and the
    one that dies alone is the failure."""
    out = tmp_path / "build"
    toy_graph.build(src, out)
    (src / "a.txt").write_text("alpha, edited")
    (src / "b.txt").write_text("beta, edited")
    r = Scheduler(out, jobs=jobs).run(_graph(src, out, upper_b=toy_graph.die))
    assert [(e["task"], e["kind"]) for e in r.errors] == [("upper:b", "worker")]
    assert r.errors[0]["error"].startswith("its worker process died") and "SIGKILL" in r.errors[0]["error"]
    assert r.blocked == {"join": ["upper:b"]}
    assert (out / "up" / "a.txt").read_text() == "ALPHA, EDITED"
    assert (out / "up" / "b.txt").read_text() == "BETA"
    assert sorted(e["task"] for e in r.explanations) == ["join", "upper:a", "upper:b"]  # each once
    assert not (out / ".staging").exists()
    fixed = toy_graph.build(src, out)
    assert sorted(fixed.ran) == ["join", "upper:b"]


def test_a_pool_that_broke_between_two_waits_is_replaced(src, tmp_path):
    """A worker may die while the scheduler is not waiting on it: the pool then
    refuses the next task, and a new pool runs it."""
    from concurrent.futures import BrokenExecutor, ThreadPoolExecutor

    made = []

    class Broken(ThreadPoolExecutor):
        def submit(self, fn, /, *args, **kwargs):
            if self is made[0]:
                raise BrokenExecutor("a child process terminated abruptly")
            return super().submit(fn, *args, **kwargs)

    out = tmp_path / "build"
    r = Scheduler(out, jobs=2, executor=lambda w: made.append(Broken(w.count)) or made[-1]).run(
        toy_graph.tasks(src, out))
    assert sorted(r.ran) == ["join", "upper:a", "upper:b"] and not r.errors and len(made) == 2
    assert sorted(e["task"] for e in r.explanations) == ["join", "upper:a", "upper:b"]
    assert (out / "joined.txt").read_text() == "ALPHA+BETA"


def test_a_build_ignores_sigpipe_while_it_runs(src, tmp_path):
    """A worker's death leaves the pool's pipes to it without a reader: with SIGPIPE at
    its default (gmsh's initialize resets it behind Python's back) writing to them
    killed the whole process, pytest included, instead of failing the task."""
    import signal

    out = tmp_path / "build"
    before = signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    try:
        r = Scheduler(out, executor=in_process).run(_graph(src, out, upper_a=toy_graph.sigpipe_state))
        assert r.results["upper:a"]["sigpipe_ignored"] is True
        assert signal.getsignal(signal.SIGPIPE) == signal.SIG_DFL  # as it was, after the build
    finally:
        signal.signal(signal.SIGPIPE, before)


@pytest.mark.parametrize("executor", ["pool", "in-process"])
def test_running_out_of_memory_is_a_failure_not_a_trace(src, tmp_path, executor):
    out = tmp_path / "build"
    extra = {"executor": in_process} if executor == "in-process" else {}
    r = Scheduler(out, jobs=1, **extra).run(_graph(src, out, upper_a=toy_graph.exhaust))
    assert r.errors == [{"task": "upper:a", "error": "ran out of memory", "kind": "memory"}]
    assert r.blocked == {"join": ["upper:a"]}
    assert not (out / "up" / "a.txt").exists() and (out / "up" / "b.txt").read_text() == "BETA"


def test_a_task_the_planner_refused_fails_without_running(src, tmp_path):
    out = tmp_path / "build"
    graph = _graph(src, out)
    graph[1].problem = UserError(src / "b.toml", "key", "not a key")
    graph[1].action = toy_graph.die  # never called
    r = Scheduler(out, executor=in_process).run(graph)
    assert r.errors == [{"task": "upper:b", "error": f"{src / 'b.toml'}: key: not a key",
                         "file": str(src / "b.toml"), "object": "key", "message": "not a key"}]
    assert _why(r)["upper:b"]["ran"] is False and r.blocked == {"join": ["upper:b"]}
    assert r.ran == ["upper:a"]


# --- twin build on the mini sources ------------------------------------------------------


def build_json(src: Path, out: Path, code: int = 0) -> dict:
    proc = twin("build", "--sources", src, "--out", out, "--json")
    assert proc.returncode == code and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    doc = json.loads(proc.stdout[proc.stdout.rfind('{\n "failed"'):])  # OpenCASCADE prints to stdout
    doc["errors"] = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    doc["ran"] = {e["task"] for e in doc["tasks"] if e["ran"]}
    doc["why"] = {e["task"]: e for e in doc["tasks"]}
    return doc


def chains(names) -> set[str]:
    """The asset chains' tasks and the scene among `names` (the viewer's tasks follow
    the scene)."""
    return {n for n in names if n == "scene" or n.split(":")[0] in ("source", "geometry", "asset")}


def outputs(out: Path, asset: str) -> dict[str, str]:
    """sha256 of every file of an asset's package, LOD variants and intermediate files."""
    folders = [*out.glob(f"models/{asset}"), *out.glob(f"models/{asset}__lod*"), out / ".source" / asset,
               out / ".ir" / asset]
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for folder in folders for p in sorted(folder.rglob("*")) if p.is_file()}


def scene_files(out: Path) -> dict[str, str]:
    scene = out / "scene"
    return {str(p.relative_to(scene)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(scene.rglob("*")) if p.is_file()}


def nudge(path: Path) -> None:
    from pipeline.bench.builds import nudge_source

    nudge_source(path, 0.005)


@pytest.fixture
def case(mini_copy) -> tuple[Path, Path]:
    """Copies of the mini sources and their build, for one case to break."""
    return mini_copy


def test_one_unreadable_source_fails_its_chain_and_the_rest_builds(case):
    src, out = case
    pole, kiosk = outputs(out, "pole"), outputs(out, "kiosk")
    obj = src / "assets" / "pole" / "pole.obj"
    good = obj.read_bytes()
    obj.write_text("v 0 0 0\nthis is not a mesh\n")
    nudge(src / "assets" / "kiosk" / "kiosk.stl")  # the other asset's edit still reaches the scene
    scene = scene_files(out)

    doc = build_json(src, out, code=1)
    assert [(e["task"], Path(e["file"]).name) for e in doc["failed"]] == [("source:pole", "pole.obj")]
    assert len(doc["errors"]) == 1 and "pole.obj" in doc["errors"][0]
    assert doc["not_built"] == {"geometry:pole": ["source:pole"], "asset:pole": ["source:pole"]}
    assert chains(doc["ran"]) == {"source:pole", "source:kiosk", "geometry:kiosk", "asset:kiosk", "scene"}
    # the scene reads packages through their views (builder.placed_task): pole's is made of its last package
    assert doc["why"]["placed:pole"]["previous_of"] == ["asset:pole"]
    assert outputs(out, "pole") == pole  # byte for byte
    assert outputs(out, "kiosk") != kiosk and scene_files(out) != scene

    # nothing of the failure was kept: the same source fails again, nothing else runs
    again = build_json(src, out, code=1)
    assert again["ran"] == {"source:pole"} and again["why"]["scene"]["reason"] == "up to date"
    # the source as it was: its chain is the last good one, nothing runs
    obj.write_bytes(good)
    assert build_json(src, out)["ran"] == set()
    nudge(obj)  # a real edit: its chain and the scene, nothing of the other asset
    assert chains(build_json(src, out)["ran"]) == {"source:pole", "geometry:pole", "asset:pole", "scene"}


def test_a_broken_asset_toml_and_a_garbage_step_beside_a_good_edit(case):
    """A new asset whose STEP cannot be read has no package to place: the scene waits
    (the last scene stays); an asset.toml that cannot be read is reported by key."""
    import mini_sources

    src, out = case
    kiosk = outputs(out, "kiosk")
    scene = scene_files(out)
    toml = src / "assets" / "kiosk" / "asset.toml"
    good_toml = toml.read_text()
    toml.write_text(good_toml.replace('category = "kiosk"', "category = 7"))
    box = src / "assets" / "box"
    box.mkdir()
    (box / "box.step").write_text("ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=GARBAGE(;\nENDSEC;\n"
                                  "END-ISO-10303-21;\n")
    (box / "asset.toml").write_text('category = "box"\nsource = "box.step"\n')
    mini_sources.write_plan(src / "floorplan" / "plan.dxf",
                            [*mini_sources.PLACEMENTS, ("B-1", "box", "L1", 2.0, -4.0, 0.0, 0.0)])
    nudge(src / "assets" / "pole" / "pole.obj")

    doc = build_json(src, out, code=1)
    failed = {e["task"]: e for e in doc["failed"]}
    assert set(failed) == {"asset:kiosk", "source:box"}
    assert (Path(failed["asset:kiosk"]["file"]).name, failed["asset:kiosk"]["object"]) == ("asset.toml", "category")
    assert Path(failed["source:box"]["file"]).name == "box.step"
    assert len(doc["errors"]) == 2
    assert chains(doc["not_built"]) == {"geometry:box", "asset:box", "scene"}
    assert all(behind == ["source:box"] for behind in doc["not_built"].values())  # and what follows the scene
    assert {"source:pole", "geometry:pole", "asset:pole"} <= doc["ran"]
    assert outputs(out, "kiosk") == kiosk and not (out / "models" / "box").exists()
    assert scene_files(out) == scene

    info = twin("info", "--sources", src)
    problems = [line for line in info.stderr.splitlines() if line.startswith("error:")]
    assert info.returncode == 1 and len(problems) == 2, info.stderr
    assert any("asset.toml" in p and "category" in p for p in problems) and any("box.step" in p for p in problems)

    # both fixed: the box's chain and the scene run; the kiosk is as it was built
    toml.write_text(good_toml)
    (box / "box.step").unlink()
    shutil.copy(src / "assets" / "kiosk" / "kiosk.stl", box / "box.stl")
    (box / "asset.toml").write_text('category = "box"\nsource = "box.stl"\n')
    fixed = build_json(src, out)
    assert chains(fixed["ran"]) == {"source:box", "geometry:box", "asset:box", "scene"}
    assert outputs(out, "kiosk") == kiosk


def half_then_fail(staging: Path, asset_toml: str, **_) -> dict:
    """A task action that writes a part of every file its chain makes, then finds its
    input bad."""
    for rel in ("models/pole/model.sdf", "models/pole/manifest.json", ".source/pole/pole.ir", ".ir/pole/pole.ir"):
        (staging / rel).parent.mkdir(parents=True, exist_ok=True)
        (staging / rel).write_text("half")
    raise UserError(asset_toml, "source", "refused halfway")


@pytest.mark.parametrize("stage", ["source", "geometry", "asset"])
def test_a_failure_in_any_task_of_a_chain_leaves_the_last_package(case, stage):
    """Outputs reach the build folder from staging, and only on success: whichever of
    its three tasks fails, the asset's package is byte for byte the last one, and the
    scene is made from it."""
    from pipeline.builder.tasks import plan

    src, out = case
    before = outputs(out, "pole")
    nudge(src / "assets" / "pole" / "pole.obj")  # the whole chain reruns
    p = plan(src, out)
    for t in p.tasks:
        if t.name == f"{stage}:pole":
            t.action = half_then_fail
    r = Scheduler(out, executor=in_process).run(p.tasks)
    assert [e["task"] for e in r.errors] == [f"{stage}:pole"]
    later = ["source", "geometry", "asset"][["source", "geometry", "asset"].index(stage) + 1:]
    assert {n: b for n, b in r.blocked.items() if n in chains(r.blocked)} == {
        f"{s}:pole": [f"{stage}:pole"] for s in later}
    assert _why(r)["placed:pole"]["previous_of"] == ["asset:pole"]  # the scene's view of pole's last package
    after = outputs(out, "pole")
    kept = {k: v for k, v in before.items() if k.startswith("models/")}
    assert {k: v for k, v in after.items() if k.startswith("models/")} == kept
    assert not any(Path(out / k).read_bytes() == b"half" for k in after)
