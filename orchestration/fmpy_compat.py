"""Work-arounds for hosting pythonfmu (0.7) FMUs inside a Python process with fmpy.

A pythonfmu FMU runs its slave in the host's own interpreter, and two of its clean-up paths
corrupt that interpreter (seen here: segmentation faults and "corrupted double-linked list" in a
later garbage collection, or at exit, after many FMU instances in one pytest process; upstream:
PythonFMU issues #228/#229, the use-after-free in ``finalizePythonInterpreter``):

* ``fmi2FreeInstance`` followed by fmpy's ``dlclose`` of the library: Python objects the library
  made outlive the code they point to;
* the library's destructor at process exit.

So, in a Python host, we never free pythonfmu instances nor unload their libraries (a few MB
per instance, returned at exit), and a process that has hosted them ends with
:func:`exit_without_finalizers` after flushing its output.
"""
from __future__ import annotations

import os
import sys

import fmpy.fmi1
import fmpy.fmi2

_patched = False


def keep_fmu_instances_alive() -> None:
    """Make fmpy's ``freeInstance`` and ``freeLibrary`` no-ops (idempotent)."""
    global _patched
    if not _patched:
        fmpy.fmi1._FMU.freeLibrary = lambda self: None  # noqa: SLF001 - fmpy has no option for it
        fmpy.fmi2.FMU2Slave.freeInstance = lambda self: None
        _patched = True


def exit_without_finalizers(status: int) -> None:
    """Flush stdout/stderr and end the process without running library destructors."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream must not stop the exit
            pass
    os._exit(status)


keep_fmu_instances_alive()
