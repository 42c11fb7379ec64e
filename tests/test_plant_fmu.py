"""The FlexibleRobot2DOF FMU built and exercised through fmpy."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.parameters import as_array
from fmus.robot_plant.plant_model import PlantParameters
from fmu_host import Slave
from orchestration.build import validate_fmu

OUTPUTS = ("q_a", "dq_a", "ddq_a", "q_m", "dq_m", "p_tool", "v_tool", "a_tool", "p_sensor", "a_sensor", "tau_s")
DT = 1e-3


@pytest.fixture(scope="session")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["FlexibleRobot2DOF"]


@pytest.fixture(scope="session")
def unzipped(fmu: Path) -> str:
    return extract(str(fmu))



def test_fmu_validates(fmu: Path) -> None:
    assert validate_fmu(fmu) == []


def test_every_real_variable_declares_unit_and_description(fmu: Path) -> None:
    md = read_model_description(str(fmu))
    reals = [v for v in md.modelVariables if v.type == "Real"]
    assert len(reals) > 40
    units = {u.name for u in md.unitDefinitions}
    for v in reals:
        assert v.unit, v.name
        assert v.unit in units, v.name
        assert v.description and v.description.strip(), v.name
    by_name = {v.name: v for v in md.modelVariables}
    assert by_name["k_hi[1]"].unit == "N.m/rad" and by_name["k_hi[1]"].causality == "parameter"
    assert by_name["tau_m[2]"].causality == "input" and by_name["tau_m[2]"].unit == "N.m"
    assert by_name["a_sensor[1]"].unit == "m/s2" and by_name["phi_tool"].unit == "rad"
    # direct feedthrough: only the accelerations depend on f_ext, nothing on tau_m
    deps = {o.variable.name: {d.name for d in (o.dependencies or [])} for o in md.outputs}
    assert deps["a_tool[1]"] == {"f_ext[1]", "f_ext[2]"}
    assert deps["q_a[1]"] == set() and deps["tau_s[2]"] == set()


def test_fmu_runs_standalone_and_the_arm_falls(fmu: Path) -> None:
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.2, step_size=DT, output_interval=DT,
                            output=[f"{n}[{i}]" for n in OUTPUTS for i in (1, 2)] + ["phi_tool"])
    assert res.shape[0] == 201
    for name in res.dtype.names:
        assert np.all(np.isfinite(res[name])), name
    # zero motor torque at the default pose (upper arm up, forearm forward): it falls
    assert res["q_a[1]"][-1] - res["q_a[1]"][0] > 0.01
    assert res["p_tool[2]"][-1] < res["p_tool[2]"][0] - 0.01
    assert_allclose(res["p_tool[1]"][0], PlantParameters().l2, atol=1e-2)


def test_gravity_holding_torque_keeps_it_at_rest(fmu: Path, unzipped: str) -> None:
    p = PlantParameters()
    q = np.array([0.5, 0.3])
    s = Slave(fmu, {"q_a0[1]": q[0], "q_a0[2]": q[1], "ideal": True}, unzip_dir=unzipped, instance_name="plant")
    s.fmu.exitInitializationMode()
    tau = dynamics.gravity_torque(q, p) / as_array(p.gear_ratio)
    x_eq = dynamics.static_equilibrium(q, p)
    s.set(tau_m=tau)
    for k in range(500):
        s.fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
    assert_allclose(s.get("q_a", 2), q, atol=1e-12)
    assert_allclose(s.get("q_m", 2), x_eq[2:4], atol=1e-9)
    assert_allclose(s.get("dq_a", 2), 0.0, atol=1e-10)
    assert_allclose(s.get("dq_m", 2), 0.0, atol=1e-8)
    assert_allclose(s.get("tau_s", 2), dynamics.gravity_torque(q, p), rtol=1e-10)
    assert_allclose(s.get("p_tool", 2), kinematics.tool_position(q, p), atol=1e-12)
    s.close()


def test_fmu_outputs_equal_the_plain_model(fmu: Path, unzipped: str) -> None:
    p = PlantParameters(p_tool0=(1.2, 0.9))
    q0 = p.initial_angles()
    s = Slave(fmu, {"p_tool0[1]": 1.2, "p_tool0[2]": 0.9, "ideal": True}, unzip_dir=unzipped, instance_name="plant")
    s.fmu.exitInitializationMode()
    robot = p.robot()
    model = dynamics.FlexibleRobotModel(robot, q0, substeps=p.substeps)
    r = as_array(p.gear_ratio)
    rng = np.random.default_rng(42)
    outs = [s.vr[f"{n}[{i}]"] for n in OUTPUTS for i in (1, 2)] + [s.vr["phi_tool"], s.vr["omega_tool"]]
    for k in range(300):
        tau = dynamics.gravity_torque(q0, robot) / r + rng.normal(0.0, 2.0, 2)
        f = rng.normal(0.0, 100.0, 2) if k > 100 else np.zeros(2)
        s.fmu.setReal(s.vec("tau_m") + s.vec("f_ext"), list(map(float, np.r_[tau, f])))
        s.fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
        model.step(tau, f, DT)
        x = model.x
        q, qm, dq, dqm = x[0:2], x[2:4], x[4:6], x[6:8]
        ddq = dynamics.arm_acceleration(x, f, robot)
        expected = np.concatenate([
            q, dq, ddq, qm, dqm, kinematics.tool_position(q, robot), kinematics.velocity(q, dq, robot, "tool"),
            kinematics.point_acceleration(q, dq, ddq, robot, "tool"), kinematics.sensor_position(q, robot),
            kinematics.point_acceleration(q, dq, ddq, robot, "sensor"), dynamics.spring_torque(q, qm, robot),
            [q[0] + q[1], dq[0] + dq[1]]])
        got = np.array(s.fmu.getReal(outs))
        assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    assert np.abs(model.x[0:2] - q0).max() > 1e-4      # it moved (0.9 mrad)
    s.close()


def test_accelerations_follow_f_ext_directly(fmu: Path, unzipped: str) -> None:
    """Direct feedthrough: a new f_ext changes ddq_a without a step."""
    s = Slave(fmu, {"ideal": True}, unzip_dir=unzipped, instance_name="plant")
    s.fmu.exitInitializationMode()
    robot = PlantParameters().robot()
    x = dynamics.static_equilibrium((0.0, 0.0), robot)
    a0 = s.get("ddq_a", 2)
    f = np.array([200.0, -100.0])
    s.set(f_ext=f)
    assert_allclose(s.get("ddq_a", 2), dynamics.arm_acceleration(x, f, robot), rtol=1e-12, atol=1e-12)
    assert np.abs(s.get("ddq_a", 2) - a0).max() > 1e-3
    s.close()


@pytest.mark.parametrize("params, fragment", [
    ({"m1": -1.0}, "parameter 'm1'"),
    ({"k_hi[1]": 0.0}, "parameter 'k_hi[1]'"),
    ({"p_tool0[1]": 5.0, "p_tool0[2]": 0.0}, "parameter 'p_tool0' = (5.0, 0.0)"),
    ({"k_lo[2]": 3e5}, "parameter 'k_lo[2]'"),
    ({"substeps": 0}, "parameter 'substeps'"),
])
def test_bad_parameters_rejected_naming_the_parameter(fmu: Path, unzipped: str, params: dict, fragment: str) -> None:
    s = Slave(fmu, params, unzip_dir=unzipped, instance_name="plant")
    with pytest.raises(Exception):
        s.fmu.exitInitializationMode()
    assert any(fragment in m for m in s.log), s.log
    s.fmu.freeInstance()
