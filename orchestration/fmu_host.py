"""One FMU driven directly through fmpy's FMU2Slave (no master), with its log recorded.

Used by the FMU tests (through ``tests/fmu_host.py``) and by the benchmarks that time one FMU
alone (``benchmarks/observers_2009.py``).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

from .fmu_store import content_key


class FmuLog(list):
    """The FMU's log messages; also an fmpy logger callback (``simulate_fmu(logger=...)``)."""

    def __call__(self, env, instance, status, category, message) -> None:  # noqa: ANN001 - C callback
        self.append(message.decode(errors="replace"))

    @property
    def messages(self) -> list[str]:
        return self

    def has(self, *words: str) -> bool:
        """Whether one message contains every word."""
        return any(all(w in m for w in words) for m in self)


class Slave:
    """An FMU instance in initialisation mode with ``params`` set; :meth:`init` leaves it.

    ``params`` values: str → String, bool → Boolean, a list/tuple → the vector ``name[1..n]``,
    otherwise by the variable's type (Integer or Real). ``unzip_dir`` reuses an extraction;
    ``logging_on`` is ``fmi2Instantiate``'s (debug logging).
    """

    def __init__(self, path: Path, params: dict | None = None, *, init: bool = False,
                 unzip_dir: str | None = None, instance_name: str = "t", logging_on: bool = True) -> None:
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.types = {v.name: v.type for v in self.md.modelVariables}
        self.log = FmuLog()
        self._own_unzip = unzip_dir is None
        if unzip_dir is None:
            content_key(Path(path))           # the archive limits (orchestration/archive.py) first
        self.unzip = extract(str(path)) if unzip_dir is None else unzip_dir
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self.log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb = cb                                   # the callbacks must outlive the instance
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzip,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=instance_name)
        self.fmu.instantiate(callbacks=cb, loggingOn=logging_on)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        for k, v in (params or {}).items():
            if isinstance(v, (tuple, list, np.ndarray)):
                self.set(**{k: v})
            elif isinstance(v, str):
                self.fmu.setString([self.vr[k]], [v])
            elif isinstance(v, bool):
                self.fmu.setBoolean([self.vr[k]], [v])
            elif self.types[k] == "Integer":
                self.fmu.setInteger([self.vr[k]], [int(v)])
            else:
                self.fmu.setReal([self.vr[k]], [float(v)])
        self.t = 0.0
        if init:
            self.init()

    def init(self) -> None:
        self.fmu.exitInitializationMode()

    def vec(self, name: str, size: int = 2) -> list[int]:
        """Value references of ``name[1..size]``."""
        return [self.vr[f"{name}[{i + 1}]"] for i in range(size)]

    def set(self, **values) -> None:
        """Set scalars or whole vectors (``name[1..n]``) in one ``setReal``."""
        refs, vals = [], []
        for k, v in values.items():
            v = np.atleast_1d(np.asarray(v, float))
            refs += [self.vr[k]] if v.size == 1 and k in self.vr else self.vec(k, v.size)
            vals += list(map(float, v))
        self.fmu.setReal(refs, vals)

    def get(self, name: str, size: int | None = None) -> np.ndarray | float:
        """A scalar, or the vector ``name[1..size]``."""
        if size is None:
            return self.fmu.getReal([self.vr[name]])[0]
        return np.array(self.fmu.getReal(self.vec(name, size)))

    def step(self, h: float) -> None:
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()
        if self._own_unzip:
            shutil.rmtree(self.unzip, ignore_errors=True)


__all__ = ["FmuLog", "Slave"]
