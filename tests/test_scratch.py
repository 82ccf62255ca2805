"""Temporary folders of killed processes are removed by the next process that makes one."""

import os
import signal
import subprocess
import sys
from pathlib import Path

from pipeline import scratch

ROOT = Path(__file__).resolve().parents[1]

# Makes a pool folder and a worker folder in the folder it is given, says where, then
# waits on stdin.
_OWNER = """
import sys
from pipeline import scratch
pool = scratch.pool_folder("twin_pool_", sys.argv[1])
scratch.remove_with(scratch, pool)  # at exit: the module lives as long as the process
worker = scratch.use_temp_folder(sys.argv[1])
open(worker + "/frame.exr", "wb").write(b"x" * 1000)
print(pool, worker, flush=True)
sys.stdin.read()
"""


def _owner(tmp: Path) -> tuple[subprocess.Popen, list[Path]]:
    proc = subprocess.Popen([sys.executable, "-c", _OWNER, str(tmp)], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    folders = [Path(p) for p in proc.stdout.readline().split()]
    assert len(folders) == 2 and all(f.is_dir() and f.parent == tmp for f in folders)
    return proc, folders


def test_a_killed_owners_folders_go_and_a_living_owners_stay(tmp_path):
    killed, killed_folders = _owner(tmp_path)
    living, living_folders = _owner(tmp_path)
    unlocked = tmp_path / "twin_pool_older"  # no lock file: not known to be abandoned
    unlocked.mkdir()
    mine = None
    try:
        os.kill(killed.pid, signal.SIGKILL)  # no exit handler runs
        killed.wait()
        assert all(f.is_dir() for f in killed_folders)
        mine = scratch.pool_folder("twin_pool_", str(tmp_path))
        assert not killed_folders[0].exists() and killed_folders[1].is_dir()  # one prefix at a time
        assert scratch.remove_abandoned("twin_worker_", str(tmp_path)) == [str(killed_folders[1])]
        assert all(f.is_dir() for f in living_folders) and unlocked.is_dir() and Path(mine).is_dir()
        assert scratch.remove_abandoned("twin_", str(tmp_path)) == []  # its own folder is held too
    finally:
        living.communicate("")
        if mine is not None:
            scratch.remove_folder(mine)
    assert living.returncode == 0 and not any(f.exists() for f in living_folders)  # removed at its exit
    assert sorted(p.name for p in tmp_path.iterdir()) == ["twin_pool_older"]
