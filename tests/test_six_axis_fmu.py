"""The FlexibleRobot6DOF FMU (fmus/robot_plant/flexible_robot6_fmu.py) through fmpy: its
interface (the names the six-axis controller and IMU are written against), its outputs equal to
the model's stepped alone, and bad input refused at initialisation naming the parameter. The
matrix every FMU passes (validation, units, feedthrough, two instances, fmpy, FMU state) is
tests/test_every_fmu.py's and tests/test_fmi_*.py's."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from fmu_host import Slave
from fmus.common.parameters import replace
from fmus.robot_plant.six_axis_model import OUTPUTS, SixAxisParameters, SixAxisPlant

DT = 1e-3


@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["FlexibleRobot6DOF"]


def test_the_interface(fmu: Path) -> None:
    """Inputs tau_m[6], f_ext[3]; the outputs of the model's table (q_m ... a_sensor) and
    t_state; the plant role; a_tool and a_sensor depend on f_ext only."""
    md = read_model_description(str(fmu))
    names = {v.name: v for v in md.modelVariables}
    inputs = sorted(v.name for v in md.modelVariables if v.causality == "input")
    assert inputs == sorted([f"tau_m[{i}]" for i in range(1, 7)] + [f"f_ext[{i}]" for i in range(1, 4)])
    want = [f"{nm}[{i}]" for nm, k in OUTPUTS for i in range(1, k + 1)] + ["t_state"]
    assert [v.name for v in md.modelVariables if v.causality == "output"] == want
    assert {nm for nm, _ in OUTPUTS} == {"q_m", "dq_m", "q_a", "dq_a", "tau_s", "p_tool", "quat_tool", "v_tool",
                                         "a_tool", "omega_tool", "p_sensor", "a_sensor"}
    assert names["p_tool[1]"].unit == "m" and names["quat_tool[1]"].unit == "1" and names["a_sensor[3]"].unit == "m/s2"
    feed = {u.variable.name: {d.name for d in (u.dependencies or [])} for u in md.outputs}
    for name, deps in feed.items():
        if name.startswith(("a_tool", "a_sensor")):
            assert deps == {"f_ext[1]", "f_ext[2]", "f_ext[3]"}, name
        else:
            assert deps == set(), name


def test_the_fmu_steps_as_the_model(fmu: Path) -> None:
    """Holding torques plus a varying part and a 10 ms blow: after each of 60 steps the FMU's
    outputs are the model's stepped alone with the same inputs, bit for bit (the same kernel)."""
    p = replace(SixAxisParameters(), q0=(0.3, 0.4, -0.3, 0.5, -0.6, 0.2))
    m = SixAxisPlant(p)
    s = Slave(fmu, {"q0": list(p.q0)}, init=True)
    try:
        hold = m.current.copy()
        assert s.get("t_state") == 0.0
        first = np.array([s.get(f"{nm}[{i + 1}]") for nm, k in OUTPUTS for i in range(k)])
        assert np.array_equal(first, m.outputs(m.x, m.current, np.zeros(6)))
        for k in range(60):
            tau = hold + np.array([0.3, -0.5, 0.4, 0.1, -0.1, 0.05]) * np.sin(0.2 * k)
            f = np.array([300.0, -200.0, 150.0]) if 10 <= k < 20 else np.zeros(3)
            s.set(tau_m=tau, f_ext=f)
            s.step(DT)
            w = np.concatenate([f, np.zeros(3)])
            m.step(tau, w, DT)
            got = np.array([s.get(f"{nm}[{i + 1}]") for nm, kk in OUTPUTS for i in range(kk)])
            assert np.array_equal(got, m.outputs(m.x, m.current, w)), k
            assert s.get("t_state") == pytest.approx((k + 1) * DT, abs=1e-15)
        assert np.abs(m.x[m.act] - np.asarray(p.q0)).max() > 1e-5           # it moved
    finally:
        s.close()


@pytest.mark.parametrize("params, words", [
    ({"q0": [0.0, 0.3, 1.5, 0.0, 0.0, 0.0]}, ("parameter 'q0[3]'", "outside axis 3's working range")),
    ({"tool_inertia": [0.01, 0.01, 0.5]}, ("parameter 'tool_inertia'", "not a physical inertia")),
    ({"bend_stiffness": [1.9e6, 8.0e5, 6.4e5, 1e10]}, ("parameter 'bend_stiffness[4]'", "'max_substeps' = 64")),
])
def test_bad_input_is_refused_at_initialisation_naming_it(fmu: Path, params: dict, words: tuple) -> None:
    s = Slave(fmu, params, logging_on=False)
    try:
        with pytest.raises(FMICallException):
            s.init()
        assert s.log.has(*words), s.log
    finally:
        s.close()
