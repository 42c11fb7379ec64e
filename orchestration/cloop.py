"""The master's stepping loop in C: ``orchestration/cosim_loop.c`` compiled with the system C
compiler and loaded with ctypes (:func:`library`), and its arguments built from the master's
slots (:class:`CLoop`).

The library is compiled on first use, once per content of the source and the flags, into
``<cache root>/loop/<hash>/`` (:func:`fmus.common.disk_cache.cache_root`; about 0.1 s of gcc): not at
``flexfusion build``, so a run with FMUs built elsewhere, or a fresh cache, still gets it, and
the FMU build stays the FMUs'. A new library is compiled to a temporary name and renamed, so
parallel processes never load half a file; the SHA-256 of its bytes is recorded beside it
(``libcosim_loop.so.sha256``).

Nothing is loaded from a folder another user could write into: the cache folders (and the
fallback in the temporary directory, used where the cache root cannot be written) are made
mode 0700 and checked (owner, mode, no symbolic link) from their root down, and the library
and its hash too (:func:`fmus.common.disk_cache.private_folder`, ``check_private``); the
library is loaded only if its bytes have the recorded hash. One that fails a check (planted,
truncated, replaced) or does not load is set aside (renamed ``.bad-*``) and compiled again,
once.

Where no C compiler is found, compiling fails, or ``FLEXFUSION_PYTHON_LOOP=1`` is set,
:func:`library` is None (:func:`unavailable` says why) and the master runs its Python loop, the
reference: both give the same results, bit for bit (tests/test_cosim_loop.py).
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from fmus.common import disk_cache

if TYPE_CHECKING:
    from .schedule import Schedule

SOURCE = Path(__file__).with_name("cosim_loop.c")
# no -ffast-math: the loop's NaN test (x != x) must stay
CFLAGS = ["-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra"]
LIBRARY_NAME = "libcosim_loop.so"
FUNCTIONS = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal", "NaN")   # cosim_loop.c's Stop.function


class _Slot(ctypes.Structure):
    _fields_ = [("set_real", ctypes.c_void_p), ("do_step", ctypes.c_void_p), ("get_real", ctypes.c_void_p),
                ("component", ctypes.c_void_p),
                ("n_in", ctypes.c_size_t), ("in_vr", ctypes.c_void_p), ("in_idx", ctypes.c_void_p),
                ("in_buf", ctypes.c_void_p),
                ("n_out", ctypes.c_size_t), ("out_vr", ctypes.c_void_p), ("out_start", ctypes.c_int64),
                ("n_check", ctypes.c_int64), ("step", ctypes.c_double)]


class _Loop(ctypes.Structure):
    _fields_ = [("slots", ctypes.c_void_p), ("n_slots", ctypes.c_int64), ("due", ctypes.c_void_p),
                ("due_start", ctypes.c_void_p), ("period", ctypes.c_int64), ("tail_start", ctypes.c_int64),
                ("values", ctypes.c_void_p),
                ("record_idx", ctypes.c_void_p), ("n_record", ctypes.c_int64), ("every", ctypes.c_int64),
                ("h", ctypes.c_double)]


class _Stop(ctypes.Structure):
    _fields_ = [("k", ctypes.c_int64), ("slot", ctypes.c_int64), ("function", ctypes.c_int32),
                ("status", ctypes.c_int32)]


_WHY_NOT: list[str] = []


def unavailable() -> str | None:
    """Why the C loop is not used in this process (None: it is)."""
    library()
    return _WHY_NOT[0] if _WHY_NOT else None


@functools.lru_cache(maxsize=None)
def library() -> Any:
    """The loaded C loop (``cosim_steps`` ready to call), compiled first if it is not in the
    cache; None without a C compiler, when compiling fails, or with ``FLEXFUSION_PYTHON_LOOP=1``."""
    _WHY_NOT.clear()
    if os.environ.get("FLEXFUSION_PYTHON_LOOP", "") not in ("", "0"):
        _WHY_NOT.append("FLEXFUSION_PYTHON_LOOP is set")
        return None
    try:
        path = _compiled()
    except Exception as exc:  # noqa: BLE001 - no compiler, a failed compilation: the Python loop runs
        _WHY_NOT.append(str(exc))
        return None
    try:
        # PyDLL: the GIL stays held through the loop; each FMU call into Python (our native
        # layer's PyGILState_Ensure) then nests instead of taking it from scratch
        lib = ctypes.PyDLL(str(path))
    except OSError:                   # checked, yet it does not load: compiled again, once
        try:
            lib = ctypes.PyDLL(str(_compiled(rebuild=True)))
        except Exception as exc:  # noqa: BLE001
            _WHY_NOT.append(str(exc))
            return None
    lib.cosim_steps.restype = ctypes.c_int64
    lib.cosim_steps.argtypes = [ctypes.POINTER(_Loop), ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p,
                                ctypes.POINTER(_Stop)]
    return lib


def _key() -> str:
    """The C loop's cache entry: a hash of the source, the flags and the platform."""
    digest = hashlib.sha256(SOURCE.read_bytes())
    digest.update("\0".join([*CFLAGS, sys.platform, os.uname().machine]).encode())
    return digest.hexdigest()[:16]


def _folders() -> list[tuple[Path, Path]]:
    """Where the library may be cached, in order: ``(folder, top)``, ``top`` the first folder
    that must be private (:func:`fmus.common.disk_cache.private_folder`)."""
    root = disk_cache.cache_root()
    shared = Path(tempfile.gettempdir()) / f"flexfusion-{os.getuid()}"
    return [(root / "loop" / _key(), root), (shared / "loop" / _key(), shared)]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _verified(target: Path) -> bool:
    """Whether the cached library ``target`` may be loaded: it and its recorded hash
    (``<target>.sha256``, written when it was compiled) private to this user and the hash
    that of its bytes. False if it is not there; raises ``PermissionError`` (why) otherwise."""
    if not os.path.lexists(target):
        return False
    record = target.with_name(target.name + ".sha256")
    disk_cache.check_private(target, folder=False)
    try:
        disk_cache.check_private(record, folder=False)
    except FileNotFoundError:
        raise PermissionError(f"{target}: no hash recorded when it was compiled") from None
    if record.read_text().strip() != _sha256(target):
        raise PermissionError(f"{target}: its content is not what was compiled (truncated or replaced)")
    return True


def _set_aside(target: Path, why: str) -> None:
    """Move a cached library that failed its check (and its hash) out of the way, keeping it
    for inspection under a hidden name, and say so once."""
    import warnings
    stamp = f".bad-{int(time.time())}-{os.getpid()}-"
    for path in (target, target.with_name(target.name + ".sha256")):
        if os.path.lexists(path):
            os.replace(path, path.with_name(stamp + path.name))
    warnings.warn(f"the cached C loop was not loaded ({why}); set aside and compiled again", stacklevel=3)


def _compiled(rebuild: bool = False) -> Path:
    """The library compiled from ``cosim_loop.c``: the cached one, if private and as compiled
    (:func:`_verified`), or compiled now (a cached one that fails the check is set aside
    first); in the cache root's ``loop/`` folder, or a private one in the temporary directory
    if the cache root cannot be used. ``rebuild``: set the cached one aside whatever it is."""
    why = []
    for folder, top in _folders():
        try:
            disk_cache.private_folder(folder, top)
        except OSError as exc:
            why.append(str(exc))
            continue                                   # not usable: the fallback folder
        target = folder / LIBRARY_NAME
        try:
            if rebuild and os.path.lexists(target):
                _set_aside(target, "it did not load")
            elif _verified(target):
                return target
        except PermissionError as exc:
            _set_aside(target, str(exc))
        except OSError as exc:
            why.append(f"{target}: {exc.strerror or exc}")
            continue
        try:
            fd, tmp = tempfile.mkstemp(prefix=".tmp", suffix=".so", dir=folder)
        except OSError as exc:
            why.append(f"{folder}: {exc.strerror or exc}")
            continue                                   # not writable: the fallback folder
        os.close(fd)
        try:
            _compile(tmp)
            record = target.with_name(target.name + ".sha256")
            with tempfile.NamedTemporaryFile("w", dir=folder, prefix=".tmp", delete=False) as f:
                f.write(_sha256(Path(tmp)) + "\n")
            os.replace(f.name, record)
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return target
    raise OSError("no private, writable cache folder for the C loop (" + "; ".join(why) + ")")


def _compile(out: str) -> None:
    from .native import c_compiler

    command = [*c_compiler(), *CFLAGS, str(SOURCE), "-o", out]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"compiling {SOURCE.name} failed ({' '.join(command)}):\n{result.stderr}")


def _pointer(array: Any) -> int:
    return ctypes.cast(array, ctypes.c_void_p).value


class CLoop:
    """``cosim_steps`` bound to one run: the master's slots (``orchestration.master._Slot``, one
    per component of the schedule's order), the run's :class:`~orchestration.schedule.Schedule`
    (its rows of components due, indices into ``slots``), the shared buffer.

    ``loop(k0, k1, rows)`` runs base steps ``k0 .. k1-1`` and returns ``(rows written, stop)``,
    ``stop`` None or ``(k, slot index or None, function name, status)``, as the master's
    ``_python_steps``.
    """

    def __init__(self, lib: Any, slots: Sequence[Any], schedule: Schedule, values_c: Any,
                 record_idx: np.ndarray, every: int, h: float) -> None:
        self._steps = lib.cosim_steps
        keep: list[Any] = []

        def array(kind: Any, items: Sequence[Any]) -> int:
            a = (kind * max(len(items), 1))(*items)
            keep.append(a)
            return _pointer(a)

        self._slots = (_Slot * len(slots))()
        for c, s in zip(self._slots, slots):
            inst = s.inst
            c.set_real, c.do_step, c.get_real = (_pointer(f) for f in (inst.c_set, inst.c_step, inst.c_get))
            c.component = inst.handle.value
            c.n_in, c.in_vr, c.in_buf = s.n_in.value, _pointer(s.in_vr), _pointer(s.in_buf)
            c.in_idx = array(ctypes.c_int64, [int(i) for i in s.in_idx])
            c.n_out, c.out_vr, c.out_start, c.n_check = s.n_out.value, _pointer(s.out_vr), s.out_start, s.n_check
            c.step = s.step.value
        due = schedule.due
        starts = np.cumsum([0] + [len(d) for d in due])
        self._loop = _Loop(_pointer(self._slots), len(slots), array(ctypes.c_int64, [i for d in due for i in d]),
                           array(ctypes.c_int64, starts.tolist()), schedule.period, schedule.tail_start,
                           _pointer(values_c),
                           array(ctypes.c_int64, record_idx.tolist()), len(record_idx), every, h)
        self._keep = (keep, slots, values_c)    # what the structures point into
        self._stop = _Stop()

    def __call__(self, k0: int, k1: int, rows: np.ndarray) -> tuple[int, tuple[int, int | None, str, int] | None]:
        n = self._steps(ctypes.byref(self._loop), k0, k1, rows.ctypes.data, ctypes.byref(self._stop))
        s = self._stop
        if s.function < 0:
            return n, None
        return n, (s.k, s.slot if s.slot >= 0 else None, FUNCTIONS[s.function], s.status)


__all__ = ["CLoop", "library", "unavailable"]
