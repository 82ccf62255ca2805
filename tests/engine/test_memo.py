"""The builder's memos: exact round trips, misses for anything unreadable, linked files."""

import numpy as np

from pipeline.engine.cache import Cache
from pipeline.engine.memo import ArrayMemo


def test_round_trip_is_exact_and_namespaced(tmp_path):
    memo = ArrayMemo(tmp_path, "code-v1")
    arrays = {"corners": np.arange(12, dtype=np.int64).reshape(4, 3), "error_m": np.array([0.1 + 0.2])}
    assert memo.get("k") is None
    memo.put("k", arrays)
    back = memo.get("k")
    assert set(back) == set(arrays)
    for name in arrays:
        assert back[name].dtype == arrays[name].dtype and np.array_equal(back[name], arrays[name])
    assert ArrayMemo(tmp_path, "code-v2").get("k") is None  # new code never reads old entries
    memo.put("k", {"corners": np.zeros((1, 3), dtype=np.int64)})  # written again: replaced whole
    assert set(memo.get("k")) == {"corners"} and np.array_equal(memo.get("k")["corners"], np.zeros((1, 3)))
    assert not list(tmp_path.glob(".tmp-*"))
    assert (memo.hits, memo.puts) == (3, 2)


def test_unreadable_entries_are_misses(tmp_path):
    memo = ArrayMemo(tmp_path, "ns")
    memo.path("garbage").parent.mkdir(parents=True, exist_ok=True)
    memo.path("garbage").write_bytes(b"not a zip")
    assert memo.get("garbage") is None
    memo.put("garbage", {"x": np.arange(3)})  # computed again, it replaces the damaged entry
    assert np.array_equal(memo.get("garbage")["x"], np.arange(3))
    memo.put("objects", {"x": np.array([{"code": "runs?"}], dtype=object)})  # a pickle inside
    assert memo.get("objects") is None


def test_an_entry_cut_short_or_claiming_more_than_it_holds_is_a_miss(tmp_path):
    import json

    memo = ArrayMemo(tmp_path, "ns")
    memo.put("k", {"codes": np.array(["GEOM003", "GEOM10"], dtype=np.str_), "x": np.arange(5)})
    assert memo.get("k")["codes"].tolist() == ["GEOM003", "GEOM10"]
    path = memo.path("k")
    path.write_bytes(path.read_bytes()[:-3])
    assert memo.get("k") is None
    header = json.dumps([["x", "<f8", [10**6, 10**6]]]).encode()  # 8 TB, in 8 bytes
    path.write_bytes(ArrayMemo.MAGIC + len(header).to_bytes(8, "little") + header + bytes(8))
    assert memo.get("k") is None


def test_a_killed_write_leaves_a_temporary_file_the_next_build_sweeps(tmp_path):
    (tmp_path / ".tmp-0123.npz").write_bytes(b"half")
    (tmp_path / ".tmp-entry").mkdir()
    Cache(tmp_path).clean_tmp()
    assert not list(tmp_path.glob(".tmp-*"))


def test_a_memo_whose_folder_is_missing_makes_it_or_stays_empty(tmp_path):
    memo = ArrayMemo(tmp_path / "not" / "yet", "ns")
    memo.put("k", {"x": np.arange(2)})
    assert np.array_equal(memo.get("k")["x"], np.arange(2))
    (tmp_path / "file").write_text("a file where the folder would be")
    blocked = ArrayMemo(tmp_path / "file", "ns")
    blocked.put("k", {"x": np.arange(2)})  # no error: the memo only spares work
    assert blocked.get("k") is None


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _collada_written(asset, folder):
    from pipeline.export import collada

    collada.write(asset, folder)
    return folder


def test_collada_documents_from_the_file_memo_are_the_documents_written(tmp_path):
    """A package written again with the memo links every document an earlier write
    kept: the same bytes, no second copy on disk, and a changed mesh made anew."""
    import dataclasses

    from fixtures_assets import articulated_asset
    from pipeline import ir
    from pipeline.engine.memo import FileMemo
    from pipeline.export import collada

    asset = articulated_asset()
    plain = collada.write(asset, tmp_path / "plain")
    memo = FileMemo(tmp_path / "cache", "package-v1")
    assert collada.write(asset, tmp_path / "first", memo) == plain
    documents = memo.puts
    assert memo.hits == 0 and documents > 0
    again = FileMemo(tmp_path / "cache", "package-v1")
    assert collada.write(asset, tmp_path / "second", again) == plain
    assert (again.hits, again.puts) == (len(plain), 0)
    assert _tree(tmp_path / "plain") == _tree(tmp_path / "first") == _tree(tmp_path / "second")
    linked = (tmp_path / "second" / plain[0]).stat()
    assert linked.st_nlink == 3  # the first write's file, the memo's entry and this one: one copy
    assert FileMemo(tmp_path / "cache", "package-v2").link("any", tmp_path / "x") is False  # new code

    # one visual's mesh moved: its documents are made, every other one linked
    link = asset.links[0]
    moved = ir.Mesh(link.visuals[0].mesh.vertices + 0.001, link.visuals[0].mesh.faces)
    visual = dataclasses.replace(link.visuals[0], lods=(moved, *link.visuals[0].lods[1:]))
    edited = asset.with_(links=(dataclasses.replace(link, visuals=(visual, *link.visuals[1:])), *asset.links[1:]))
    third = FileMemo(tmp_path / "cache", "package-v1")
    collada.write(edited, tmp_path / "third", third)
    assert third.puts == 1 and third.hits == len(plain) - 1
    assert _tree(tmp_path / "third") == _tree(_collada_written(edited, tmp_path / "plain_edited"))


def test_a_file_memo_that_cannot_link_keeps_nothing_and_the_files_are_written(tmp_path):
    from fixtures_assets import articulated_asset
    from pipeline.engine.memo import FileMemo
    from pipeline.export import collada

    (tmp_path / "file").write_text("a file where the cache folder would be")
    memo = FileMemo(tmp_path / "file", "ns")
    asset = articulated_asset()
    written = collada.write(asset, tmp_path / "out", memo)
    assert memo.hits == 0 and _tree(tmp_path / "out") == _tree(_collada_written(asset, tmp_path / "plain"))
    assert len(written) == memo.puts  # each tried, none kept
