"""Compiled native code kept in the private cache: a library compiled once per content, verified
before every load, set aside and compiled again if it fails.

One mechanism for every native library FlexFusion compiles where it runs: the master's C stepping
loop (:mod:`orchestration.cloop`) and the Cython kernels of the working tree
(:mod:`fmus.common.cython_kernels`). An entry is ``<cache root>/<kind>/<key>/<name>``, ``key`` a
hash of everything it is compiled from (the caller's), or the same below a private folder of the
system's temporary directory where the cache root cannot be used.

* **Private**: every folder from the root down is mode 0700 and checked (owner, mode, no symbolic
  link: :func:`fmus.common.disk_cache.private_folder`), and the library and its hash too.
* **Verified**: the SHA-256 of the library's bytes is recorded beside it when it is compiled
  (``<name>.sha256``); a library is handed out only if its bytes have that hash.
* **Whole**: compiled to a temporary name and renamed, so parallel processes never load half a
  file.
* **Self-healing**: an entry that fails a check (planted, truncated, replaced), or that the caller
  could not load (``rebuild=True``), is renamed ``.bad-*`` (kept for inspection) and compiled
  again, with one warning.
"""
from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import sysconfig
import tempfile
import time
import warnings
from pathlib import Path
from typing import Callable

from fmus.common import disk_cache


def c_compiler() -> list[str]:
    """The system C compiler as a command (``$CC``, sysconfig's ``CC``, then cc/gcc/clang).

    Raises
    ------
    FileNotFoundError
        When none is installed.
    """
    candidates = [os.environ.get("CC", ""), sysconfig.get_config_var("CC") or "", "cc", "gcc", "clang"]
    for candidate in candidates:
        words = shlex.split(candidate)
        if words and shutil.which(words[0]):
            return [shutil.which(words[0]), *words[1:]]
    raise FileNotFoundError("no C compiler found (tried $CC, sysconfig CC, cc, gcc, clang; "
                            "Debian/Ubuntu: apt-get install gcc)")


def folders(kind: str, key: str) -> list[tuple[Path, Path]]:
    """Where the entry ``kind``/``key`` may be cached, in order: ``(folder, top)``, ``top`` the
    first folder that must be private."""
    root = disk_cache.cache_root()
    shared = Path(tempfile.gettempdir()) / f"flexfusion-{os.getuid()}"
    return [(root / kind / key, root), (shared / kind / key, shared)]


def sha256(path: Path) -> str:
    """The SHA-256 (hex) of the file ``path``'s bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def verified(target: Path) -> bool:
    """Whether the cached library ``target`` may be loaded: it and its recorded hash
    (``<target>.sha256``) private to this user, and the hash that of its bytes. False if it is
    not there; raises ``PermissionError`` (why) otherwise."""
    if not os.path.lexists(target):
        return False
    record = target.with_name(target.name + ".sha256")
    disk_cache.check_private(target, folder=False)
    try:
        disk_cache.check_private(record, folder=False)
    except FileNotFoundError:
        raise PermissionError(f"{target}: no hash recorded when it was compiled") from None
    if record.read_text().strip() != sha256(target):
        raise PermissionError(f"{target}: its content is not what was compiled (truncated or replaced)")
    return True


def set_aside(target: Path, why: str, what: str) -> None:
    """Move the cached library ``target`` (and its hash) out of the way, under a hidden
    ``.bad-*`` name kept for inspection, with one warning naming ``what`` it is and ``why``."""
    stamp = f".bad-{int(time.time())}-{os.getpid()}-"
    for path in (target, target.with_name(target.name + ".sha256")):
        if os.path.lexists(path):
            os.replace(path, path.with_name(stamp + path.name))
    warnings.warn(f"the cached {what} was not loaded ({why}); set aside and compiled again",
                  stacklevel=3)


def compiled(kind: str, key: str, name: str, compile_to: Callable[[Path], None], what: str,
             rebuild: bool = False) -> Path:
    """The library ``<kind>/<key>/<name>``: the cached one if private and as compiled
    (:func:`verified`), else compiled now by ``compile_to(path)`` (which writes the library to
    ``path``, a temporary name in the entry's folder, or raises); a cached one that fails its
    check is set aside first (a warning names ``what`` it is). ``rebuild``: set the cached one aside whatever it is (the caller
    could not load it).

    Raises
    ------
    OSError
        No private, writable cache folder (each tried one's reason).
    Exception
        Whatever ``compile_to`` raises.
    """
    why = []
    for folder, top in folders(kind, key):
        try:
            disk_cache.private_folder(folder, top)
        except OSError as exc:
            why.append(str(exc))
            continue                                   # not usable: the fallback folder
        target = folder / name
        try:
            if rebuild and os.path.lexists(target):
                set_aside(target, "it did not load", what)
            elif verified(target):
                return target
        except PermissionError as exc:
            set_aside(target, str(exc), what)
        except OSError as exc:
            why.append(f"{target}: {exc.strerror or exc}")
            continue
        try:
            fd, tmp = tempfile.mkstemp(prefix=".tmp", suffix=Path(name).suffix, dir=folder)
        except OSError as exc:
            why.append(f"{folder}: {exc.strerror or exc}")
            continue                                   # not writable: the fallback folder
        os.close(fd)
        try:
            compile_to(Path(tmp))
            record = target.with_name(target.name + ".sha256")
            with tempfile.NamedTemporaryFile("w", dir=folder, prefix=".tmp", delete=False) as f:
                f.write(sha256(Path(tmp)) + "\n")
            os.replace(f.name, record)
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return target
    raise OSError(f"no private, writable cache folder for the {what} (" + "; ".join(why) + ")")
