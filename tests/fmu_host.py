"""One FMU under test, driven through fmpy's FMU2Slave with its log recorded (the host lives
in :mod:`orchestration.fmu_host`, shared with the benchmarks), and every FMU built once.

Shared by the FMU test modules.
"""
from __future__ import annotations

from pathlib import Path

from orchestration.fmu_host import Slave  # noqa: F401 - re-exported to the FMU tests

_EVERY_FMU: list[Path] = []


def every_fmu(tmp_path_factory) -> list[Path]:  # noqa: ANN001 - pytest's TempPathFactory
    """Every FlexFusion FMU, built once per test process (about 5 s)."""
    if not _EVERY_FMU:
        from orchestration.build import build_all
        _EVERY_FMU.extend(build_all(tmp_path_factory.mktemp("every_fmu"), quiet=True))
    return list(_EVERY_FMU)
