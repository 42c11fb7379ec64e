"""The FMU store: where an FMU file becomes a folder a library is loaded from, and what is known
of an FMU by its content (its parsed model description), kept across processes and checkouts.

* :func:`content_key`: an FMU's identity, a hash of its zip's central directory (each member's
  name, size and CRC-32; no member read), checked against the archive limits first
  (:mod:`orchestration.archive`).
* :func:`described`: a value parsed from an FMU once per content, kept in the disk cache
  (``<cache root>/<kind>/``: the model descriptions of :func:`orchestration.scenario.read_variables`,
  the self-descriptions of :func:`orchestration.fmu_annotation.describe`).
* :func:`folder`: the folder an FMU is extracted to, ``<cache root>/fmus/<content>-<platform>-2``
  (:func:`cached_folder`), one per FMU content for every process and checkout of the user;
  without a usable cache, a temporary folder of this process (removed when its last run ends,
  :func:`run_ended`).

Safe between processes: a folder is extracted under a temporary name and renamed when whole
(the first rename wins); every process holds a shared lock (``flock``) on the ``.complete``
marker of each folder it uses, for as long as it lives (its libraries and imported packages
stay mapped after a run), and pruning (:func:`prune`, keeping the :data:`KEEP` last used
folders) and ``flexfusion cache clear`` remove a folder only while holding its exclusive lock,
which fails while any process holds the shared one. A folder whose shared libraries are not
whole is set aside and extracted again (:func:`_repaired`); one whose library still does not
load after that is reported, naming the folder and ``flexfusion cache clear``
(:func:`set_aside`, used by the master).

The C loop's library has its own entry in the same cache (:mod:`orchestration.cloop`); the
cache's folders are listed and cleared by :mod:`orchestration.caches` (``flexfusion cache``).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, Callable

from . import archive

KEEP = 32                 #: cached FMU folders kept (the last used that no process uses; 1-4 MB each)
COMPLETE = ".complete"    #: the marker written last into a cached folder, and its lock file
LAYOUT = 2                #: of a cached folder: 2 whole (1, before: bundled packages linked to ``packages/``)

_CONTENT: dict[tuple[str, int, int], str] = {}     # FMU file version -> content key, in this process
_EXTRACTED: dict[tuple[str, int, int], str] = {}   # FMU file version -> its folder in this process
_EXTRACT_ROOT: list[str] = []     # this process's temporary folder (when there is no cache)
_ACTIVE_RUNS = [0]
_HELD: dict[str, int] = {}        # folder -> the descriptor of its marker, locked shared (in use)


# ---------------------------------------------------------------------------------------------
# what is known of an FMU by its content
# ---------------------------------------------------------------------------------------------
def content_key(fmu: Path) -> str:
    """A hash of the FMU file's content, read from the zip's own directory (every member's
    name, size and CRC-32: no member is read), once per file version and process; the archive
    is checked against the limits first (:func:`orchestration.archive.check`).

    Raises
    ------
    OSError, zipfile.BadZipFile
        The file cannot be read as a zip archive.
    orchestration.archive.ArchiveError
        The archive passes a limit, or an entry's name leaves its folder.
    """
    st = fmu.stat()
    version = (str(fmu.resolve()), st.st_mtime_ns, st.st_size)
    key = _CONTENT.get(version)
    if key is None:
        with zipfile.ZipFile(fmu) as z:
            infos = z.infolist()
        archive.check(infos, str(fmu))
        members = sorted((i.filename, i.file_size, i.CRC) for i in infos)
        key = _CONTENT[version] = hashlib.sha256(repr(members).encode()).hexdigest()[:32]
    return key


def described(fmu: Path, kind: str, parse: Callable[[Path], Any], keep: int) -> Any:
    """``parse(fmu)`` (a value of JSON types), computed once per FMU content and kept in the
    disk cache's folder ``kind`` (its ``keep`` last used entries:
    :func:`fmus.common.disk_cache.cached_json`)."""
    from fmus.common.disk_cache import cached_json
    return cached_json(kind, content_key(fmu), lambda: parse(fmu), keep)


# ---------------------------------------------------------------------------------------------
# the folders
# ---------------------------------------------------------------------------------------------
def run_began() -> None:
    """A run of this process uses the store (until :func:`run_ended`)."""
    _ACTIVE_RUNS[0] += 1


def run_ended() -> None:
    """A run of this process ended: when the last one ends, the temporary folders it
    extracted to (no cache) are removed (:func:`_remove_temporary`), not at exit: study
    workers end without running Python's exit handlers."""
    _ACTIVE_RUNS[0] -= 1
    if not _ACTIVE_RUNS[0]:
        _remove_temporary()


def folder(fmu: Path) -> str:
    """The folder the FMU file ``fmu`` is extracted to, one per FMU file version for the
    process, so its shared library is loaded once and reused by every instance (the dynamic
    loader matches an already loaded library by its path, even after the file was removed and
    extracted again).

    That folder is the FMU's entry in the cache (:func:`cached_folder`): extracted once for
    every process and run. Without a writable cache, a temporary folder of this process,
    removed when its last run ends (:func:`run_ended`); a package this process has imported
    already is not extracted there (:func:`_still_read`).

    Raises
    ------
    OSError, zipfile.BadZipFile, orchestration.archive.ArchiveError
        Not a readable FMU, or one beyond the archive limits.
    """
    path = fmu.resolve()
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size)
    where = _EXTRACTED.get(key)
    if where is None or not Path(where, "modelDescription.xml").is_file():
        content_key(path)                    # the archive's limits, before anything is extracted
        cached = cached_folder(path)         # again where it was removed under us: same path
        where = _EXTRACTED[key] = where or cached or str(Path(_temporary_root()) / str(len(_EXTRACTED)))
        if where != cached:
            from fmpy import extract
            extract(str(path), unzipdir=where, include=_still_read)
    return where


def _temporary_root() -> str:
    if not _EXTRACT_ROOT:
        _EXTRACT_ROOT.append(tempfile.mkdtemp(prefix="flexfusion_fmus_"))
    return _EXTRACT_ROOT[0]


def cached_folder(fmu: Path) -> str | None:
    """The FMU's folder in the cache (``<cache root>/fmus/<content>-<platform>-<layout>``,
    :mod:`fmus.common.disk_cache`), extracted now if it is not there yet, and held in use by
    this process (:func:`_hold`); None if the cache cannot be written.

    It is named by the FMU's content (:func:`content_key`), the platform, whose binaries are
    the only ones extracted, and the folder's :data:`LAYOUT` (a folder an older FlexFusion made,
    with links to shared packages, is not taken for one); everything else of the FMU is extracted whole (its bundled Python
    packages too: sharing them between folders saved a cold start 0.2-0.7 s of CPU once per FMU
    content but nothing on a warm one, ARCHITECTURE.md "The FMU store"). The cache's ``fmus/``
    folder holds code that is loaded: it is used only if private to this user
    (:func:`fmus.common.disk_cache.private_folder`: made 0700, owner and mode checked from the
    cache root down), else the FMU is extracted to a temporary folder of this process. A folder
    whose shared libraries are not whole is set aside and extracted again (:func:`_repaired`).
    A folder is extracted under a temporary name and renamed when complete, so processes
    extracting the same FMU at once each use a whole folder (the first rename wins). Extracting
    a new folder removes all but the :data:`KEEP` last used ones that no process uses
    (:func:`prune`).
    """
    from fmpy import platform

    from fmus.common.disk_cache import cache_root, private_folder
    try:
        key = content_key(fmu)
    except (OSError, zipfile.BadZipFile):
        return None      # not an FMU: the temporary extraction reports it
    root = cache_root() / "fmus"
    entry = root / f"{key}-{platform}-{LAYOUT}"
    marker = entry / COMPLETE
    try:
        private_folder(root, cache_root())      # code is loaded from it: private, or not used
        for _ in range(3):                      # removed between the look and the hold: again
            if marker.is_file():
                _repaired(entry, fmu, platform)
            if not marker.is_file():
                prune(root, KEEP - 1)
                _publish(entry, lambda staging: _extract(fmu, platform, staging), marker.is_file)
            if _hold(entry):
                break
        else:
            return None
        os.utime(entry)                  # its last use
    except OSError:
        return None
    return str(entry)


# ---------------------------------------------------------------------------------------------
# in use, pruning
# ---------------------------------------------------------------------------------------------
try:
    import fcntl
except ImportError:                      # no flock (Windows): a folder in use may be pruned;
    fcntl = None                         # the process extracts it again at the same path


def _hold(entry: Path) -> bool:
    """Mark the cached folder ``entry`` in use by this process for as long as it lives: a
    shared lock on its marker (released by the system when the process ends, however it ends).
    False if the folder is gone (pruned, set aside) between the look and the lock."""
    marker = entry / COMPLETE
    fd = _HELD.get(str(entry))
    if fd is not None:
        try:
            if os.path.samestat(os.fstat(fd), os.stat(marker)):
                return True
        except FileNotFoundError:
            pass
        _release(entry)                  # the folder held before was removed: hold the new one
    try:
        fd = os.open(marker, os.O_RDONLY)
    except FileNotFoundError:
        return False
    if fcntl is not None:
        fcntl.flock(fd, fcntl.LOCK_SH)   # waits while a pruner holds it (for one rename)
    try:
        same = os.path.samestat(os.fstat(fd), os.stat(marker))
    except FileNotFoundError:
        same = False
    if not same:                         # renamed away before the lock was taken
        os.close(fd)
        return False
    _HELD[str(entry)] = fd
    return True


def _release(entry: Path) -> None:
    fd = _HELD.pop(str(entry), None)
    if fd is not None:
        os.close(fd)


def remove_unused(entry: Path) -> bool:
    """Remove the cached FMU folder ``entry`` unless a process uses it (holds its marker's
    lock, :func:`_hold`): renamed away while holding the exclusive lock, then deleted. Whether
    it was removed."""
    try:
        fd = os.open(entry / COMPLETE, os.O_RDONLY)
    except FileNotFoundError:
        fd = None                        # not published whole: nobody can hold it
    except OSError:
        return False
    try:
        if fd is not None and fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                return False             # in use
        trash = entry.with_name(f".removing-{os.getpid()}-{entry.name}")
        try:
            entry.rename(trash)
        except OSError:
            return False
    finally:
        if fd is not None:
            os.close(fd)
    shutil.rmtree(trash, ignore_errors=True)
    return True


def prune(root: Path, keep: int) -> None:
    """Remove all but the ``keep`` last used folders of ``root`` (by modification time) that no
    process uses (:func:`remove_unused`), and temporary folders older than
    :data:`~fmus.common.disk_cache.STALE_TEMPORARY_S` (left by a process that died)."""
    from fmus.common.disk_cache import STALE_TEMPORARY_S
    used, stale = [], time.time() - STALE_TEMPORARY_S
    for entry in root.iterdir():
        try:
            stamp = entry.stat().st_mtime
        except OSError:
            continue
        if entry.name.startswith("."):
            if stamp < stale:
                shutil.rmtree(entry, ignore_errors=True)
        else:
            used.append((stamp, entry))
    for _, entry in sorted(used, reverse=True)[keep:]:
        remove_unused(entry)          # unless a process holds it: this one too (another descriptor)


def set_aside(entry: str | Path) -> bool:
    """Set the cached FMU folder ``entry`` aside (renamed to a hidden ``.bad-*`` name, removed
    an hour later by :func:`prune`) so that the next :func:`folder` extracts it again: for a
    folder whose library does not load. False if it is not a folder of the cache (a temporary
    one) or could not be renamed. This process's memo of it is forgotten."""
    from fmus.common.disk_cache import cache_root
    entry = Path(entry)
    if entry.parent != cache_root() / "fmus":
        return False
    for key, where in list(_EXTRACTED.items()):
        if where == str(entry):
            del _EXTRACTED[key]
    _release(entry)
    try:
        os.replace(entry, entry.with_name(f".bad-{int(time.time())}-{os.getpid()}-{entry.name}"))
    except OSError:
        return False
    return True


def _repaired(entry: Path, fmu: Path, platform: str) -> None:
    """Set a cached FMU folder aside if one of its shared libraries (``*.so``/``*.dll``/
    ``*.dylib``: its binary for ``platform``, a package's compiled kernels) is not the size it
    has in the FMU ``fmu``: a library truncated by a full disk or a killed copy makes the
    process that loads it die (a bus error, no message), so the folder is extracted again
    instead. Set aside = renamed to a hidden name, which :func:`prune` removes an hour later (a
    process that has the library loaded keeps it)."""
    import warnings
    bad = []
    with zipfile.ZipFile(fmu) as z:
        for m in z.infolist():
            name = m.filename
            if not name.endswith((".so", ".dll", ".dylib")) or \
                    (name.startswith("binaries/") and not name.startswith(_binaries(platform))):
                continue
            try:
                if (entry / name).stat().st_size == m.file_size:
                    continue
            except FileNotFoundError:
                continue            # not extracted here (another platform's)
            bad.append(name)
    if not bad:
        return
    _release(entry)
    os.replace(entry, entry.with_name(f".bad-{int(time.time())}-{os.getpid()}-{entry.name}"))
    warnings.warn(f"{entry}: {', '.join(bad)} not whole (truncated?): set aside, the FMU is extracted again",
                  stacklevel=4)


# ---------------------------------------------------------------------------------------------
# extraction
# ---------------------------------------------------------------------------------------------
def _extract(fmu: Path, platform: str, staging: Path) -> None:
    """Extract the FMU into ``staging``, its binaries for ``platform`` only, the marker of a
    complete folder last."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(staging, [m for m in z.namelist()
                               if not m.startswith("binaries/") or m.startswith(_binaries(platform))])
    (staging / COMPLETE).touch()


def _binaries(platform: str) -> tuple[str, ...]:
    """The folders of an FMU's binaries for ``platform`` (fmpy's FMI 2.0 name, ``linux64``):
    FMI 2.0's and FMI 3.0's (its platform tuple, ``x86_64-linux``)."""
    from fmpy import platform as fmi2_platform, platform_tuple
    return (f"binaries/{platform}/",) + ((f"binaries/{platform_tuple}/",) if platform == fmi2_platform else ())


def _publish(final: Path, fill: Callable[[Path], None], published: Callable[[], bool]) -> None:
    """Make the cache's folder ``final``: ``fill`` a temporary folder beside it, then rename it
    to ``final``, so that no process ever sees it half made; where another process was first
    (the rename fails) and its folder is ``published``, that one is used."""
    staging = Path(tempfile.mkdtemp(prefix=".extracting-", dir=final.parent))
    try:
        fill(staging)
        try:
            staging.rename(final)
        except OSError:
            if not published():
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _still_read(member: str) -> bool:
    """Whether this process may still read an FMU's file ``member``: not one of a package in
    ``resources/`` that it has imported already from another FMU's folder. Python imports a
    package once per process, from the first folder that provides it, and never reads another
    copy; our FMUs each bundle the same ``fmus_<hash>`` package and ``pythonfmu``, which their
    script imports whole when it loads, so only the first FMU of a process needs them (each
    other one saves about 45 files of extraction). A folder that merely shares the name of a
    package imported from elsewhere (``resources/xml/`` of a C FMU) is extracted."""
    parts = member.split("/", 2)
    if len(parts) < 3 or parts[0] != "resources":
        return True
    module = sys.modules.get(parts[1])
    origin = getattr(module, "__file__", None) or ""
    return not (hasattr(module, "__path__") and _EXTRACT_ROOT
                and origin.startswith(os.path.join(_EXTRACT_ROOT[0], "")))


def _remove_temporary() -> None:
    """Remove this process's temporary FMU folders (the paths stay reserved for the next run)."""
    if _EXTRACT_ROOT:
        shutil.rmtree(_EXTRACT_ROOT[0], ignore_errors=True)


__all__ = ["KEEP", "COMPLETE", "content_key", "described", "run_began", "run_ended", "folder", "cached_folder", "prune",
           "remove_unused", "set_aside"]
