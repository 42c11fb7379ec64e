"""Run an SSP package in libcosim (libcosimpy), the Open Simulation Platform's engine, and
write the recorded variables to a JSON file. Used by ``tests/test_ssp.py`` and
``benchmarks/fmi_libcosim_flagship.py`` in a subprocess, run as a script (:data:`RUNNER`):
pythonfmu FMUs run in the host interpreter, so libcosim and fmpy must not share a process.

Usage::

    python orchestration/cosim_runner.py PACKAGE.ssp STEP_NS N_STEPS OUT.json comp.var [comp.var ...]

Steps the execution ``N_STEPS`` times by its base step ``STEP_NS`` (integer nanoseconds) and
records, after every step, the last value of each ``comp.var`` (scalar FMI variable names).
``OUT.json`` holds ``{"time": [...], "values": {"comp.var": [...]}, "log": "..."}``.
"""
from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path

#: This file, to run as a script in a subprocess of its own.
RUNNER = Path(__file__).resolve()


def _run(ssp: str, step_ns: int, n_steps: int, columns: list[str]) -> dict:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)

    ex = CosimExecution.from_ssp_file(ssp, step_size=step_ns)
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    where: list[tuple[int, int]] = []
    for col in columns:
        comp, var = col.split(".", 1)
        index = ex.slave_index_from_instance_name(comp)
        refs = {}
        for v in ex.slave_variables(index):
            name = v.name.decode() if isinstance(v.name, bytes) else v.name
            refs[name] = v.reference
        if var not in refs:
            raise KeyError(f"{col}: no such variable in libcosim's view of '{comp}'")
        where.append((index, refs[var]))
    time: list[float] = []
    values: dict[str, list[float]] = {c: [] for c in columns}
    for k in range(1, n_steps + 1):
        if not ex.step(1):
            raise RuntimeError(f"libcosim step {k} failed")
        time.append(k * step_ns * 1e-9)
        for col, (index, ref) in zip(columns, where):
            values[col].append(float(observer.last_real_values(index, [ref])[0]))
    return {"time": time, "values": values}


def main(argv: list[str]) -> int:
    ssp, step_ns, n_steps, out = argv[0], int(argv[1]), int(argv[2]), argv[3]
    columns = argv[4:]
    try:
        result = _run(ssp, step_ns, n_steps, columns)
        status = 0
    except Exception:  # noqa: BLE001 - reported in the output file for the test to show
        result = {"error": traceback.format_exc()}
        status = 1
    with open(out, "w") as f:
        json.dump(result, f)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
