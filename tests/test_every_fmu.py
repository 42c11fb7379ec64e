"""One test matrix over every FlexFusion FMU (the Reference-FMUs' way): each FMU validates with
fmpy, declares a unit on every Real variable, declares the direct feedthrough it has, runs twice
in one process, runs one second from its start values under plain fmpy, and names a bad
parameter in its FMI error.

What every FMU must also do, tested elsewhere over the same build: initial outputs
(test_fmi_initialization.py), the FMI error contract and FMU state (test_fmi_contract.py), its
requirements.txt (test_fmi_dependencies.py), hosts (test_fmi_hosting.py, test_native.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from numpy.testing import assert_array_equal

from fmu_host import Slave
from fmus.common.fmi import known_units
from orchestration.build import _CLASS, fmu_scripts, validate_fmu

#: Every model identifier `flexfusion build` makes (the FMU class of each script), known at
#: collection so that each FMU is its own test case.
MODELS = sorted(_CLASS.findall(s.read_text())[-1] for s in fmu_scripts())
H = 1e-3             # the master's base step: every FMU's sample rates divide it


@pytest.fixture(params=MODELS)
def fmu(request: pytest.FixtureRequest, every_fmu: dict[str, Path]) -> Path:
    return every_fmu[request.param]


def test_the_matrix_covers_the_build(every_fmu: dict[str, Path]) -> None:
    assert sorted(every_fmu) == MODELS


def test_validates(fmu: Path) -> None:
    assert validate_fmu(fmu) == []


def test_every_real_has_a_defined_unit_and_every_variable_a_description(fmu: Path) -> None:
    md = read_model_description(str(fmu))
    defined = {u.name for u in md.unitDefinitions}
    assert defined <= set(known_units())
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real":
            assert v.unit in defined, f"{v.name}: unit {v.unit!r}"


def _inputs(md) -> list[str]:  # noqa: ANN001 - fmpy's ModelDescription
    return [v.name for v in md.modelVariables if v.causality == "input" and v.type == "Real"]


def _nudged(md, names: list[str], k: int) -> dict[str, float]:  # noqa: ANN001
    """Inputs near their start values, each different (k varies them again)."""
    start = {v.name: float(v.start or 0.0) for v in md.modelVariables if v.type == "Real"}
    return {n: start[n] + 0.01 * (i + 1 + k) for i, n in enumerate(names)}


def test_declared_dependencies_are_inputs_and_cover_the_feedthrough(fmu: Path) -> None:
    """Each output lists its direct-feedthrough inputs (indices of input variables), and an
    output that lists none of an input's does not move when only that input changes."""
    md = read_model_description(str(fmu))
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    structure = {u.variable.name: u for u in md.outputs}
    assert set(structure) == {v.name for v in outputs}
    declared = {}
    for name, unknown in structure.items():
        deps = unknown.dependencies or []
        assert all(d.causality == "input" for d in deps), name
        declared[name] = {d.name for d in deps}
    inputs = _inputs(md)
    if not inputs:
        return
    s = Slave(fmu, init=True)
    try:
        s.set(**_nudged(md, inputs, 0))
        s.step(H)
        for name in inputs:
            before = {o.name: s.get(o.name) for o in outputs}
            s.set(**{name: s.get(name) + 0.37})       # no doStep: only feedthrough can move
            after = {o.name: s.get(o.name) for o in outputs}
            moved = {o for o in before if not (before[o] == after[o]
                                                or (math.isnan(before[o]) and math.isnan(after[o])))}
            undeclared = {o for o in moved if name not in declared[o]}
            assert not undeclared, f"{name} moves {sorted(undeclared)} without declaring it"
    finally:
        s.close()


def _run(s: Slave, md, n: int, k0: int = 0) -> np.ndarray:  # noqa: ANN001
    """Outputs after each of n steps, with inputs varying with the step number k0, k0 + 1, ..."""
    inputs = _inputs(md)
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    rows = []
    for k in range(k0, k0 + n):
        if inputs:
            s.set(**_nudged(md, inputs, k % 7))
        s.step(H)
        rows.append([s.get(o) for o in outputs])
    return np.array(rows)


def test_two_instances_in_one_process_are_independent(fmu: Path) -> None:
    """Two live instances, stepped alternately, give what one instance alone gives."""
    md = read_model_description(str(fmu))
    alone = Slave(fmu, init=True)
    reference = _run(alone, md, 20)
    alone.close()
    a = Slave(fmu, init=True, instance_name="a")
    b = Slave(fmu, init=True, instance_name="b", unzip_dir=a.unzip)
    try:
        rows_a, rows_b = [], []
        for k in range(20):
            rows_a.append(_run(a, md, 1, k)[0])
            rows_b.append(_run(b, md, 1, k)[0])
    finally:
        b.close()
        a.close()
    assert_array_equal(np.array(rows_a), reference)
    assert_array_equal(np.array(rows_b), reference)


def test_runs_one_second_from_its_start_values_under_plain_fmpy(fmu: Path) -> None:
    result = fmpy.simulate_fmu(str(fmu), stop_time=1.0, step_size=H, output_interval=H)
    assert len(result) == 1001
    assert result["time"][-1] == pytest.approx(1.0)
    for name in result.dtype.names:
        assert np.all(np.isfinite(result[name])), name


def test_a_bad_parameter_is_an_fmi_error_naming_it(fmu: Path) -> None:
    md = read_model_description(str(fmu))
    name = next(v.name for v in md.modelVariables if v.causality == "parameter" and v.type == "Real")
    s = Slave(fmu, {name: float("nan")}, logging_on=False)
    try:
        with pytest.raises(FMICallException):
            s.init()
        assert s.log.has(f"parameter '{name}'", "not a finite number"), s.log
    finally:
        s.close()
