"""The master's stepping loop in C: ``orchestration/cosim_loop.c`` compiled with the system C
compiler and loaded with ctypes (:func:`library`), and its arguments built from the master's
slots (:class:`CLoop`).

The library is compiled on first use, once per content of the source and the flags, into
``<cache root>/loop/<hash>/`` (about 0.1 s of gcc): not at ``flexfusion build``, so a run with
FMUs built elsewhere, or a fresh cache, still gets it, and the FMU build stays the FMUs'. The
cache entry is private, verified by the hash recorded when it was compiled, and set aside and
compiled again (once) if it fails a check or does not load: :mod:`fmus.common.native_cache`.

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
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from fmus.common import native_cache

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


def _compiled(rebuild: bool = False) -> Path:
    """The library compiled from ``cosim_loop.c``, in the private cache's ``loop/<key>/``
    (:func:`fmus.common.native_cache.compiled`: verified, set aside and compiled again if bad).
    ``rebuild``: set the cached one aside whatever it is."""
    return native_cache.compiled("loop", _key(), LIBRARY_NAME, _compile, "C loop", rebuild)


def _compile(out: Path) -> None:
    command = [*native_cache.c_compiler(), *CFLAGS, str(SOURCE), "-o", str(out)]
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
