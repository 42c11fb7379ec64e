"""``flexfusion check-estimator``: does an FMU meet the estimator contract?

The contract (docs/estimator_contract.md; the table in :mod:`fmus.common.estimator_contract`)
names the inputs an estimator may take and the outputs it must give. An FMU that meets it can
replace any of our estimators in a scenario, and be fed by a recorded log (LogReplay). Each rule
below is checked on the FMU's modelDescription, the last one by running it; a failed rule gives
one line ``<rule>: <what is wrong>``.

======================  ===================================================================
``co-simulation``       FMI 2.0 with a CoSimulation interface
``required-outputs``    ``p_tool_hat[1]``, ``p_tool_hat[2]``: Real outputs
``inputs``              every input is a contract input (name, index within its size), Real
``outputs``             an output with a contract name has the contract's size and is Real
``units``               a declared unit of a contract variable is the contract's (none: SI)
``t_meas``              an input ``t_meas`` starts negative (unstamped until connected)
``runs``                instantiates, initialises with its defaults and start inputs, steps
                        1 s (its default step, else 0.01 s) with a finite ``p_tool_hat``
======================  ===================================================================
"""
from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from fmus.common import estimator_contract as contract

RULES = ("co-simulation", "required-outputs", "inputs", "outputs", "units", "t_meas", "runs")
RUN_TIME = 1.0         # s
RUN_STEP = 0.01        # s, when the FMU has no default step


def _split(name: str) -> tuple[str, int | None]:
    """``"q_m_meas[2]"`` -> ``("q_m_meas", 2)``; ``"t_meas"`` -> ``("t_meas", None)``."""
    if name.endswith("]") and "[" in name:
        base, index = name[:-1].split("[", 1)
        if index.isdigit():
            return base, int(index)
    return name, None


def _fits(signal: contract.Signal, index: int | None) -> bool:
    return index is None if signal.size is None else (index is not None and 1 <= index <= signal.size)


def check_estimator(path: str | Path, *, run: bool = True) -> list[str]:
    """The failed rules of the contract, one line each (empty: the FMU meets it); without
    ``run``, the rules of the modelDescription only (no ``runs``: the FMU is not executed)."""
    from fmpy import read_model_description

    from .fmu_store import content_key
    try:
        content_key(Path(path))        # the archive limits (orchestration/archive.py), before any read
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # noqa: BLE001 - not an FMU, a broken zip or XML, beyond the limits
        return [f"co-simulation: cannot read the modelDescription of {path}: {exc}"]
    failures = []
    if md.fmiVersion != "2.0" or md.coSimulation is None:
        failures.append(f"co-simulation: fmiVersion {md.fmiVersion}, "
                        f"{'a' if md.coSimulation else 'no'} CoSimulation interface (FMI 2.0 "
                        "co-simulation needed)")
    variables = {v.name: v for v in md.modelVariables}
    inputs = {c.name: c for c in contract.INPUTS}
    outputs = {c.name: c for c in contract.REQUIRED_OUTPUTS + contract.OPTIONAL_OUTPUTS}

    missing = [f"{n} ({'not an output' if n in variables else 'missing'})"
               for s in contract.REQUIRED_OUTPUTS for n in s.scalars()
               if n not in variables or variables[n].causality != "output" or variables[n].type != "Real"]
    if missing:
        failures.append("required-outputs: " + ", ".join(missing) + " (a Real output each)")

    bad_inputs = []
    for v in md.modelVariables:
        if v.causality != "input":
            continue
        base, index = _split(v.name)
        if base not in inputs or not _fits(inputs[base], index):
            bad_inputs.append(f"'{v.name}' is not a contract input")
        elif v.type != "Real":
            bad_inputs.append(f"'{v.name}' is {v.type}, not Real")
    for base, s in inputs.items():          # a vector input is taken whole
        present = [n for n in s.scalars() if n in variables and variables[n].causality == "input"]
        if present and len(present) != len(s.scalars()):
            bad_inputs.append(f"'{base}' has {len(present)} of its {s.size} elements")
    if bad_inputs:
        failures.append("inputs: " + "; ".join(bad_inputs) + " (allowed: "
                        + ", ".join(f"{s.name}[{s.size}]" if s.size else s.name for s in contract.INPUTS) + ")")

    bad_outputs = []
    for base, s in outputs.items():
        present = [v for v in md.modelVariables if _split(v.name)[0] == base and v.causality == "output"]
        if present and ({v.name for v in present} != set(s.scalars()) or any(v.type != "Real" for v in present)):
            bad_outputs.append(f"'{base}' must be {len(s.scalars())} Real output(s) "
                               f"{', '.join(s.scalars())}, has {', '.join(v.name for v in present)}")
    if bad_outputs:
        failures.append("outputs: " + "; ".join(bad_outputs))

    bad_units = []
    for v in md.modelVariables:
        base, _ = _split(v.name)
        s = inputs.get(base) if v.causality == "input" else outputs.get(base) if v.causality == "output" else None
        unit = _unit(v)
        if s is not None and unit is not None and unit != s.unit:
            bad_units.append(f"'{v.name}' is in {unit}, the contract's unit is {s.unit}")
    if bad_units:
        failures.append("units: " + "; ".join(bad_units))

    t_meas = variables.get("t_meas")
    if t_meas is not None and t_meas.causality == "input" and not float(t_meas.start or 0.0) < 0.0:
        failures.append(f"t_meas: the input t_meas starts at {t_meas.start}; it must start negative "
                        "(unstamped: the measurements count as taken at the end of each step)")

    if run and md.coSimulation is not None:
        problem = _run(path, md, [n for s in contract.REQUIRED_OUTPUTS for n in s.scalars()
                                  if n in variables and variables[n].causality == "output"])
        if problem:
            failures.append("runs: " + problem)
    return failures


def _unit(v: Any) -> str | None:
    if getattr(v, "unit", None):
        return v.unit
    declared = getattr(v, "declaredType", None)
    return getattr(declared, "unit", None) if declared is not None else None


def _run(path: str | Path, md: Any, names: list[str]) -> str | None:
    """Why the FMU does not run 1 s with its defaults and start inputs, its outputs ``names``
    finite (None: it does)."""
    import fmpy
    step = (md.defaultExperiment.stepSize if md.defaultExperiment is not None
            and md.defaultExperiment.stepSize else None) or RUN_STEP
    log: list[str] = []

    def logger(env: Any, instance: Any, status: int, category: Any, message: bytes) -> None:
        if status > 1 and message:          # discard, error, fatal: the reason of a failure
            log.append(" ".join(message.decode(errors="replace").split()))
    try:
        result = fmpy.simulate_fmu(str(path), start_time=0.0, stop_time=RUN_TIME, step_size=step,
                                   output_interval=step, output=names, validate=False, logger=logger)
    except Exception as exc:  # noqa: BLE001 - any failure of the FMU is the finding
        return (f"{RUN_TIME:g} s with its defaults and start inputs failed: "
                f"{' '.join(str(exc).split()).rstrip('.')}" + (f"; FMU log: {log[-1]}" if log else ""))
    bad = [n for n in names if not all(math.isfinite(float(x)) for x in result[n])]
    if bad:
        return f"{', '.join(bad)} not finite within {RUN_TIME:g} s with its defaults and start inputs"
    return None


def main(paths: list[Path]) -> int:
    """Check each FMU; print one line per failed rule; 0 if all pass, else 2."""
    status = 0
    for path in paths:
        if not Path(path).is_file():
            print(f"error: {path}: no such file", file=sys.stderr)
            status = 2
            continue
        failures = check_estimator(path)
        for line in failures:
            print(f"{path}: {line}")
        if failures:
            status = 2
        else:
            print(f"{path}: meets the estimator contract ({len(RULES)} rules)")
    return status


__all__ = ["RULES", "check_estimator", "main"]
