"""RigidKinematics: the motor-angle baseline, as math and through its FMU."""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest
from numpy.testing import assert_allclose

from fmus.common import dynamics, kinematics
from fmus.common.robot_params import RobotParameters
from fmus.estimators import rigid_kinematics_model as rk


def test_gravity_compensation_inverts_the_static_deflection() -> None:
    """At rest in static equilibrium the compensated kinematics give the true tool position."""
    p = RobotParameters()
    for q in ([0.0, 0.0], [0.3, -0.2], [-0.4, 0.6]):
        x = dynamics.static_equilibrium(q, p)
        assert_allclose(rk.arm_angles(x[2:4], p, True), q, atol=1e-12)
        assert_allclose(rk.tool_position(x[2:4], p, True), kinematics.tool_position(q, p), atol=1e-12)
        # without compensation (the default, as in the papers) the tool sags by millimetres
        sag = np.hypot(*(rk.tool_position(x[2:4], p) - kinematics.tool_position(q, p)))
        assert sag > 1e-3
        assert_allclose(rk.arm_angles(x[2:4], p), x[2:4] / np.array(p.gear_ratio), rtol=1e-15)


def test_compensation_uses_the_models_stiffness_not_the_plants() -> None:
    """A model 20 % stiffer than the robot removes only about 1/1.2 of the true sag."""
    true = RobotParameters()
    model = RobotParameters(k_lo=tuple(1.2 * k for k in true.k_lo), k_hi=tuple(1.2 * k for k in true.k_hi))
    q = [0.3, -0.2]
    x = dynamics.static_equilibrium(q, true)
    p_true = kinematics.tool_position(q, true)
    sag = np.hypot(*(rk.tool_position(x[2:4], model) - p_true))
    left = np.hypot(*(rk.tool_position(x[2:4], model, True) - p_true))
    assert 0.1 * sag < left < 0.25 * sag


def numpy_arm_angles(q_m, robot, gravity_compensation=False):
    """The numpy version the scalar kernel replaced (issue 16), as the reference."""
    q_motor = np.asarray(q_m, float) / np.asarray(robot.gear_ratio, float)
    if not gravity_compensation:
        return q_motor
    q, D = q_motor, None
    for _ in range(8):
        D = dynamics.spring_deflection(dynamics.gravity_torque(q, robot), robot, D)
        q_next = q_motor - D
        if np.abs(q_next - q).max() <= 1e-11:
            return q_next
        q = q_next
    return q


@pytest.mark.parametrize("compensate", [False, True])
def test_scalar_kernel_matches_the_numpy_version(compensate) -> None:
    """Random arm poses over the workspace (and a much softer model): the same angles to
    round-off, including the soft zone of the spring (small gravity torque near q1 = 0)."""
    rng = np.random.default_rng(7)
    for p in (RobotParameters(), RobotParameters(k_lo=(3e4, 2e4), k_hi=(2.8e5, 1.4e5))):
        for _ in range(200):
            q_m = dynamics.static_equilibrium(rng.uniform([-0.6, -0.8], [0.8, 0.8]), p)[2:4]
            q_m = q_m + rng.normal(0.0, 0.05, 2)           # off equilibrium: any motor angles
            assert_allclose(rk.arm_angles(q_m, p, compensate), numpy_arm_angles(q_m, p, compensate),
                            rtol=0, atol=1e-15)


def test_scalar_spring_pieces_match_the_numpy_functions() -> None:
    rng = np.random.default_rng(3)
    p = RobotParameters()
    k = dynamics.arm_constants(p)
    for _ in range(200):
        q = rng.uniform(-1.5, 1.5, 2)
        assert_allclose(k.gravity(*q), dynamics.gravity_torque(q, p), rtol=1e-15, atol=1e-12)
        tau = rng.normal(0.0, 10.0 ** rng.uniform(-3, 3.5), 2)      # the soft zone and beyond
        D = [k.deflection(i, tau[i]) for i in range(2)]
        assert_allclose(D, dynamics.spring_deflection(tau, p), rtol=1e-13, atol=1e-18)
        assert_allclose(dynamics.spring_torque(np.zeros(2), np.multiply(D, k.r), p), tau,
                        rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def fmu(every_fmu: dict[str, Path]) -> Path:
    return every_fmu["RigidKinematics"]


@pytest.mark.parametrize("compensate", [False, True])
def test_fmu_matches_the_model(fmu, compensate) -> None:
    p = RobotParameters()
    q_m = dynamics.static_equilibrium([0.2, 0.1], p)[2:4]
    res = fmpy.simulate_fmu(str(fmu), stop_time=0.01, step_size=1e-3,
                            start_values={"q_m_meas[1]": q_m[0], "q_m_meas[2]": q_m[1],
                                          "gravity_compensation": compensate},
                            output=["p_tool_hat[1]", "p_tool_hat[2]", "q_a_hat[1]"])
    assert_allclose([res["p_tool_hat[1]"][-1], res["p_tool_hat[2]"][-1]],
                    rk.tool_position(q_m, p, compensate), atol=1e-12)
    md = fmpy.read_model_description(str(fmu))
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real" and v.causality in ("input", "output"):
            assert v.unit, v.name
