"""Where FlexFusion keeps, across processes, what it computes once and finds again by content.

``$FLEXFUSION_CACHE_DIR``, else ``$XDG_CACHE_HOME/flexfusion``, else ``~/.cache/flexfusion``
(the root the kernel cache of :mod:`fmus.common.jit` uses too). Every entry is named by a
hash of everything it is made from (:func:`content_key`), and published whole (written under
a temporary name starting with ``.``, then renamed), so a reader never sees a half-written
entry and no entry is ever stale. A folder keeps its last used entries (:func:`prune`). A
cache that cannot be written means no cache (the caller computes), never an error.

A folder that holds code something loads (compiled kernels, extracted FMUs, the C loop) is made
private with :func:`private_folder` (mode 0700) and checked before anything in it is loaded:
each folder from the cache's root down, and each file loaded (:func:`check_private`), must be
owned by this user and not writable by group or others, and no symbolic link. A folder that
fails the check is not used (the caller falls back, or runs without that cache).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import stat
import tempfile
import time
import types
from pathlib import Path
from typing import Any, Callable

STALE_TEMPORARY_S = 3600.0     #: a temporary entry older than this was left by a process that died


def cache_root() -> Path:
    """The cache's root folder (see the module docstring; it may not exist yet)."""
    base = os.environ.get("FLEXFUSION_CACHE_DIR")
    if not base:
        base = os.path.join(os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache"), "flexfusion")
    return Path(base)


def check_private(path: Path, *, folder: bool | None = None) -> None:
    """Raise ``PermissionError`` naming why unless ``path`` is private to this user: not a
    symbolic link, owned by this user, not writable by group or others, and a folder (``folder``
    True), a regular file (False) or either (None). ``FileNotFoundError`` if it is not there."""
    st = os.lstat(path)
    kind = "folder" if stat.S_ISDIR(st.st_mode) else "file" if stat.S_ISREG(st.st_mode) else None
    if kind is None or (folder is not None and (kind == "folder") != folder):
        what = "a symbolic link" if stat.S_ISLNK(st.st_mode) else f"not a {'folder' if folder else 'file'}"
        raise PermissionError(f"{path}: {what}")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise PermissionError(f"{path}: owned by user {st.st_uid}, not by this user ({os.getuid()})")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise PermissionError(f"{path}: writable by group or others (mode {stat.S_IMODE(st.st_mode):o})")


def private_folder(path: Path, top: Path | None = None) -> Path:
    """The folder ``path``, made with mode 0700 where missing (with its missing parents), and
    checked private (:func:`check_private`) from ``top`` (a parent of ``path``; default ``path``
    itself) down to it. Raises ``OSError`` (``PermissionError`` naming the folder and why)."""
    path = Path(path)
    top = Path(top) if top is not None else path
    below = [path, *path.parents]
    below = below[:below.index(top) + 1] if top in below else [path]
    for p in reversed(top.parents if top in below else path.parents):
        if not os.path.lexists(p):
            os.mkdir(p, 0o700)                 # the parents of the checked chain: not checked
    for p in reversed(below):                  # from the top down: nothing made below a bad one
        try:
            os.mkdir(p, 0o700)
        except FileExistsError:
            pass                               # there already (or made by another process)
        check_private(p, folder=True)
    return path


def content_key(*parts: Any) -> str:
    """A hash (32 hex digits) of ``parts``: numbers bit for bit (floats by ``float.hex``, arrays
    by dtype, shape and bytes), strings, and containers, dataclasses and plain objects by their
    type and contents, recursively. Anything else is refused (``TypeError``): two different
    values must never share a key."""
    digest = hashlib.sha256()
    _feed(digest, parts)
    return digest.hexdigest()[:32]


def _feed(digest: Any, x: Any) -> None:
    import numpy as np

    def put(tag: str, payload: bytes = b"") -> None:
        digest.update(f"{tag}:{len(payload)}:".encode() + payload)

    if x is None or isinstance(x, (bool, int, str)):
        put(type(x).__name__, repr(x).encode())
    elif isinstance(x, float):
        put("float", float(x).hex().encode())
    elif isinstance(x, (np.ndarray, np.generic)):
        a = np.ascontiguousarray(x)
        put("array", f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
    elif isinstance(x, (tuple, list)):
        put(type(x).__name__, str(len(x)).encode())
        for item in x:
            _feed(digest, item)
    elif isinstance(x, dict):
        put("dict", str(len(x)).encode())
        for k in sorted(x, key=repr):
            _feed(digest, k)
            _feed(digest, x[k])
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):
        put(type(x).__qualname__)
        _feed(digest, {f.name: getattr(x, f.name) for f in dataclasses.fields(x)})
    elif hasattr(x, "__dict__") and not callable(x) and not isinstance(x, types.ModuleType):
        put(type(x).__qualname__)
        _feed(digest, dict(vars(x)))
    else:
        raise TypeError(f"content_key: cannot key a {type(x).__name__}")


def prune(folder: Path, keep: int) -> None:
    """Remove all but the ``keep`` last used entries of ``folder`` (by modification time:
    mark a use with ``os.utime``), and temporary entries older than :data:`STALE_TEMPORARY_S`."""
    used, stale = [], time.time() - STALE_TEMPORARY_S
    for entry in folder.iterdir():
        try:
            stamp = entry.stat().st_mtime
        except OSError:
            continue
        if entry.name.startswith("."):
            if stamp < stale:
                _remove(entry)
        else:
            used.append((stamp, entry))
    for _, entry in sorted(used, reverse=True)[keep:]:
        _remove(entry)


def _remove(entry: Path) -> None:
    if entry.is_dir() and not entry.is_symlink():
        shutil.rmtree(entry, ignore_errors=True)
    else:
        entry.unlink(missing_ok=True)


def cached_array(kind: str, key: str, shape: tuple[int, ...], compute: Callable[[], Any], keep: int) -> Any:
    """The float64 array of ``shape`` stored as ``<cache root>/<kind>/<key>.npy``, or
    ``compute()`` stored there (the folder keeping its ``keep`` last used entries). ``key``
    must cover everything ``compute`` depends on (:func:`content_key`)."""
    import numpy as np

    def read(path: Path) -> Any:
        stored = np.load(path, allow_pickle=False)
        return stored if stored.shape == shape and stored.dtype == np.float64 else None

    return _cached(kind, f"{key}.npy", read, lambda f, value: np.save(f, value, allow_pickle=False), compute, keep)


def cached_json(kind: str, key: str, compute: Callable[[], Any], keep: int) -> Any:
    """The value made of JSON types (lists come back for tuples) stored as
    ``<cache root>/<kind>/<key>.json``, or ``compute()`` stored there (the folder keeping its
    ``keep`` last used entries), as :func:`cached_array`."""
    return _cached(kind, f"{key}.json", lambda path: json.loads(path.read_bytes()),
                   lambda f, value: f.write(json.dumps(value).encode()), compute, keep)


def _cached(kind: str, name: str, read: Callable[[Path], Any], write: Callable[[Any, Any], Any],
            compute: Callable[[], Any], keep: int) -> Any:
    """The value ``read`` from ``<cache root>/<kind>/<name>`` (None: not a valid one), or
    ``compute()``, then ``write`` it into a temporary file renamed to that name."""
    folder = cache_root() / kind
    path = folder / name
    try:
        stored = read(path)
        if stored is not None:
            os.utime(path)                     # its last use
            return stored
    except (OSError, ValueError):
        pass                                   # not there (or unreadable): compute it
    value = compute()
    temporary = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        prune(folder, keep - 1)
        fd, temporary = tempfile.mkstemp(prefix=".", suffix=path.suffix, dir=folder)
        with os.fdopen(fd, "wb") as f:
            write(f, value)
        os.replace(temporary, path)
    except OSError:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
    return value
