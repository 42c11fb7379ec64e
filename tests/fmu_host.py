"""One FMU under test, driven through fmpy's FMU2Slave with its log recorded (the host lives
in :mod:`orchestration.fmu_host`, shared with the benchmarks), and every FMU built once.

Shared by the FMU test modules.
"""
from __future__ import annotations

from pathlib import Path

from orchestration.fmu_host import FmuLog, Slave  # noqa: F401 - re-exported to the FMU tests
