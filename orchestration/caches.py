"""The caches under the cache root (:func:`fmus.common.disk_cache.cache_root`): what each holds,
its size and entries (``flexfusion cache info``), and clearing them without pulling anything
from under a running process (``flexfusion cache clear``).

Each folder of the root is one cache, cleared by the rule its use allows:

* ``fmus/`` (the FMU store, :mod:`orchestration.fmu_store`): an entry goes unless a process
  holds it (its in-use lock, :func:`orchestration.fmu_store.remove_unused`);
* ``model_descriptions/``, ``fmu_annotations/``, ``tables/``, ``bandpass/`` (values computed from their
  content): every entry goes; a reader that misses one computes it again, a writer replaces
  one whole (:func:`fmus.common.disk_cache.cached_json`);
* ``loop/`` (the C loop), ``kernels/`` (Cython kernels), ``numba/`` (the kernels' numba cache):
  code compiled on first use;
  a process that loaded it keeps it mapped, one that finds it gone compiles it again. An entry
  changed in the last :data:`BUSY_S` seconds is kept (a process may be writing it);
* ``packages/`` (shared packages of an older FlexFusion, which linked to them): an entry used
  in the last hour is kept (its modification time marks its last use, as that version pruned);
* ``keys/`` (the key that signs study job files) and any folder not named here: kept.

Temporary entries (names starting with ``.``: being written, set aside) older than
:data:`~fmus.common.disk_cache.STALE_TEMPORARY_S` go with their cache.
"""
from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

BUSY_S = 120.0     #: a compiled-code entry changed this recently may be being written: kept

KINDS = {          # folder -> (what it holds, how it is cleared)
    "fmus": ("FMU store: extracted FMUs", "unused"),
    "model_descriptions": ("model-description cache: parsed modelDescription.xml", "data"),
    "fmu_annotations": ("FMU self-descriptions: parsed flexfusion annotations", "data"),
    "tables": ("reference tables of the motion controller", "data"),
    "bandpass": ("band-pass filter designs of the metrics", "data"),
    "loop": ("the C stepping loop, compiled", "code"),
    "numba": ("kernel cache (numba)", "code"),
    "kernels": ("compiled kernels (Cython, fmus.common.native_cache)", "code"),
    "packages": ("shared packages of an older FlexFusion", "legacy"),
    "keys": ("the key that signs study job files (not a cache: kept)", "keep"),
}


@dataclass
class Entry:
    """One cache (a folder of the root): ``name``, what it holds, its size in bytes and its
    number of entries (not counting temporary ones)."""
    name: str
    what: str
    size: int
    entries: int


@dataclass
class Cleared:
    """What :func:`clear` did: ``removed`` entries (``cache/entry``) and ``kept`` ones with
    why."""
    removed: list[str] = field(default_factory=list)
    kept: list[tuple[str, str]] = field(default_factory=list)


def root() -> Path:
    """The cache root (:func:`fmus.common.disk_cache.cache_root`)."""
    from fmus.common.disk_cache import cache_root
    return cache_root()


def _size(path: Path) -> int:
    """Bytes of the files below ``path`` (links not followed)."""
    if path.is_symlink() or path.is_file():
        return path.lstat().st_size
    total = 0
    for folder, _, names in os.walk(path):
        for name in names:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
            except OSError:
                pass
    return total


def info() -> list[Entry]:
    """Every cache under the root, in :data:`KINDS` order then any other folder."""
    base = root()
    if not base.is_dir():
        return []
    names = sorted(p.name for p in base.iterdir() if p.is_dir() and not p.is_symlink())
    ordered = [n for n in KINDS if n in names] + [n for n in names if n not in KINDS]
    out = []
    for name in ordered:
        folder = base / name
        entries = [p for p in folder.iterdir() if not p.name.startswith(".")]
        out.append(Entry(name, KINDS.get(name, ("unknown (not FlexFusion's)", "keep"))[0], _size(folder), len(entries)))
    return out


def _newest(path: Path) -> float:
    """The latest modification time of ``path`` or anything below it."""
    newest = path.lstat().st_mtime
    if path.is_dir() and not path.is_symlink():
        for folder, dirs, names in os.walk(path):
            for name in dirs + names:
                try:
                    newest = max(newest, os.lstat(os.path.join(folder, name)).st_mtime)
                except OSError:
                    pass
    return newest


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def clear() -> Cleared:
    """Clear every cache under the root by its rule (see the module docstring)."""
    from fmus.common.disk_cache import STALE_TEMPORARY_S

    from . import fmu_store
    done = Cleared()
    base = root()
    if not base.is_dir():
        return done
    now = time.time()
    for cache in sorted(p for p in base.iterdir() if p.is_dir() and not p.is_symlink()):
        rule = KINDS.get(cache.name, ("", "keep"))[1]
        if rule == "keep":
            done.kept.append((cache.name, KINDS.get(cache.name, ("not FlexFusion's", ""))[0]))
            continue
        for entry in sorted(cache.iterdir()):
            label = f"{cache.name}/{entry.name}"
            try:
                if entry.name.startswith("."):
                    if entry.lstat().st_mtime < now - STALE_TEMPORARY_S:
                        _remove(entry)
                        done.removed.append(label)
                    continue                   # being written (or set aside) now: not listed
                why = None
                if rule == "unused":
                    if not fmu_store.remove_unused(entry):
                        why = "in use by a running process"
                elif rule == "code" and _newest(entry) > now - BUSY_S:
                    why = f"changed in the last {BUSY_S:.0f} s: a process may be writing it"
                elif rule == "legacy" and entry.lstat().st_mtime > now - STALE_TEMPORARY_S:
                    why = "used in the last hour by an older FlexFusion"
                else:
                    _remove(entry)
                if why:
                    done.kept.append((label, why))
                else:
                    done.removed.append(label)
            except OSError as exc:
                done.kept.append((label, f"cannot remove it: {exc.strerror or exc}"))
    return done


def main(action: str) -> int:
    """``flexfusion cache info`` (a table: cache, size, entries, what it holds) or
    ``flexfusion cache clear`` (what was removed, what was kept and why); exit status 0."""
    base = root()
    if action == "info":
        entries = info()
        print(f"cache root: {base}" + ("" if entries else " (empty or not there)"))
        if entries:
            print(f"  {'cache':20s} {'size':>10s} {'entries':>8s}  holds")
            for e in entries:
                print(f"  {e.name:20s} {e.size / 1e6:8.1f} MB {e.entries:8d}  {e.what}")
            print(f"  {'total':20s} {sum(e.size for e in entries) / 1e6:8.1f} MB")
        return 0
    before = sum(e.size for e in info())
    done = clear()
    after = sum(e.size for e in info())
    print(f"cache root: {base}: removed {len(done.removed)} entries ({(before - after) / 1e6:.1f} MB), "
          f"kept {len(done.kept)}")
    for label, why in done.kept:
        print(f"  kept {label}: {why}")
    return 0


__all__ = ["KINDS", "BUSY_S", "Entry", "Cleared", "root", "info", "clear", "main"]
