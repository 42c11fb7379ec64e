"""Work-arounds for hosting pythonfmu (0.7) FMUs inside a Python process with fmpy.

A pythonfmu FMU runs its slave in the host's own interpreter, and two of its clean-up paths
corrupt that interpreter (seen here: segmentation faults and "corrupted double-linked list" in a
later garbage collection, or at exit, after many FMU instances in one process; upstream:
PythonFMU issues #228/#229, the use-after-free in ``finalizePythonInterpreter``):

* ``fmi2FreeInstance`` (and fmpy's ``dlclose`` of the library after it): Python objects the
  library made outlive the code they point to;
* the library's destructor at process exit.

So, in a Python host, pythonfmu instances are terminated but never freed (kept until exit, a few
MB each; ``FLEXFUSION_FREE_PYTHONFMU=1`` frees them, for a fixed pythonfmu build), no FMU
library is unloaded, and a process that has hosted them ends with
:func:`exit_without_finalizers` after flushing its output.
"""
from __future__ import annotations

import atexit
import os
import sys

import fmpy.fmi1
import fmpy.fmi2

_KEPT: list = []     # pythonfmu instances (or their owners, holding the callbacks) kept until exit


def is_pythonfmu(unzip_dir: str) -> bool:
    """Whether the FMU extracted in ``unzip_dir`` was made by pythonfmu."""
    return os.path.isfile(os.path.join(unzip_dir, "resources", "slavemodule.txt"))


def free_instance(fmu: fmpy.fmi2.FMU2Slave, owner: object = None) -> None:
    """``fmi2FreeInstance``, except for a pythonfmu instance: that one is kept (with ``owner``,
    which holds its callbacks) until the process ends. The library stays loaded either way."""
    if is_pythonfmu(fmu.unzipDirectory) and os.environ.get("FLEXFUSION_FREE_PYTHONFMU") != "1":
        _KEPT.append(owner if owner is not None else fmu)
    else:
        fmu.fmi2FreeInstance(fmu.component)


def keep_fmu_instances_alive() -> None:
    """Route fmpy's own ``freeInstance`` (used by ``simulate_fmu``) through :func:`free_instance`
    and never unload a library (idempotent)."""
    fmpy.fmi1._FMU.freeLibrary = lambda self: None  # noqa: SLF001 - fmpy has no option for it
    fmpy.fmi2.FMU2Slave.freeInstance = free_instance


def exit_without_finalizers(status: int) -> None:
    """Run the Python exit handlers (e.g. the removal of the FMU extraction folders), flush
    stdout/stderr and end the process without running library destructors."""
    try:
        atexit._run_exitfuncs()
    except Exception:  # noqa: BLE001 - a failing handler must not stop the exit
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream must not stop the exit
            pass
    os._exit(status)


keep_fmu_instances_alive()
