"""fork_join.beside: a task's two parts side by side when its worker has a core to spare,
with the same results, the same files and the same errors as one after the other."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from fixtures_assets import articulated_asset
from pipeline import fork_join
from pipeline.export.package import write_package
from pipeline.errors import UserError


@pytest.fixture
def two_cores(monkeypatch):
    monkeypatch.setenv(fork_join.SHARE_VARIABLE, "2")


def test_child_part_runs_in_another_process(two_cores):
    here, there = fork_join.beside(os.getpid, os.getpid)
    assert here == os.getpid()
    assert there != os.getpid()


def test_one_core_runs_both_here(monkeypatch):
    monkeypatch.setenv(fork_join.SHARE_VARIABLE, "1")
    assert fork_join.beside(os.getpid, os.getpid) == (os.getpid(), os.getpid())


def test_child_error_surfaces_as_from_a_plain_call(two_cores):
    def refuse():
        raise UserError("x.blend", "Cube", "bad mesh")

    with pytest.raises(UserError, match="x.blend: Cube: bad mesh"):
        fork_join.beside(lambda: 1, refuse)


def test_a_child_that_dies_is_run_again_here(two_cores):
    parent = os.getpid()

    def dies_in_the_child():
        if os.getpid() != parent:
            os._exit(3)
        return "ran here"

    assert fork_join.beside(lambda: 1, dies_in_the_child) == (1, "ran here")


def test_here_error_waits_for_the_child_and_surfaces(two_cores, tmp_path):
    marker = tmp_path / "child-finished"

    def child():
        marker.write_text("done")
        return 0

    def fail():
        raise ValueError("here failed")

    with pytest.raises(ValueError, match="here failed"):
        fork_join.beside(fail, child)
    assert marker.read_text() == "done"  # no orphan left writing after the call


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_package_is_the_same_written_side_by_side(monkeypatch, tmp_path):
    asset = articulated_asset()
    monkeypatch.setenv(fork_join.SHARE_VARIABLE, "1")
    serial = write_package(asset, tmp_path / "serial" / "models", alongside=lambda: "checked")
    monkeypatch.setenv(fork_join.SHARE_VARIABLE, "2")
    forked = write_package(asset, tmp_path / "forked" / "models", alongside=lambda: "checked")
    assert serial == forked
    assert serial[2] == "checked"
    assert any(name.endswith(".dae") for name in serial[0])
    assert _files(tmp_path / "serial") == _files(tmp_path / "forked")


def test_spread_runs_each_part_after_the_first_in_a_process_of_its_own(two_cores):
    pids = fork_join.spread([os.getpid, os.getpid, os.getpid])
    assert pids[0] == os.getpid()
    assert len(set(pids)) == 3


def test_spread_keeps_the_order_and_surfaces_a_part_error(two_cores):
    assert fork_join.spread([lambda: 1, lambda: 2, lambda: 3]) == [1, 2, 3]

    def refuse():
        raise UserError("x.blend", "Cube", "bad mesh")

    with pytest.raises(UserError, match="x.blend: Cube: bad mesh"):
        fork_join.spread([lambda: 1, lambda: 2, refuse])
