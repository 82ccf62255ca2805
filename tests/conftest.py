"""Fixtures shared across test files. The sample's build and the mini sources' build
are made once per test run (once across pytest-xdist's workers, helpers.made_once),
in the run's temporary folder, never the repository's build/; tests read them and
copy or link what they change."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path

import pytest

import pipeline  # noqa: F401  before a test module loads numpy: its idle OpenBLAS threads sleep (pipeline/__init__.py)
from helpers import ROOT, SOURCES, made_once, twin

CODE = ROOT / "pipeline"


def _build(sources: Path, out: Path, *args: str) -> None:
    proc = twin("build", "--sources", sources, "--out", out, "--json", *args, timeout=3600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-4000:]


def _make_sample(folder: Path) -> None:
    shutil.copytree(SOURCES, folder / "sources")
    _build(folder / "sources", folder / "build")


def _sample(tmp_path_factory) -> Path:
    return made_once(tmp_path_factory, "sample", [SOURCES, CODE], _make_sample)


@pytest.fixture(scope="session")
def sample_build(tmp_path_factory) -> Path:
    """The sample substation built once per run: the tests that render, label,
    validate or view it share it. Built from a copy of sources/ beside it, as a
    checkout's build/ is (a task's key holds its inputs' paths relative to the build
    folder: a copy of both folders side by side finds the build's cache entries).
    The build starts as soon as the tests are collected (pytest_collection_finish)."""
    return _sample(tmp_path_factory) / "build"


def pytest_collection_finish(session):
    """Start the sample build in the background once the tests that need it are known:
    the workers run the other tests meanwhile, and the first that needs the sample
    waits on made_once's lock. The thread only waits on the build's process, and a
    failed build is recorded by made_once for every asker to report."""
    if any("sample_build" in getattr(item, "fixturenames", ()) for item in session.items):
        factory = session.config._tmp_path_factory
        # The worker's base folder is made here, before the thread starts: the first
        # getbasetemp() empties the folder, without a lock, so made in the thread it can
        # empty the folder of a module fixture that the first test is making.
        factory.getbasetemp()
        threading.Thread(target=_build_quietly, args=(factory,), name="sample-build", daemon=True).start()


def _build_quietly(factory) -> None:
    try:
        _sample(factory)
    except BaseException:  # made_once recorded it; the fixture raises it where a test needs the sample
        pass


@pytest.fixture(scope="session")
def mini_build(tmp_path_factory) -> tuple[Path, Path]:
    """The mini sources (tests/mini_sources.py, their defaults) and their build by the
    local pool with two jobs, made once per run: (sources, build), side by side as
    src/ and build/. Never edit them: copy both to src/ and build/ of one folder (the
    tasks' keys stay the same), or build elsewhere."""
    import mini_sources

    def make(folder: Path) -> None:
        mini_sources.make(folder / "src")
        _build(folder / "src", folder / "build", "--jobs", "2")

    folder = made_once(tmp_path_factory, "mini", [Path(mini_sources.__file__), CODE], make)
    return folder / "src", folder / "build"


@pytest.fixture
def mini_copy(mini_build, tmp_path) -> tuple[Path, Path]:
    """Copies of the mini sources and their build, side by side as the originals are
    (tmp_path/src, tmp_path/build), for a test to edit and build again."""
    src, out = mini_build
    shutil.copytree(src, tmp_path / "src")
    shutil.copytree(out, tmp_path / "build", symlinks=True)
    return tmp_path / "src", tmp_path / "build"


@pytest.fixture
def src(tmp_path) -> Path:
    """The toy graph's sources (tests/toy_graph.py): a.txt and b.txt."""
    d = tmp_path / "src"
    d.mkdir()
    (d / "a.txt").write_text("alpha")
    (d / "b.txt").write_text("beta")
    return d


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """For pytest-xdist's --dist loadgroup (make test): the tests that share a module's
    fixture (one of its parameters, when it has them), directly or through another
    test that uses it with theirs, run on one worker, so that each is made once; the
    others are spread one by one. The marks are set before xdist reads them."""
    shared = {item: _module_fixtures(item) for item in items}
    group = _fixture_groups(shared)
    for item, names in shared.items():
        if names:
            item.add_marker(pytest.mark.xdist_group(group[item.module.__name__, names[0]]))
    result = yield  # test_grouping checks that xdist took the marks
    # The costly first, the quick ones last to fill the gaps: a long test (its mark)
    # and the tests that share a module fixture while the sample builds in the
    # background, then what needs the sample. A long test that waits on clocks among
    # the quick ones last would wait beside other tests' waits (the dask cluster's),
    # leaving both cores idle; first, the sample's build and the fixtures fill them.
    # A test that drives a browser page (seconds a page) last would leave the other
    # worker idle while it draws: such tests come before the quick ones.
    items.sort(key=_cost_rank)
    return result


def _module_fixtures(item) -> list[str]:
    """The fixtures of a module's scope (or a class's or package's) that `item` uses,
    a parametrized one by its parameter's index."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    spec = getattr(item, "callspec", None)
    return [f"{name}[{spec.indices[name]}]" if spec is not None and name in spec.params else name
            for name in sorted(info.name2fixturedefs)
            if info.name2fixturedefs[name][-1].scope in ("module", "class", "package")]


def _fixture_groups(shared: dict) -> dict[tuple[str, str], str]:
    """Each (module, fixture) to its group's name: the module and the fixtures that
    tests use together, joined over every test of the module that uses one."""
    parent: dict[tuple[str, str], tuple[str, str]] = {}

    def root(key):
        while parent.setdefault(key, key) != key:
            key = parent[key]
        return key

    for item, names in shared.items():
        module = item.module.__name__
        for name in names:
            parent[root((module, name))] = root((module, names[0]))
    members: dict = {}
    for key in parent:
        members.setdefault(root(key), []).append(key[1])
    return {key: f"{key[0]}:{'+'.join(sorted(members[root(key)]))}" for key in parent}


def _cost_rank(item) -> int:
    if item.get_closest_marker("long"):
        return -1
    if "sample_build" in getattr(item, "fixturenames", ()):
        return 1
    if item.get_closest_marker("xdist_group"):
        return 0
    return 2 if item.get_closest_marker("browser") else 3
