"""orchestration.safe_io: atomic writes and the folder lock."""
from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

from orchestration import safe_io


def test_an_atomic_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "run.json"
    safe_io.atomic_write_json(target, {"status": "running"})

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space left"):
        safe_io.atomic_write_text(target, "x" * 10_000)
    assert target.read_text() == '{\n "status": "running"\n}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]


def test_a_folder_lock_is_exclusive_across_processes_and_freed_by_the_process_end(tmp_path):
    hold = ("import sys, time; from orchestration.safe_io import FolderLock; "
            "FolderLock(sys.argv[1]).acquire(); print('held', flush=True); time.sleep(60)")
    child = subprocess.Popen([sys.executable, "-c", hold, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert child.stdout.readline().strip() == "held"
        with pytest.raises(safe_io.FolderLockedError, match=rf"in use by another process \(pid {child.pid}\)"):
            safe_io.FolderLock(tmp_path).acquire()
    finally:
        child.kill()
        child.wait()
    with safe_io.FolderLock(tmp_path):           # the kernel dropped the dead process's lock
        with pytest.raises(safe_io.FolderLockedError):
            safe_io.FolderLock(tmp_path).acquire()   # a second open file in this process too
