"""Crash-safe files: atomic writes and a folder owned by one process at a time.

A file written with :func:`atomic_write_bytes` (or the text and JSON forms) is either the old
one or the whole new one, whatever happens meanwhile (a full disk, SIGKILL, a power cut): the
data go to a temporary file in the same folder, are flushed to the disk, and the temporary file
is renamed over the target (``os.replace`` is atomic on POSIX file systems).

:class:`FolderLock` holds an exclusive ``fcntl.flock`` on ``<folder>/.lock``; the kernel drops it
when the process ends, however it ends, so a stale lock never needs cleaning up.
"""
from __future__ import annotations

import fcntl
import json
import os
import tempfile
from pathlib import Path
from typing import Any

LOCK_NAME = ".lock"


class FolderLockedError(RuntimeError):
    """Another process holds the folder's lock."""


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (the old file or the whole new one, never a part)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any) -> None:
    """:func:`atomic_write_bytes` of ``obj`` as indented JSON."""
    atomic_write_text(path, json.dumps(obj, indent=1) + "\n")


class FolderLock:
    """An exclusive lock on a folder for as long as it is held (a context manager).

    Raises :class:`FolderLockedError` at once (no waiting) when another process holds it.
    """

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip()
            os.close(fd)
            raise FolderLockedError(f"{self.folder} is in use by another process"
                                    + (f" (pid {holder})" if holder.isdigit() else "")) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def is_locked(folder: str | Path) -> bool:
    """Whether a process holds the folder's lock now (e.g. a run still writing to it)."""
    try:
        fd = os.open(Path(folder) / LOCK_NAME, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


__all__ = ["is_locked", "atomic_write_bytes", "atomic_write_text", "atomic_write_json", "FolderLock",
           "FolderLockedError", "LOCK_NAME"]
