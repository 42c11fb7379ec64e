"""Initialisation semantics of every FlexFusion FMU as a standard master sees them (FMI 2.0,
section 4.2.4): outputs are valid in Initialization Mode as soon as the parameters and inputs
they depend on are set, and a parameter set after such a read still takes effect.

libcosim and OMSimulator read outputs before ``fmi2ExitInitializationMode``; our outputs used to
read as their start value (zero) there.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from numpy.testing import assert_allclose, assert_array_equal

from fmu_host import Slave
from orchestration.build import fmu_scripts


def _inputs(path: Path) -> dict[str, float]:
    """Inputs near their start values, each a little different, so that every one matters."""
    md = read_model_description(str(path))
    return {v.name: float(v.start or 0.0) + 0.01 * (i + 1)
            for i, v in enumerate(v for v in md.modelVariables if v.causality == "input")}


def _outputs(s: Slave) -> np.ndarray:
    return np.array(s.fmu.getReal([v.valueReference for v in s.md.modelVariables
                                   if v.causality == "output"]))


def _sample_parameter(path: Path) -> tuple[str, float]:
    """A Real parameter with a nonzero default, changed by 5 %, that the FMU accepts (the
    six-axis plant refuses another upper arm length ``l1`` than the data sheet's: the next)."""
    md = read_model_description(str(path))
    for v in md.modelVariables:
        if v.causality == "parameter" and v.type == "Real" and float(v.start or 0.0) != 0.0:
            s = Slave(path, {v.name: 1.05 * float(v.start)}, logging_on=False)
            try:
                s.init()
            except FMICallException:
                continue
            finally:
                s.close()
            return v.name, 1.05 * float(v.start)
    pytest.skip(f"{path.stem} has no Real parameter")


def test_outputs_are_calculated_initial_unknowns(every_fmu: dict[str, Path]) -> None:
    for name, path in every_fmu.items():
        md = read_model_description(str(path))
        outputs = [v for v in md.modelVariables if v.causality == "output"]
        assert outputs, name
        assert {v.initial for v in outputs} == {"calculated"}, name
        assert {u.variable.name for u in md.initialUnknowns} == {v.name for v in outputs}, name


def test_every_fmu_outputs_in_initialization_mode_equal_those_after_it(every_fmu: dict[str, Path]) -> None:
    assert len(every_fmu) == len(fmu_scripts())
    for name, path in every_fmu.items():
        s = Slave(path)
        s.set(**_inputs(path))
        during = _outputs(s)                   # before fmi2ExitInitializationMode
        s.init()
        after = _outputs(s)
        s.close()
        assert np.all(np.isfinite(during)), name
        assert_array_equal(during, after, err_msg=name)


def test_a_parameter_set_after_a_read_takes_effect(every_fmu: dict[str, Path]) -> None:
    changed = 0
    for name, path in every_fmu.items():
        param, value = _sample_parameter(path)
        s = Slave(path)
        s.set(**_inputs(path))
        before = _outputs(s)
        s.set(**{param: value})                # after a read, still in Initialization Mode
        late = _outputs(s)
        s.init()
        late_after = _outputs(s)
        s.close()
        fresh = Slave(path, {param: value})    # the same value set before any read
        fresh.set(**_inputs(path))
        fresh.init()
        expected = _outputs(fresh)
        fresh.close()
        assert_array_equal(late, expected, err_msg=f"{name}.{param}")
        assert_array_equal(late_after, expected, err_msg=f"{name}.{param}")
        changed += not np.array_equal(before, expected)
    assert changed >= 6      # the sample parameter changes some initial output of many FMUs


def test_plant_pose_is_right_before_exit_initialization(every_fmu: dict[str, Path]) -> None:
    """The flagship's failure in libcosim: consumers started from p_tool = 0."""
    from fmus.common import kinematics
    from fmus.robot_plant.plant_model import PlantParameters
    p = PlantParameters(ideal=True)     # the nominal geometry: tool position by rigid kinematics
    s = Slave(every_fmu["FlexibleRobot2DOF"], {"ideal": True})
    q_a, p_tool = s.get("q_a", 2), s.get("p_tool", 2)
    s.close()
    assert_allclose(q_a, p.initial_angles(), atol=1e-12)
    assert_allclose(p_tool, kinematics.tool_position(q_a, p.robot()), atol=1e-12)
    assert np.linalg.norm(p_tool) > 1.0         # links of about 0.9 m and 1.2 m
