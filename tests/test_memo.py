"""The builder's array memo: exact round trips, misses for anything unreadable."""

import numpy as np

from pipeline.builder.cache import Cache
from pipeline.builder.memo import ArrayMemo


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
